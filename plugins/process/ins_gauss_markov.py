"""First-order Gauss-Markov blocks appended to the ``ins`` state (``gauss_markov:`` in the ``ins`` params).

A slowly varying error of a measurement (the height a 2-D fix assumes, while the floor dips along the
route; a fix's slowly wandering offset) is not white: filters and, more so, smoothers average it as if it
were, and end up confident of a value nobody measured. Modelled as a state, it is estimated with the
rest and its uncertainty stays honest. Each element of a block follows

.. math::
    \\dot b = -b / \\tau + w, \\quad E[b^2] = sd^2 \\ \\text{(stationary)}

discretised exactly over dt: ``b_{k+1} = exp(-dt / tau) b_k``, ``Q_b = sd^2 (1 - exp(-2 dt / tau))``
(the variance of the stationary process that is not explained by b_k). Over a run of samples the same
formulas hold with dt = sum dts (the block does not depend on the input). The INS part (16, 10 or 22
states) is the ``ins`` model unchanged (``Ins`` or ``InsStates``): its f, F, Q, Q_inputs, f_inputs and
alignment are used for the first elements, the blocks are appended after them in the order given, and
the INS and the blocks are independent in F and Q (block diagonal). A measurement model reads a block
by name (``position``'s ``offset_block``).
"""
from __future__ import annotations

import copy

import numpy as np

from fusion.api import (Block, BuildContext, Event, LinearisesInputRuns, Message, ReportsStepEvents, StateLayout,
                        has)

from .ins_params import InsParams, InsProcess

__all__ = ["InsGaussMarkov", "GaussMarkovBlock"]


class GaussMarkovBlock(Block):
    """A vector block whose one element is named by the block itself (``hz``, not ``hzx``)."""

    def element_names(self) -> tuple[str, ...]:
        return (self.name,) if self.size == 1 else super().element_names()


