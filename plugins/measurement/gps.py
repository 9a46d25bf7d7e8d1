"""Measurement ``gps``: a loosely coupled GPS fix, local-NED position and horizontal velocity (paper 002 eqs. 6, 10)."""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from fusion import quaternion as quat
from fusion.api import BuildContext, ConfigError, MalformedMessage, MeasurementModel, Message, Observation, Params


class GpsParams(Params):
    """YAML parameters of ``gps``. Standard deviations are of one fix at HDOP = ``hdop_ref``."""

    horizontal_sd: float = Field(2.5, gt=0, description="north/east position sd (m) at hdop_ref")
    vertical_sd: float = Field(4.0, gt=0, description="down position sd (m) at hdop_ref")
    velocity_sd: float = Field(0.1, gt=0, description="north/east velocity sd (m/s) at hdop_ref")
    hdop_scaling: bool = Field(True, description="scale the horizontal sds by HDOP / hdop_ref and the vertical "
                               "one by VDOP / hdop_ref (VDOP from GSA; else 1.5 HDOP)")
    hdop_ref: float = Field(1.0, gt=0, description="HDOP at which the sds above hold")
    use_velocity: bool = Field(True, description="fuse the RMC/VTG velocity (False: position only)")
    lever_arm: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="antenna position in the body "
                                                  "frame (m, FRD): the position C_b^n l and, with the velocity, "
                                                  "the antenna's C_b^n (w x l) from the gyro")
    accuracy: Literal["dop", "receiver"] = Field("dop", description="dop: the sds above scaled by the DOPs; "
                                                 "receiver: the receiver's own 1-sd accuracies (hacc, vacc of a "
                                                 "12-value fix, decoder gps_fields) with the sds above as floors, "
                                                 "as PX4 EKF2 does")


