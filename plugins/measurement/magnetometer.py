"""Measurement ``magnetometer``: the Earth's field seen in the body frame, ``h = C_n^b(q) m_n`` (paper 002 sec. 2.3).

For one state (the EKF) h and its Jacobian run in C when the kernel is built (_magnetometer_kernel.c, setup.py
KERNELS; no per-call numpy overhead), the same formulas to the last bit or two; the numpy code
is the reference and runs otherwise (``FUSION_PURE_PYTHON=1``, fusion/kernels.py)."""
from __future__ import annotations

import math
from typing import ClassVar, Literal, Sequence

import numpy as np
from pydantic import Field, model_validator

from fusion import kernels
from fusion import quaternion as quat
from fusion.api import (BuildContext, ConfigError, Event, MalformedMessage, MeasurementModel, Message, Observation, Params,
                        RejectedMessage)


def earth_field(declination_deg: float, inclination_deg: float, intensity: float) -> np.ndarray:
    """m_n (3,) in NED from declination D (east of true north), inclination I (below the horizon) and
    intensity F: ``F [cos I cos D, cos I sin D, sin I]``."""
    D, I = np.radians(declination_deg), np.radians(inclination_deg)
    return intensity * np.array([np.cos(I) * np.cos(D), np.cos(I) * np.sin(D), np.sin(I)])


class FieldParams(Params):
    """The local reference field: ``field_ned`` or declination / inclination / intensity (a World
    Magnetic Model / IGRF value for the place and date); none of them: the recording's header, else the IGRF
    at its origin and date (fusion_plugins.measurement.earth_field)."""

    field_ned: tuple[float, float, float] | None = Field(None, description="m_n (NED, the sensor's units, e.g. uT)")
    declination_deg: float | None = Field(None, ge=-180, le=180, description="east of true north positive")
    inclination_deg: float | None = Field(None, ge=-90, le=90, description="below the horizon positive")
    intensity: float | None = Field(None, gt=0, description="total field (the sensor's units, e.g. uT)")

    @model_validator(mode="after")
    def _one_way(self):
        angles = (self.declination_deg, self.inclination_deg, self.intensity)
        if getattr(self, "field_source", "config") == "alignment":
            if self.field_ned is not None or any(a is not None for a in angles):
                raise ValueError("field_source: alignment estimates the field: give no field_ned, "
                                 "declination_deg, inclination_deg or intensity")
            return self
        if any(a is not None for a in angles) and any(a is None for a in angles):
            raise ValueError("give all of declination_deg, inclination_deg and intensity (a World Magnetic Model "
                             "value for the place and date), or field_ned, or none (the recording's header, "
                             "else the IGRF at its origin and date)")
        if self.field_ned is not None and any(a is not None for a in angles):
            raise ValueError("give field_ned or the declination/inclination/intensity, not both")
        if self.field_ned is not None and not np.any(self.field_ned):
            raise ValueError("field_ned must not be zero")
        return self

    def field(self) -> np.ndarray | None:
        """m_n (3,) NED from these parameters, or None when they give none."""
        from fusion_plugins.measurement.earth_field import config_field

        return config_field(self)


class MagnetometerParams(FieldParams):
    """YAML parameters of ``magnetometer``."""

    direction_only: bool = Field(False, description="measure the unit vector m_b / |m_b| (insensitive to the "
                                 "intensity; noise sd then in rad)")
    align: Literal["improved_triad", "triad", "none"] = Field(
        "improved_triad", description="initial alignment over the static start (initial.align_s) from the mean "
        "field and the mean specific force (solvers.triad); none: the attitude is left to the process")
    updates: bool = Field(True, description="fuse the samples after the static start (false: the magnetometer "
                          "only aligns, as 'without magnetometer' in paper 002 sec. 5)")
    align_accel_sd: float = Field(0.01, gt=0, description="sd (m/s^2) of the static mean specific force beyond "
                                  "the state's accelerometer-bias uncertainty (vibration, residual tilt)")
    field_source: Literal["config", "alignment"] = Field(
        "config", description="config: the field above (none given: the recording header's, else the IGRF at its "
        "origin and date); alignment: estimated over initial.align_s as the mean "
        "sample rotated to NED by the attitude the alignment set before this sensor's turn (a sensor listed "
        "earlier, e.g. the onboard estimator's first attitude: docs/import.md); needs align: none")
    max_heading_sd_deg: float = Field(10.0, gt=0, description="field_source: alignment: the field is estimated "
                                      "only if the aligned attitude's heading sd (from P0) is at most this; "
                                      "else every sample is rejected, saying why")

    @model_validator(mode="after")
    def _not_circular(self):
        if self.field_source == "alignment" and self.align != "none":
            raise ValueError(f"field_source: alignment takes the attitude from elsewhere; align: {self.align} "
                             "would take it from the field it estimates (set align: none)")
        return self


