"""Measurement ``position``: a position fix of the antenna/receiver, with lever arm (paper 000 eq. 53)."""
from __future__ import annotations

import warnings
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import (MAX_MAGNITUDE, BuildContext, ConfigError, Fix, MalformedMessage, MeasurementModel, Message,
                        Observation, Params)
from fusion.lapack import lapack


_SYM3 = np.array([[3, 4, 5], [4, 6, 7], [5, 7, 8]])   # indices into a 9-value fix of its symmetric covariance


def static_R(fixes: np.ndarray, full: bool = False) -> np.ndarray:
    """R from fixes (N, m) taken at one fixed point (paper 000 sec. V-B): ``diag(sd_x^2, sd_y^2, ...)``
    (m^2), or the full sample covariance with ``full=True``."""
    fixes = np.asarray(fixes, dtype=float)
    if fixes.ndim != 2 or fixes.shape[0] < 2:
        raise ValueError(f"expected at least 2 fixes of shape (N, m), got {fixes.shape}")
    S = np.atleast_2d(np.cov(fixes.T))
    return S if full else np.diag(np.diag(S))


class PositionParams(Params):
    """YAML parameters of ``position``."""

    lever_arm: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="receiver position in the body frame (m, FRD): r_ABPS of eq. 53")
    dim: int | None = Field(None, ge=1, le=3, description="measure the first dim components of p "
                            "(default: all of them; 2 for a horizontal fix on a 3-D state)")
    offset_block: str | None = Field(None, description="name of a state block (e.g. a Gauss-Markov block of "
                                     "the ins process) added to the fix: a slowly varying error of the fix (m)")
    offset_axes: tuple[int, ...] | None = Field(None, description="the fix's axes (0 x, 1 y, 2 z) the offset "
                                                "block adds to, one per block element (default: the first ones)")
    use_fix_covariance: bool = Field(True, description="use the covariance a solver attaches to its fix as R "
                                     "(False: always the sensor's configured noise)")
    bridge: Literal["first_order", "imu"] = Field(
        "first_order", description="how a fix with an age (of the position age s before its stamp) is bridged to "
        "the state: first_order p - v age, or imu: + age^2/2 the IMU's acceleration and the lever arm turned back "
        "by its rate (the model then reads the input samples: fusion.api.UsesInput; state blocks q, v, ba, bw)")
    accel_sd: float = Field(0.0, ge=0, le=1e6, description="m/s^2: the acceleration the bridge does not account "
                            "for (first_order: the vehicle's own; imu: its change over the age); R += (accel_sd "
                            "age^2 / 2)^2 per axis")
    gravity: float = Field(9.80665, gt=0, description="m/s^2, down: g_n of the imu bridge's acceleration "
                           "C_b^n (f - b_a) + g_n (only its vertical part; a 2-D fix barely sees it)")