class InsGaussMarkov(InsProcess):
    """The ``ins`` process with Gauss-Markov blocks appended (module docstring). State: the INS state
    (``p v q ba bw`` for 16 states; see ``ins``) then each ``gauss_markov`` block. Input as ``ins``:
    ``u = [ax ay az gx gy gz]`` (m/s^2, rad/s, FRD)."""


    def __init__(self, params: InsParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        from .ins import Ins

        p: InsParams = self.params  # type: ignore[assignment]
        self.core = Ins(p.model_copy(update={"gauss_markov": []}), context)   # Ins or InsStates
        self.m = self.core.layout.n                          # INS part: the first m elements
        self.layout = StateLayout(self.core.layout.blocks + tuple(GaussMarkovBlock(b.name, b.size) for b in p.gauss_markov))
        self.g, self.g_n = self.core.g, self.core.g_n
        self._tau = np.concatenate([np.full(b.size, b.tau) for b in p.gauss_markov])   # s, (k,)
        self._var = np.concatenate([np.full(b.size, b.sd * b.sd) for b in p.gauss_markov])
        self.hold_after = p.hold_after        # fusion.api.HoldsInput

    def held(self, age: float) -> "InsGaussMarkov":
        """fusion.api.HoldsInput: this model for a prediction that starts ``age`` s after the sample it
        holds (the INS part's ``held``; the blocks do not depend on the input)."""
        core = self.core.held(age)
        if core is self.core:
            return self
        c = copy.copy(self)
        c.core = core
        return c

    # ------------------------------------------------------------------ the blocks alone
    def decay(self, T: float) -> np.ndarray:
        """exp(-T / tau) (k,): the factor of the blocks' mean over T (s)."""
        return np.exp(-T / self._tau)

    def block_noise(self, T: float) -> np.ndarray:
        """sd^2 (1 - exp(-2 T / tau)) (k,): the blocks' process-noise variances over T (s)."""
        return self._var * -np.expm1(-2.0 * T / self._tau)

    def _join(self, x: np.ndarray, y_ins: np.ndarray, T: float) -> np.ndarray:
        """States (..., n): the INS part y_ins (..., m) and the blocks of x (..., n) decayed over T."""
        out = np.empty(y_ins.shape[:-1] + (self.layout.n,))
        out[..., :self.m] = y_ins
        out[..., self.m:] = np.asarray(x, dtype=float)[..., self.m:] * self.decay(T)
        return out

    def _embed(self, Q_ins: np.ndarray, T: float) -> np.ndarray:
        n, m = self.layout.n, self.m
        Q = np.zeros((n, n))
        Q[:m, :m] = Q_ins
        Q.reshape(-1)[m * (n + 1)::n + 1] = self.block_noise(T)    # the blocks' diagonal (a view, no fancy index)
        return Q

    # ------------------------------------------------------------------ process model
    def f(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Propagate states x (..., n) over dt (s) with the IMU sample u (6,) or (..., 6): the INS part by
        ``ins``, the blocks by exp(-dt / tau) (vectorised over sigma points)."""
        x = np.asarray(x, dtype=float)
        return self._join(x, self.core.f(x[..., :self.m], u, dt), dt)

    def f_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """States (..., n) after the samples ``us`` (k, 6) held over ``dts`` (k,) (s): ``ins.f_inputs`` for
        the INS part, exp(-sum dts / tau) for the blocks (the same as k calls of :meth:`f`)."""
        x = np.asarray(x, dtype=float)
        dts = np.asarray(dts, dtype=float)
        return self._join(x, self.core.f_inputs(x[..., :self.m], us, dts), float(dts.sum()))

    def jacobian(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """F (n, n) at x (n,): the INS F and diag(exp(-dt / tau)), block diagonal."""
        x = np.asarray(x, dtype=float)
        n, m = self.layout.n, self.m
        F = np.zeros((n, n))
        F[:m, :m] = self.core.jacobian(x[:m], u, dt)
        F[range(m, n), range(m, n)] = self.decay(dt)
        return F

    def Q(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """Q (n, n) over dt (s): the INS Q and sd^2 (1 - exp(-2 dt / tau)), block diagonal."""
        return self._embed(self.core.Q(np.asarray(x, dtype=float)[:self.m], u, dt), dt)

    def Q_batch(self, x: np.ndarray, u: np.ndarray | None, dt: float) -> np.ndarray:
        """:meth:`Q` for states x (N, n) at once (N, n, n) (the batched filters, fusion.batch): the INS's own
        ``Q_batch`` when it has one, the blocks' variances on the diagonal."""
        x = np.asarray(x, dtype=float)
        core_batch = getattr(self.core, "Q_batch", None)
        if core_batch is None:
            return np.stack([self.Q(xi, u if u is None or np.ndim(u) == 1 else u[i], dt) for i, xi in enumerate(x)])
        n, m = self.layout.n, self.m
        out = np.zeros((x.shape[0], n, n))
        out[:, :m, :m] = core_batch(x[:, :m], u, dt)
        out[:, range(m, n), range(m, n)] = self.block_noise(dt)
        return out

    def linearise_inputs(self, x: np.ndarray, us: np.ndarray, dts: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The EKF's run of samples (fusion.api.LinearisesInputRuns) when the INS part has one (the paper-002
        state sets): its means, F_j and Q_j with the blocks' decay exp(-dt_j / tau) and noise appended
        (block diagonal, as :meth:`jacobian` and :meth:`Q`); None otherwise (sample by sample)."""
        if not has(self.core, LinearisesInputRuns):
            return None
        x = np.asarray(x, dtype=float)
        run = self.core.linearise_inputs(x[:self.m], us, dts)
        if run is None:
            return None
        y, F_ins, Q_ins = run
        dts = np.asarray(dts, dtype=float)
        k, n, m = dts.shape[0], self.layout.n, self.m
        d = np.arange(m, n)
        F = np.zeros((k, n, n))
        F[:, :m, :m] = F_ins
        F[:, d, d] = np.exp(-dts[:, None] / self._tau)
        Q = np.zeros((k, n, n))
        Q[:, :m, :m] = Q_ins
        Q[:, d, d] = self._var * -np.expm1(-2.0 * dts[:, None] / self._tau)
        return self._join(x, y, float(np.sum(dts))), F, Q

    def Q_inputs(self, x0: np.ndarray, x1: np.ndarray, us: np.ndarray, dts: np.ndarray) -> np.ndarray:
        """Q (n, n) of a run of samples: ``ins.Q_inputs`` and the blocks' noise over T = sum dts."""
        m = self.m
        Qi = self.core.Q_inputs(np.asarray(x0, float)[:m], np.asarray(x1, float)[:m], us, dts)
        return self._embed(Qi, float(np.asarray(dts, dtype=float).sum()))

    def step_events(self, t: float, dts: np.ndarray) -> tuple[Event, ...]:
        """The INS part's (fusion.api.ReportsStepEvents: ``ins``'s eta clamps); the blocks report nothing."""
        return self.core.step_events(t, dts) if has(self.core, ReportsStepEvents) else ()

    def input_from(self, message: Message) -> np.ndarray:
        return self.core.input_from(message)

    def stillness(self, x0: np.ndarray, P0: np.ndarray, us: np.ndarray, ts: np.ndarray) -> tuple[bool, str] | None:
        """``ins``'s stillness test of the alignment window on the INS part."""
        m = self.m
        return self.core.stillness(np.asarray(x0, float)[:m], np.asarray(P0, float)[:m, :m], us, ts)

    def align(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray, still: bool = True,
              window: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``ins``'s levelling (and gyro bias) on the INS part; the blocks and P0 unchanged. ``still``,
        ``window``: as ``Ins.align``."""
        x0 = np.array(x0, dtype=float, copy=True)
        m = self.m
        y, _ = self.core.align(x0[:m], np.asarray(P0, float)[:m, :m], u_mean, still=still, window=window)
        x0[:m] = y
        return x0, np.array(P0, dtype=float, copy=True)