# Heading sd (rad) after an alignment without a magnetometer sample: a uniform heading has sd pi / sqrt(3);
# a linearised quaternion filter cannot carry more (the q block's errors are about unit components)
HEADING_UNKNOWN_SD = math.pi / math.sqrt(3.0)
_FLIP = np.array([1.0, -1.0, -1.0, -1.0])
_ROT, _NORM = quat.ROTATION_FORM, quat.NORM_TERMS
_K4 = quat.ROTATION_FORM.reshape(4, 4, 3, 3)          # [i, j, r, c]: R(q)_rc = q_i q_j K4[i, j, r, c]
_ndarray = np.ndarray
_einsum = np.einsum
#: the compiled h and Jacobian for one state, or None (not built, or FUSION_PURE_PYTHON=1 at import)
KERNEL = kernels.load("fusion_plugins.measurement._magnetometer_kernel")


class Magnetometer(MeasurementModel):
    """Three-axis magnetometer, ``z = C_n^b(q) m_n`` (FRD body frame, units of m_n), the direct vector
    measurement (the alternative to the TRIAD attitude measurement, ``solvers.triad``).

    ``C_n^b = C_b^n(q)^T = C_b^n(q*)`` (computed from q / |q|), so ``dh/dq = rotate_jacobian(q*, m_n)
    diag(1, -1, -1, -1)`` (analytic; no sensitivity along q). A disturbed field (a vehicle, a bridge)
    shows as a large NIS: use a chi2 gate. ``direction_only`` measures ``m_b / |m_b|`` against
    ``C_n^b m_n / |m_n|`` instead.
    """

    name: ClassVar[str] = "magnetometer"
    Params: ClassVar[type[Params]] = MagnetometerParams
    dim: int = 3

    def __init__(self, params: MagnetometerParams | None = None, context: BuildContext | None = None):
        super().__init__(params, context)
        layout = self.context.layout
        if layout is None or "q" not in layout or layout.block("q").kind != "quaternion":
            raise ConfigError("magnetometer needs a state with an attitude quaternion block 'q'")
        self._q = layout["q"]
        self.n = layout.n
        self.direction_only = bool(self.params.direction_only)  # type: ignore[attr-defined]
        self.m_n: np.ndarray | None = None      # field_source: alignment: set by align_state
        self._info: dict = {"source": "alignment"}
        if self.params.field_source == "config":  # type: ignore[attr-defined]
            from fusion_plugins.measurement.earth_field import resolve_field

            m, self._info = resolve_field(self.params, self.context)
            self._set_field(m)
        self._start: str | None = None           # how align_state set the attitude
        self._aligned = False      # set by align_state: the static start is over
        self._heading_sd: float | None = None   # deg, field_source: alignment: of the attitude it rotated by
        self.events: list[Event] = []          # an alignment without samples: its warning, until take_events()

    def _set_field(self, m: np.ndarray) -> None:
        self.m_n = m / np.linalg.norm(m) if self.direction_only else np.asarray(m, dtype=float)

    def h(self, x: np.ndarray) -> np.ndarray:
        """Predicted field (..., 3) in the body frame for states x (..., n)."""
        if self.m_n is None:
            raise ConfigError("magnetometer: field_source: alignment needs initial.align_s > 0 (the field is "
                              "estimated over the alignment window)")
        if type(x) is _ndarray and x.ndim == 1:
            if KERNEL is not None:
                out = np.empty(3)
                try:
                    KERNEL.h(x, self._q.start, self.m_n, out)
                    return out
                except (TypeError, ValueError):      # not a contiguous float64 x: the numpy code below
                    pass
            # One state (the EKF): quat.rotate's own operations on (4,), without its broadcasting (cheaper,
            # the same numbers: C = q q^T K / |q|^2, then C m_n).
            q = x[self._q] * _FLIP
            qq = (q[:, None] * q).reshape(16)
            C = (qq @ _ROT / qq[_NORM].sum(axis=-1, keepdims=True)).reshape(3, 3)
            return _einsum("...ij,...j->...i", C, self.m_n)
        q = np.asarray(x, dtype=float)[..., self._q]
        return quat.rotate(q * _FLIP, self.m_n)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx (3, n) at x (n,)."""
        if self.m_n is None:
            self.h(x)
        if KERNEL is not None:
            H = np.empty((3, self.n))
            try:
                KERNEL.jacobian(x, self._q.start, self.m_n, H)
                return H
            except (TypeError, ValueError):          # not a contiguous float64 x (n,): the numpy code below
                pass
        return self._jacobian_numpy(x)

    def _jacobian_numpy(self, x: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` in numpy (the compiled kernel's reference)."""
        # quat.rotate_jacobian(q*, m_n) diag(1, -1, -1, -1) by its own operations on (4,) (the same numbers)
        q = np.asarray(x, dtype=float)[self._q] * _FLIP
        n2 = _einsum("...i,...i->...", q, q)
        Rv = _einsum("kjrc,...j,...c->...rk", _K4, q, self.m_n) * 2.0      # d(R(q) m)/dq, R homogeneous
        Cv = _einsum("...rk,...k->...r", Rv, q) / (2.0 * n2)
        H = np.zeros((3, self.n))
        H[:, self._q] = (Rv - 2.0 * Cv[:, None] * q) / n2 * _FLIP
        return H

    def align_state(self, x0: np.ndarray, P0: np.ndarray, u_mean: np.ndarray,
                    observations: Sequence[Observation], R: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Initial attitude by TRIAD / Improved TRIAD (paper 002 sec. 3.1, fusion.api.AlignsState) from the
        mean field of the static start and the mean specific force ``u_mean[:3]`` (corrected by the state's
        ``ba`` / ``sa`` when it has them): body gravity ``g_b = -f_b``, reference ``g_n = [0, 0, g]``.

        Covariance (solvers.triad.attitude_covariance): the accelerometer side is the state's bias
        covariance plus ``align_accel_sd^2``, the magnetometer side the sensor's R itself (its calibration
        residual does not average away over a static start); the q block of P0 becomes G P_theta G^T and
        its correlation with ``ba`` (a bias tilts the levelled attitude) G J1 P_ba."""
        from fusion_plugins.measurement.attitude import covariance_in_state, error_to_quaternion
        from fusion_plugins.solvers.triad import attitude_covariance, solve

        method = self.params.align  # type: ignore[attr-defined]
        self._aligned = True
        if self.params.field_source == "alignment" and observations:  # type: ignore[attr-defined]
            from fusion_plugins.measurement.attitude import error_to_quaternion

            q0 = np.asarray(x0, dtype=float)[self._q]
            G = error_to_quaternion(q0 / np.linalg.norm(q0))          # G^T G = I / 4
            P_theta = 16.0 * G.T @ np.asarray(P0, float)[self._q, self._q] @ G
            self._heading_sd = float(np.degrees(np.sqrt(max(P_theta[2, 2], 0.0))))
            if self._heading_sd <= self.params.max_heading_sd_deg:  # type: ignore[attr-defined]
                self._set_field(np.mean(quat.rotate(q0, np.array([o.z for o in observations])), axis=0))
            return x0, P0
        if method == "none":
            self._start = "attitude not aligned by the magnetometer (align: none)"
            return x0, P0
        if not observations:
            self._start = ("roll and pitch from gravity over the static start; heading unknown (no magnetometer "
                           "sample): from the GPS velocity once moving")
            return self._heading_unknown(x0, P0)
        self._start = (f"roll, pitch and heading by {method} from gravity and the magnetic field over the static "
                       f"start ({len(observations)} magnetometer samples)")
        layout = self.context.layout
        x0 = np.array(x0, dtype=float, copy=True)
        P0 = np.array(P0, dtype=float, copy=True)
        f = np.asarray(u_mean, dtype=float)[:3].copy()
        ba = layout["ba"] if "ba" in layout else None  # type: ignore[operator]
        if ba is not None:
            f -= x0[ba]
        if "sa" in layout:  # type: ignore[operator]
            f /= x0[layout["sa"]]  # type: ignore[index]
        b1 = -f
        b2 = np.mean([o.z for o in observations], axis=0)
        S1 = np.eye(3) * self.params.align_accel_sd ** 2  # type: ignore[attr-defined]
        if ba is not None:
            S1 = S1 + P0[ba, ba]
        S2 = R if R is not None else np.eye(3) * (1e-2 * np.linalg.norm(b2)) ** 2
        g_n = np.array([0.0, 0.0, np.linalg.norm(b1)])
        s1 = float(np.sqrt(np.trace(S1) / 3)) / np.linalg.norm(b1)
        s2 = float(np.sqrt(np.trace(S2) / 3)) / np.linalg.norm(b2)
        C = solve(method, b1, b2, g_n, self.m_n, s1, s2)
        P_theta, J1 = attitude_covariance(method, b1, b2, g_n, self.m_n, S1, S2, C)
        q = quat.from_matrix(C)
        x0[self._q] = q
        P0[self._q, :] = 0.0
        P0[:, self._q] = 0.0
        P0[self._q, self._q] = covariance_in_state(q, P_theta)
        if ba is not None:
            cross = error_to_quaternion(q) @ J1 @ P0[ba, ba]
            P0[self._q, ba] = cross
            P0[ba, self._q] = cross.T
        return x0, P0

    def _heading_unknown(self, x0: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) of an alignment without a magnetometer sample: the attitude the process levelled (roll
        and pitch from the mean specific force) with its tilt sd from the accelerometer side of TRIAD, and
        the heading unknown (sd HEADING_UNKNOWN_SD rad) instead of the config's guess held at its sd; one
        ``warning`` in ``events``."""
        from fusion_plugins.measurement.attitude import covariance_in_state

        layout = self.context.layout
        x0 = np.array(x0, dtype=float, copy=True)
        P0 = np.array(P0, dtype=float, copy=True)
        q = x0[self._q]
        q = quat.normalize(q) if np.any(q) else np.array([1.0, 0.0, 0.0, 0.0])
        var = self.params.align_accel_sd ** 2  # type: ignore[attr-defined]
        if "ba" in layout:  # type: ignore[operator]
            var += float(np.trace(P0[layout["ba"], layout["ba"]])) / 3.0  # type: ignore[index]
        g = float(self.context.extra.get("gravity", 9.80665))
        tilt = var / g ** 2
        P0[self._q, :] = 0.0
        P0[:, self._q] = 0.0
        P0[self._q, self._q] = covariance_in_state(q, np.diag([tilt, tilt, HEADING_UNKNOWN_SD ** 2]))
        self.events.append(Event(math.nan, "warning", self.context.sensor,
                                 "no magnetometer sample in the alignment window (initial.align_s): heading "
                                 f"unknown (sd {math.degrees(HEADING_UNKNOWN_SD):.0f} deg), roll and pitch from "
                                 "the accelerometer; the heading comes from the later magnetometer samples or "
                                 "the GPS velocity"))
        return x0, P0

    def info(self) -> dict:
        """The summary's ``info`` (fusion.api.ReportsInfo): where the reference field came from and how the
        starting attitude was found."""
        out = {"reference_field": dict(self._info)}
        if self.m_n is not None and self._info.get("source") == "alignment":
            out["reference_field"]["field_ned"] = [round(float(v), 4) for v in self.m_n]
        if self._start is not None:
            out["start"] = self._start
        return out

    def take_events(self) -> list[Event]:
        """The events since the last call (an alignment without samples), forgotten once taken."""
        events, self.events = self.events, []
        return events

    def observe(self, message: Message) -> Observation | None:
        """Observation of a sample ``mx my mz`` (FRD); None after the static start with ``updates: false``."""
        if self._aligned and not self.params.updates:  # type: ignore[attr-defined]
            return None
        if self.m_n is None and self._aligned:
            if self._heading_sd is not None:
                raise RejectedMessage(
                    f"magnetometer: field_source: alignment: the attitude the alignment set has a heading sd of "
                    f"{self._heading_sd:.0f} deg (> max_heading_sd_deg {self.params.max_heading_sd_deg:g}): "  # type: ignore[attr-defined]
                    "nothing gave it a heading (no initial_attitude line in the log? docs/import.md)")
            raise RejectedMessage("magnetometer: field_source: alignment found no magnetometer sample in the "
                                  "alignment window (initial.align_s): the reference field is unknown")
        z = message.floats()
        if z.shape != (3,):
            raise MalformedMessage(f"magnetometer expects 3 finite values (mx my mz), got {message.values!r}")
        a, b, c = z.tolist()
        total = a + b + c
        # a nan or an inf among them, in plain floats (~4x cheaper than np.isfinite); an overflowing sum of
        # finite values is checked one by one
        if total - total != 0.0 and not np.all(np.isfinite(z)):
            raise MalformedMessage(f"magnetometer expects 3 finite values (mx my mz), got {message.values!r}")
        if self.direction_only:
            nz = float(np.linalg.norm(z))
            if nz == 0.0:
                raise MalformedMessage("magnetometer: zero field")
            z = z / nz
        return Observation(message.t, z, self)