class Gps(MeasurementModel):
    """GPS fix from the ``nmea`` decoder: ``z = [pn pe pd vn ve]`` (m, m/s, local NED), loosely coupled.

    .. math::
        h(x) = [p + C_b^n(q) r_{arm};\\ v_N;\\ v_E]

    (eq. 10's position and velocity rows). With a ``lever_arm`` r the velocity rows are the antenna's,
    ``v + C_b^n(q) (w x r)``, w the body rate (rad/s, FRD) from the latest gyro sample (fusion.api.UsesInput)
    corrected by the state's gyro bias ``bw`` and scale ``sw`` where the state has them (the INS's
    ``(u - bw) / sw``): an antenna 2 m ahead moves 0.87 m/s sideways in a 25 deg/s turn, far beyond a
    receiver's 0.1 m/s. An epoch without velocity (no RMC/VTG, or ``use_velocity: false``) is
    a position-only observation.
    R is diagonal, built per fix: ``horizontal_sd``, ``vertical_sd``, ``velocity_sd`` scaled by the
    dilution of precision when ``hdop_scaling`` (the receiver's own accuracy figure), divided by N for a
    fix averaged over N epochs (the decoder's origin fix); with ``accuracy: receiver`` (a fix from the
    ``gps_fields`` decoder, which carries the receiver's 1-sd ``hacc vacc``) the sds are
    ``max(horizontal_sd, hacc)``, ``max(vertical_sd, vacc)``, as PX4 EKF2 and ArduPilot EKF3 use their
    GPS noise parameters as floors. Jacobian analytic.
    """

    name: ClassVar[str] = "gps"
    carries_R = True    # R from the fix's HDOP/VDOP (R_of)
    Params: ClassVar[type[Params]] = GpsParams

    def __init__(self, params: GpsParams | None = None, context: BuildContext | None = None,
                 velocity: bool | None = None):
        super().__init__(params, context)
        p: GpsParams = self.params  # type: ignore[assignment]
        layout = self.context.layout
        if layout is None or "p" not in layout or "v" not in layout:
            raise ConfigError("gps needs a state with position 'p' and velocity 'v' blocks (3 elements each)")
        self._p, self._v = layout["p"], layout["v"]
        if self._p.stop - self._p.start != 3 or self._v.stop - self._v.start != 3:
            raise ConfigError("gps needs 3-D position and velocity blocks")
        self.n = layout.n
        self.velocity = p.use_velocity if velocity is None else velocity
        self.dim = 5 if self.velocity else 3
        self.lever_arm = np.asarray(p.lever_arm, dtype=float)
        self._q = layout["q"] if np.any(self.lever_arm) and "q" in layout else None
        if np.any(self.lever_arm) and self._q is None:
            raise ConfigError("gps: a lever_arm needs an attitude block 'q'")
        self._rows = np.r_[np.arange(self._p.start, self._p.stop), self._v.start, self._v.start + 1][:self.dim]
        self._position_only = self if not self.velocity else None
        self._rate: np.ndarray | None = None         # the latest gyro sample (rad/s, FRD), for w x r
        if self._q is not None and self.velocity:
            # an instance attribute, so that only a model with a lever arm is a UsesInput (the scheduler then
            # integrates the inputs up to each fix; without one the runs of inputs stay as they were)
            self.take_input = self._take_input
            self._bw = layout["bw"] if "bw" in layout else None
            self._sw = layout["sw"] if "sw" in layout else None

    def _take_input(self, t: float | None, u: np.ndarray | None) -> None:
        """fusion.api.UsesInput: the latest IMU sample [accel (3), gyro (3)] before the fix."""
        self._rate = None if u is None or np.size(u) < 6 else np.asarray(u, dtype=float)[3:6].copy()

    def _body_rate(self, x: np.ndarray) -> np.ndarray | None:
        """w (..., 3) rad/s: the gyro sample corrected by the state's bias and scale (None before a sample)."""
        if self._rate is None:
            return None
        w = self._rate - x[..., self._bw] if self._bw is not None else np.broadcast_to(self._rate, x.shape[:-1] + (3,))
        return w / x[..., self._sw] if self._sw is not None else w

    def position_only(self) -> "Gps":
        if self._position_only is None:
            self._position_only = Gps(self.params, self.context, velocity=False)  # type: ignore[arg-type]
        return self._position_only

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted fix (..., dim) for states x (..., n)."""
        x = np.asarray(x, dtype=float)
        z = x[..., self._rows]
        if self._q is not None:
            z = z.copy()
            q = x[..., self._q]
            z[..., :3] += quat.rotate(q, self.lever_arm)
            w = self._body_rate(x) if self.dim == 5 else None
            if w is not None:
                z[..., 3:5] += quat.rotate(q, np.cross(w, self.lever_arm))[..., :2]
        return z

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (dim, n) at x (n,)."""
        H = np.zeros((self.dim, self.n))
        H[np.arange(self.dim), self._rows] = 1.0
        if self._q is not None:
            x = np.asarray(x, float)
            q = x[self._q]
            H[:3, self._q] = quat.rotate_jacobian(q, self.lever_arm)
            w = self._body_rate(x) if self.dim == 5 else None
            if w is not None:
                H[3:5, self._q] = quat.rotate_jacobian(q, np.cross(w, self.lever_arm))[:2]
                # d(w x r)/dw = -[r x]; w = (u - bw) / sw: dw/dbw = -1/sw, dw/dsw = -w/sw (per axis)
                C = quat.to_matrix(q)[:2]
                r = self.lever_arm
                Cr = C @ np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])   # C [r x]
                inv_s = 1.0 / x[self._sw] if self._sw is not None else np.ones(3)
                if self._bw is not None:
                    H[3:5, self._bw] = Cr * inv_s
                if self._sw is not None:
                    H[3:5, self._sw] = Cr * (w * inv_s)
        return H

    def position_from(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Position block (3,) that makes the predicted antenna position equal z[:3] at attitude x."""
        z = np.asarray(z, dtype=float)[:3]
        if self._q is None:
            return z.copy()
        return z - quat.rotate(np.asarray(x, float)[self._q], self.lever_arm)

    def R_of(self, hdop: float, vdop: float, averaged: float, velocity: bool,
             hacc: float = np.nan, vacc: float = np.nan) -> np.ndarray:
        """Diagonal R (m^2, m^2/s^2) of one fix."""
        p: GpsParams = self.params  # type: ignore[assignment]
        if p.accuracy == "receiver":
            sh = max(p.horizontal_sd, hacc) if np.isfinite(hacc) and hacc > 0 else p.horizontal_sd
            sv = max(p.vertical_sd, vacc) if np.isfinite(vacc) and vacc > 0 else p.vertical_sd
            var = [sh ** 2] * 2 + [sv ** 2] + ([p.velocity_sd ** 2] * 2 if velocity else [])
            return np.diag(np.asarray(var) / max(averaged, 1.0))
        kh = kv = 1.0
        if p.hdop_scaling and np.isfinite(hdop) and hdop > 0:
            kh = hdop / p.hdop_ref
            kv = (vdop if np.isfinite(vdop) and vdop > 0 else 1.5 * hdop) / p.hdop_ref
        var = [(p.horizontal_sd * kh) ** 2] * 2 + [(p.vertical_sd * kv) ** 2]
        if velocity:
            var += [(p.velocity_sd * kh) ** 2] * 2
        return np.diag(np.asarray(var) / max(averaged, 1.0))

    def observe(self, message: Message) -> Observation | None:
        """Observation of a decoded fix ``pn pe pd vn ve hdop vdop satellites quality averaged``
        (the ``nmea`` decoder's output; ``gps_fields`` adds the receiver's ``hacc vacc``, m); 3 or 5 plain
        values are a fix with the nominal sds."""
        v = message.floats()
        hacc = vacc = np.nan
        if v.size == 12:
            z, hdop, vdop, averaged, hacc, vacc = v[:5], v[5], v[6], v[9], v[10], v[11]
        elif v.size == 10:
            z, hdop, vdop, averaged = v[:5], v[5], v[6], v[9]
        elif v.size in (3, 5):
            z, hdop, vdop, averaged = v, np.nan, np.nan, 1.0
        else:
            raise MalformedMessage(f"gps expects a decoded fix of 10 values (nmea decoder), 12 (gps_fields) or "
                                   f"3/5 values, got {v.size}")
        if not np.all(np.isfinite(z[:3])):
            raise MalformedMessage(f"gps: non-finite position in {message.values!r}")
        with_v = self.velocity and z.size == 5 and bool(np.all(np.isfinite(z[3:5])))
        model = self if with_v or not self.velocity else self.position_only()
        z = z[:5] if with_v else z[:3]
        return Observation(message.t, z.copy(), model, self.R_of(hdop, vdop, averaged, with_v, hacc, vacc))