class Position(MeasurementModel[PositionParams]):
    """Position fix ``z = p + C_b^n(q) r`` (paper 000 eq. 53), z (m, navigation frame, NED).

    Works on any layout with a ``p`` block (2-D or 3-D); ``dim`` is the size of ``p`` (or the ``dim``
    param). The lever arm r (body frame FRD, m) is rotated by the attitude quaternion block ``q``
    (``C_b^n`` computed from q / |q|); a state without a quaternion block has no attitude, so the lever
    arm is then ignored, with a warning at build time (``self.note`` says so).

    ``observe``: a message of ``dim`` values (or 3 for a 2-D state) is the fix, with the sensor's
    configured R; a message of 9 values ``x y z cxx cxy cxz cyy cyz czz`` (as ``ols_trilateration``
    emits) carries its own covariance, used as R (leading dim x dim block).

    A fix with an ``age`` (of the position that long before its stamp: ``ols_trilateration`` when the filter has
    integrated inputs past the cycle's mean range time) is bridged by ``bridge``: ``first_order``
    (:class:`AgedPosition`, ``p - v age``) or ``imu`` (:class:`ImuAgedPosition`, second order from the latest IMU
    sample); ``accel_sd`` adds what the bridge leaves out to R.

    ``offset_block`` (with ``offset_axes``): a state block added to the fix's axes, ``z = p + C_b^n r + o``:
    a slowly varying error of the fix modelled as a state (e.g. the height error of a 2-D fix that assumes
    a known height, an ``ins`` ``gauss_markov`` block), so that it is not averaged as white noise.

    Jacobian: ``dz/dp = I``, ``dz/dq = d(C_b^n(q) r)/dq`` (analytic, fusion.quaternion.rotate_jacobian),
    ``dz/do = 1`` on the offset's axes.
    """

    name: ClassVar[str] = "position"
    Params: ClassVar[type[Params]] = PositionParams

    def __init__(self, params: PositionParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        p = self.params
        layout = self.context.layout
        if layout is None or "p" not in layout:
            blocks = [b.name for b in layout.blocks] if layout is not None else []
            raise ConfigError(f"position needs a state with a position block 'p' (this state has {blocks})")
        self._p = layout["p"]
        np_ = self._p.stop - self._p.start
        self.dim = p.dim if p.dim is not None else min(np_, 3)
        if self.dim > np_:
            raise ConfigError(f"position: dim {self.dim} but the state's p block has {np_} elements")
        self.n = layout.n
        self.carries_R = bool(p.use_fix_covariance)   # a 9- or 10-value fix carries its covariance
        self._v = layout["v"] if "v" in layout and layout["v"].stop - layout["v"].start >= self.dim else None
        self.lever_arm = np.asarray(p.lever_arm, dtype=float)
        qblocks = [b.name for b in layout.blocks if b.kind == "quaternion"]
        self._q: slice | None = None
        self.note = ""
        if np.any(self.lever_arm):
            if qblocks:
                self._q = layout["q" if "q" in qblocks else qblocks[0]]
                # R(q) r = outer(q, q).ravel() @ _Kr: the rotated lever arm in one product (times |q|^2)
                self._Kr = quat.rotation_form(self.lever_arm)
            else:
                self.note = ("lever_arm ignored: the state has no attitude (quaternion block), so the fix is "
                             "taken as the position p itself")
                warnings.warn(f"position: {self.note}", stacklevel=2)
        self.linear = self._q is None   # z = p (the first dim elements): affine; with a lever arm, not
        self._off, self._off_axes = self._offset(layout)
        self._u: np.ndarray | None = None      # the latest input sample (imu bridge)
        if p.bridge == "imu":
            missing = [b for b in ("v", "q") if b not in layout]
            if missing or self._v is None:
                raise ConfigError(f"position: bridge 'imu' needs state blocks v and q (an ins process); this state "
                                  f"has {[b.name for b in layout.blocks]}")
            self._qi = layout["q"]
            self._ba = layout["ba"] if "ba" in layout else None
            self._bw = layout["bw"] if "bw" in layout else None
            # fusion.api.UsesInput only in this mode: the scheduler then integrates the inputs up to each of the
            # sensor's messages and hands over the latest sample
            self.take_input = self._take_input

    def _take_input(self, t: float | None, u: np.ndarray | None) -> None:
        """fusion.api.UsesInput (bridge 'imu'): the latest IMU sample ``ax ay az gx gy gz`` (m/s^2, rad/s, FRD)."""
        self._u = None if u is None else np.asarray(u, dtype=float)

    def _offset(self, layout) -> tuple[slice | None, np.ndarray]:
        """The offset block's slice and the fix axes it adds to (ConfigError when the block is missing or
        the axes do not fit it)."""
        p = self.params
        if p.offset_block is None:
            if p.offset_axes is not None:
                raise ConfigError("position: offset_axes needs offset_block")
            return None, np.zeros(0, dtype=int)
        if p.offset_block not in layout:
            raise ConfigError(f"position: offset_block {p.offset_block!r} is no block of the state (blocks are "
                              f"{[b.name for b in layout.blocks]}; the ins process makes one with gauss_markov:)")
        sl = layout[p.offset_block]
        own = [b for b, s in (("position", self._p), ("velocity", self._v), ("attitude", self._q))
               if s is not None and sl.start < s.stop and s.start < sl.stop]
        if own:
            raise ConfigError(f"position: offset_block {p.offset_block!r} is the state's {own[0]} block, which the "
                              "model already measures; name an error block (e.g. an ins gauss_markov block)")
        size = sl.stop - sl.start
        axes = np.asarray(p.offset_axes if p.offset_axes is not None else range(size), dtype=int)
        if axes.size != size or len(set(axes.tolist())) != size or np.any(axes < 0) or np.any(axes >= self.dim):
            raise ConfigError(f"position: offset_axes {axes.tolist()} must name {size} distinct axes of the "
                              f"{self.dim}-D fix (block {p.offset_block!r} has {size} elements)")
        return sl, axes

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted fix (..., dim) (m) for states x (..., n): eq. 53, plus the offset block if configured."""
        x = np.asarray(x, dtype=float)
        z = x[..., self._p.start:self._p.start + self.dim]
        if self._q is None:
            z = z.copy()
        else:
            q = x[..., self._q]
            qq = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
            arm = (qq @ self._Kr) / qq[..., quat.NORM_TERMS].sum(axis=-1, keepdims=True)   # C_b^n r
            z = z + arm[..., :self.dim]
        if self._off is not None:
            z[..., self._off_axes] += x[..., self._off]
        return z

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (dim, n) at x (n,)."""
        x = np.asarray(x, dtype=float)
        H = np.zeros((self.dim, self.n))
        H[np.arange(self.dim), self._p.start + np.arange(self.dim)] = 1.0
        if self._q is not None:
            H[:, self._q] = quat.rotate_jacobian(x[self._q], self.lever_arm)[:self.dim]
        if self._off is not None:
            H[self._off_axes, np.arange(self._off.start, self._off.stop)] = 1.0
        return H

    def position_from(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The position block value (dim,) that makes ``h`` equal the fix z at attitude x (n,): z - C_b^n r.
        For initialising p from a first fix of a receiver that is off the state's origin."""
        z = np.array(z, dtype=float)[:self.dim]
        x = np.asarray(x, dtype=float)
        if self._off is not None:
            z[self._off_axes] -= x[self._off]
        if self._q is None:
            return z
        return z - quat.rotate(x[self._q], self.lever_arm)[:self.dim]

    def observe(self, message: Message | Fix) -> Observation | None:
        """Observation of a solver's typed :class:`fusion.api.Fix` (position, covariance, age), or of a fix
        message of a recording: ``dim`` (or 3) coordinates, or 9 values with the covariance, or 10: the
        covariance and the fix's age (s: the position is of that long before the message time).
        MalformedMessage, with the reason, for another count, a value that is no finite number, a negative
        age or a covariance that is not positive definite."""
        if isinstance(message, Fix):
            return self._observe_fix(message)
        z = message.floats()
        if z.ndim != 1:   # sequences where numbers belong (a message from another source)
            raise MalformedMessage(f"position expects numbers, got {message.values!r}")
        if not np.all(np.isfinite(z)):
            raise MalformedMessage(f"position: non-finite value in {message.values!r}")
        if np.any(np.abs(z) > MAX_MAGNITUDE):
            raise MalformedMessage(f"position: a value beyond {MAX_MAGNITUDE:g} in {message.values!r} (its square "
                                   "overflows float64)")
        R = None
        model: MeasurementModel = self
        if z.size == 10:
            if self._v is None:
                raise MalformedMessage("position: a fix with an age needs a state with a velocity block 'v'")
            if z[9] < 0.0:
                raise MalformedMessage(f"position: negative fix age {z[9]}")
            if z[9] > 0.0:
                model = self._aged(float(z[9]))
            z = z[:9]
        if z.size == 9:
            R = self._fix_R(z[_SYM3])           # the upper triangle x y z cxx cxy cxz cyy cyz czz, mirrored
            z = z[:3]
        elif z.size not in (self.dim, 3) or z.size < self.dim:
            raise MalformedMessage(f"position expects {self.dim} coordinates (or 9 values: x y z and the "
                                   f"covariance upper triangle), got {z.size}")
        return Observation(message.t, z[:self.dim], model, self._bridge_R(R, model))

    def _fix_R(self, cov: np.ndarray) -> np.ndarray | None:
        """R from a fix's covariance (3, 3) (its leading dim x dim block), or None with
        ``use_fix_covariance: false``; MalformedMessage when a filter could not factor it."""
        if not self.params.use_fix_covariance:
            return None
        R = cov[:self.dim, :self.dim]
        bad = R.shape != (self.dim, self.dim)
        if not bad:   # one sum (a nan or inf propagates), the element test only when it is not finite
            total = float(R.sum())
            bad = total - total != 0.0 and not np.all(np.isfinite(R))
        if bad:       # (dpotrf below passes NaN through)
            raise MalformedMessage(f"position: the fix's covariance {R.tolist()} (m^2) is not a finite "
                                   f"{self.dim} x {self.dim} matrix")
        if lapack.dpotrf(R, lower=1)[1] != 0:   # np.linalg.cholesky's test (its lower triangle), ~5x cheaper
            raise MalformedMessage(f"position: the fix's covariance {R.tolist()} (m^2) is not positive "
                                   "definite")
        return R

    def _observe_fix(self, fix: Fix) -> Observation:
        z = np.asarray(fix.value, dtype=float)
        # not (max |z| <= MAX_MAGNITUDE): a nan, an inf or a too large coordinate, in one reduction
        if z.ndim != 1 or z.size < self.dim or not (float(np.abs(z).max()) <= MAX_MAGNITUDE):
            raise MalformedMessage(f"position: a fix needs {self.dim} finite coordinates, got {fix.value!r}")
        if fix.age < 0.0:
            raise MalformedMessage(f"position: negative fix age {fix.age}")
        model: MeasurementModel = self
        if fix.age > 0.0:
            if self._v is None:
                raise MalformedMessage("position: a fix with an age needs a state with a velocity block 'v'")
            model = self._aged(float(fix.age))
        R = self._fix_R(np.asarray(fix.cov, dtype=float)) if fix.cov is not None else None
        return Observation(fix.t, z[:self.dim], model, self._bridge_R(R, model))

    def _aged(self, age: float) -> "AgedPosition":
        """The model of a fix ``age`` s old: bridged first order, or with the latest IMU sample (bridge imu;
        first order until the first sample)."""
        if self.params.bridge == "imu" and self._u is not None:
            return ImuAgedPosition(self, age, self._u)
        return AgedPosition(self, age)

    def _bridge_R(self, R: np.ndarray | None, model: MeasurementModel) -> np.ndarray | None:
        """R plus what the bridge of an aged fix leaves out: (accel_sd age^2 / 2)^2 on each axis (the
        acceleration over the age, or its change with the imu bridge). Unchanged without an age or accel_sd,
        or without a fix covariance (the sensor's configured R, which the run applies, is left as it is)."""
        sd = self.params.accel_sd
        if R is None or not sd or not isinstance(model, AgedPosition):
            return R
        R = R.copy()
        R.flat[::self.dim + 1] += (0.5 * sd * model.age * model.age) ** 2
        return R


class AgedPosition(MeasurementModel):
    """A fix of the position ``age`` seconds before its time stamp: ``z = p - v age + C_b^n r`` (the
    position model bridged to the update time with the state's velocity, first order). Bound per
    observation by :meth:`Position.observe` for a 10-value fix message (``ols_trilateration`` when the
    belief it compensated with is later than the cycle's mean range time); not a registry component."""

    name: ClassVar[str] = "position (aged)"

    def __init__(self, base: Position, age: float):
        super().__init__(base.params, base.context)
        self.base, self.age, self.dim = base, age, base.dim
        self._v = base._v

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted fix (..., dim) (m) for states x (..., n)."""
        x = np.asarray(x, dtype=float)
        return self.base.h(x) - self.age * x[..., self._v.start:self._v.start + self.dim]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (dim, n) at x (n,)."""
        H = self.base.jacobian(x)
        H[np.arange(self.dim), self._v.start + np.arange(self.dim)] -= self.age
        return H

    def position_from(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The position block value that makes ``h(x)`` equal z."""
        x = np.asarray(x, dtype=float)
        return self.base.position_from(z, x) + self.age * x[self._v.start:self._v.start + self.dim]


class ImuAgedPosition(AgedPosition):
    """A fix of the receiver ``age`` s before its stamp, bridged to the second order with the IMU sample u
    (``ax ay az gx gy gz``, m/s^2 and rad/s, FRD) taken at the update: with the state's bias-corrected specific
    force f = u_a - b_a and rate w = u_w - b_w,

        z = p - v age + age^2/2 (C_b^n f + g_n) + C_b^n (r - age w x r + age^2/2 w x (w x r))   (+ offset)

    the position p(t - age) = p - v age + a age^2 / 2 to the jerk term, and the lever arm r as it was age s
    earlier (turned back by the rate, to the second order). Equivalently the lever arm is replaced by the body
    vector ``r_e = r - age w x r + age^2/2 (f + w x (w x r))``; f and w depend on the state's biases (ba, bw blocks, when present),
    so a sigma-point filter carries their uncertainty. Not a registry component."""

    name: ClassVar[str] = "position (aged, imu)"

    def __init__(self, base: Position, age: float, u: np.ndarray):
        super().__init__(base, age)
        self._f, self._w = u[:3], u[3:6]
        self._qs, self._ba, self._bw = base._qi, base._ba, base._bw
        self._g = np.array([0.0, 0.0, 0.5 * age * age * base.params.gravity])

    def _body(self, x: np.ndarray) -> np.ndarray:
        """r_e - r (..., 3): the body vector (m, FRD) the bridge adds to the lever arm."""
        a = self.age
        f = self._f - x[..., self._ba] if self._ba is not None else np.broadcast_to(self._f, x.shape[:-1] + (3,))
        w = self._w - x[..., self._bw] if self._bw is not None else np.broadcast_to(self._w, x.shape[:-1] + (3,))
        r = self.base.lever_arm
        wr = np.cross(w, r)
        return 0.5 * a * a * (f + np.cross(w, wr)) - a * wr      # C(t - age) r = C (r - age w x r + age^2/2 w x (w x r))

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted fix (..., dim) (m) for states x (..., n)."""
        x = np.asarray(x, dtype=float)
        d = quat.rotate(x[..., self._qs], self._body(x)) + self._g
        return super().h(x) + d[..., :self.dim]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (dim, n) at x (n,)."""
        x = np.asarray(x, dtype=float)
        H = super().jacobian(x)
        q = x[self._qs]
        H[:, self._qs] += quat.rotate_jacobian(q, self._body(x))[:self.dim]
        C = quat.to_matrix(q)[:self.dim]
        a = self.age
        if self._ba is not None:
            H[:, self._ba] -= 0.5 * a * a * C
        if self._bw is not None:
            # w = u_w - b_w: d(-a w x r)/dw = a [r]x; d(w x (w x r))/dw = (w.r) I + w r^T - 2 r w^T
            r = self.base.lever_arm
            w = self._w - x[self._bw]
            rx = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
            dw = a * rx + 0.5 * a * a * (float(w @ r) * np.eye(3) + np.outer(w, r) - 2.0 * np.outer(r, w))
            H[:, self._bw] -= C @ dw
        return H

    def position_from(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The position block value that makes ``h(x)`` equal z."""
        x = np.asarray(x, dtype=float)
        d = quat.rotate(x[self._qs], self._body(x)) + self._g
        return super().position_from(z, x) - d[:self.dim]
