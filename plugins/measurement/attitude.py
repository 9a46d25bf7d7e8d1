"""Measurement ``attitude``: an attitude fix with its covariance (a TRIAD solution, paper 002 sec. 2.3, eq. 10's q row)."""
from __future__ import annotations

from typing import ClassVar, Sequence

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, Fix, MalformedMessage, MeasurementModel, Message, Observation, Params

_SYM = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])        # the 6-value upper triangle, mirrored


def error_to_quaternion(q: np.ndarray) -> np.ndarray:
    """G (4, 3) with ``q_est - q_true ~ G d theta`` for ``q_est = exp(d theta / 2) (x) q_true`` (navigation-
    frame attitude error d theta, rad): ``G = R(q)[:, 1:] / 2`` (``[0, v] (x) q = R(q) [0, v]``)."""
    return 0.5 * quat.right_matrix(np.asarray(q, float))[:, 1:]


def covariance_in_state(q: np.ndarray, P_theta: np.ndarray, norm_sd: float = 1e-4) -> np.ndarray:
    """4 x 4 covariance of the quaternion block for an attitude error of covariance P_theta (3, 3) (rad^2),
    plus ``norm_sd^2`` along q itself (so the block is positive definite)."""
    G = error_to_quaternion(q)
    return G @ P_theta @ G.T + norm_sd ** 2 * np.outer(q, q) / (q @ q)


class AttitudeParams(Params):
    """YAML parameters of ``attitude``."""

    use_fix_covariance: bool = Field(True, description="R from the fix's own covariance (a TRIAD solver "
                                     "propagates it); False: the sensor's configured noise (rad)")


class Attitude(MeasurementModel):
    """Attitude fix ``q_m`` (Hamilton, scalar first, C_b^n) with the covariance of its navigation-frame error:
    a solver's :class:`fusion.api.Fix` (``attitude``, ``attitude_cov``: ``triad``, ``orientation_geometric``),
    or a recording's message ``qw qx qy qz [pxx pxy pxz pyy pyz pzz]``.

    Measured as the rotation from the fix to the state, z = 0 and
    ``h(x) = 2 vec(q (x) q_m*) sign(w)`` with q = x_q / |x_q| (rad, navigation frame; the small-angle
    error, first order in the residual), so R is the fix's 3 x 3 covariance (full rank, unlike a 4-vector
    q measurement) and q / -q are the same fix. Jacobian numerical (the EKF's central differences).
    :meth:`align_state`: the initial attitude from the static fixes (their chordal mean, R / N).
    """

    name: ClassVar[str] = "attitude"
    carries_R = True    # a fix carries its covariance
    Params: ClassVar[type[Params]] = AttitudeParams
    dim: int = 3

    def __init__(self, params: AttitudeParams | None = None, context: BuildContext | None = None,
                 q_m: np.ndarray | None = None):
        super().__init__(params, context)
        layout = self.context.layout
        if layout is None or "q" not in layout or layout.block("q").kind != "quaternion":
            raise ConfigError("attitude needs a state with an attitude quaternion block 'q'")
        self._q = layout["q"]
        self.q_m_conj = None if q_m is None else quat.conjugate(quat.normalize(np.asarray(q_m, float)))
        self.q_m = q_m

    def h(self, x: np.ndarray) -> np.ndarray:
        """Rotation vector (..., 3) (rad) from the fix to the state's attitude, navigation frame."""
        if self.q_m_conj is None:
            raise ValueError("attitude.h needs a fix: use the model bound by observe()")
        q = quat.normalize(np.asarray(x, dtype=float)[..., self._q])
        d = quat.multiply(q, self.q_m_conj)
        return 2.0 * d[..., 1:] * np.where(d[..., :1] < 0.0, -1.0, 1.0)

    def observe(self, message: Message | Fix) -> Observation | None:
        """Observation of a solver's Fix (its ``attitude`` and ``attitude_cov``, rad^2), or of a message
        ``qw qx qy qz`` + 6 covariance values (rad^2, the upper triangle) (or 4 values: configured R)."""
        if isinstance(message, Fix):
            if message.attitude is None:
                raise MalformedMessage("attitude: the fix carries no attitude")
            q = np.asarray(message.attitude, dtype=float)
            C = None if message.attitude_cov is None else np.asarray(message.attitude_cov, dtype=float)
            if q.shape != (4,) or not np.all(np.isfinite(q)) or (C is not None and (
                    C.shape != (3, 3) or not np.all(np.isfinite(C)))):
                raise MalformedMessage(f"attitude: a fix needs a finite quaternion (4,) and covariance (3, 3), got "
                                       f"{message.attitude!r}, {message.attitude_cov!r}")
            cov = None if C is None else np.triu(C) + np.triu(C, 1).T
        else:
            v = message.floats()
            if v.size not in (4, 10) or not np.all(np.isfinite(v)):
                raise MalformedMessage(f"attitude expects qw qx qy qz [+ 6 covariance values], got {message.values!r}")
            q, cov = v[:4], (v[4:][_SYM] if v.size == 10 else None)
        nq = float(np.linalg.norm(q))
        if not 0.5 < nq < 2.0:
            raise MalformedMessage(f"attitude: quaternion norm {nq:.3g} is not near 1")
        R = cov if self.params.use_fix_covariance else None  # type: ignore[attr-defined]
        return Observation(message.t, np.zeros(3), Attitude(self.params, self.context, q / nq), R)  # type: ignore[arg-type]

    def align_state(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray,
                    observations: Sequence[Observation], R: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Initial attitude: the chordal mean of the static fixes (fusion.api.AlignsState), covariance the
        mean fix covariance / N; the q rows and columns of P0 are replaced. No observations: unchanged."""
        if not observations:
            return x0, P0
        qs = np.array([o.model.q_m for o in observations])  # type: ignore[attr-defined]
        qs *= np.where(qs @ qs[0] < 0.0, -1.0, 1.0)[:, None]
        q = quat.normalize(qs.sum(axis=0))
        Rs = [o.R if o.R is not None else R for o in observations]
        if any(r is None for r in Rs):
            return x0, P0
        P_theta = np.mean(Rs, axis=0) / len(observations)
        x0 = np.array(x0, dtype=float, copy=True)
        P0 = np.array(P0, dtype=float, copy=True)
        x0[self._q] = q
        P0[self._q, :] = 0.0
        P0[:, self._q] = 0.0
        P0[self._q, self._q] = covariance_in_state(q, P_theta)
        return x0, P0
