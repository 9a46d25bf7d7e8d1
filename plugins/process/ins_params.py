"""Parameters of the ``ins`` process model (paper 000 sec. V-A): gravity, noise densities (SI units)."""
from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from fusion.api import Params, ProcessModel

STANDARD_GRAVITY = 9.80665          # m/s^2
EARTH_RATE = 7.292115e-5            # rad/s (WGS84)

# ADIS16364 data sheet (Analog Devices, Rev. B): angular random walk 2.0 deg/sqrt(h), velocity random walk
# 0.12 m/s/sqrt(h), in-run bias stability 25 deg/h and 0.1 mg. The bias random-walk densities are those
# stabilities spread over ~100 s (stability / sqrt(100 s)), a common engineering reading of the sheet.
ADIS16364_GYRO_ND = 2.0 * np.pi / 180.0 / 60.0            # rad/s/sqrt(Hz)  (= 5.82e-4)
ADIS16364_ACCEL_ND = 0.12 / 60.0                          # m/s^2/sqrt(Hz)  (= 2.0e-3)
ADIS16364_GYRO_BIAS_RW = 25.0 * np.pi / 180.0 / 3600.0 / 10.0   # rad/s^2/sqrt(Hz) (= 1.2e-5)
ADIS16364_ACCEL_BIAS_RW = 0.1e-3 * STANDARD_GRAVITY / 10.0      # m/s^3/sqrt(Hz)  (= 9.8e-5)

Density = float | tuple[float, float, float]



class GaussMarkovBlock(Params):
    """A first-order Gauss-Markov state block appended to the INS state (``gauss_markov:`` in the ``ins``
    params): ``size`` elements, each ``b_dot = -b / tau + w``, stationary sd ``sd`` (units of whatever a
    measurement model adds it to, e.g. m for a fix's height error). Exact discretisation over dt:
    ``b_k+1 = exp(-dt / tau) b_k``, ``Q = sd^2 (1 - exp(-2 dt / tau))`` per element."""

    name: str = Field(..., pattern=r"^[A-Za-z_][A-Za-z0-9_]*$", description="block name in the state")
    size: int = Field(1, ge=1, le=6, description="number of elements")
    tau: float = Field(..., gt=0, le=1e9, description="correlation time (s)")
    sd: float = Field(..., gt=0, le=1e6, description="stationary standard deviation (units of the quantity)")


def somigliana_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """Normal gravity (m/s^2) on the WGS84 ellipsoid (Somigliana) with the free-air correction -3.086e-6 h."""
    s2 = np.sin(np.radians(latitude_deg)) ** 2
    g0 = 9.7803253359 * (1.0 + 0.00193185265241 * s2) / np.sqrt(1.0 - 0.00669437999013 * s2)
    return float(g0 - 3.086e-6 * height_m)


class InsParams(Params):
    """YAML parameters of ``ins``. Noise densities are one value (all axes) or three (x y z, FRD).

    Data-sheet conversions: ARW [deg/sqrt(h)] * pi/180 / 60 = rad/s/sqrt(Hz);
    VRW [m/s/sqrt(h)] / 60 = m/s^2/sqrt(Hz). Defaults are ADIS16364-class figures.
    """

    gravity: float | None = Field(None, gt=0, description="local gravity g (m/s^2); default: from latitude, "
                                  "else the system's gravity (context.extra['gravity']), else 9.80665")
    latitude_deg: float | None = Field(None, ge=-90, le=90, description="latitude (deg) for g and Earth rate")
    height_m: float = Field(0.0, description="ellipsoidal height (m) for g from latitude")
    earth_rate: bool = Field(False, description="subtract the Earth rate C_n^b w_ie (eq. 38; needs latitude)")
    eta: float = Field(0.0, ge=0, description="quaternion norm-correction gain eta (1/s) of eq. 50; eta*dt < 1")
    integration: Literal["euler", "trapezoidal"] = Field(
        "euler", description="euler: eqs. 40-41 as in the paper; trapezoidal: mean of C_k f and C_k+1 f, "
        "p += v dt + a dt^2/2 (second order)")
    accel_noise_density: Density = Field(ADIS16364_ACCEL_ND, description="white noise of f (m/s^2/sqrt(Hz))")
    gyro_noise_density: Density = Field(ADIS16364_GYRO_ND, description="white noise of w (rad/s/sqrt(Hz))")
    accel_bias_rw: Density = Field(ADIS16364_ACCEL_BIAS_RW, description="accel bias random walk (m/s^3/sqrt(Hz))")
    gyro_bias_rw: Density = Field(ADIS16364_GYRO_BIAS_RW, description="gyro bias random walk (rad/s^2/sqrt(Hz))")
    quat_norm_variance: float = Field(0.0, ge=0, description="variance added along q per step so Q is "
                                      "positive definite (the norm direction is otherwise noise-free)")
    max_specific_force: float | None = Field(None, gt=0, description="sensor range (m/s^2, any axis)")
    max_rate: float | None = Field(None, gt=0, description="sensor range (rad/s, any axis)")
    hold_after: float | None = Field(None, gt=0, description="s: a sample held longer than this (an IMU gap) "
                                     "is integrated over hold_after only (counted from the sample's time), "
                                     "then the state coasts (attitude and velocity kept) with the hold noise "
                                     "below over the rest of the gap (None: the sample is held over the whole "
                                     "gap, no hold noise)")
    # The hold noise is the vehicle's own motion while no IMU sample says what it does: its acceleration and
    # rotation rates as first-order Gauss-Markov processes (sd, correlation time), in the navigation frame;
    # the coast's errors are their integrals (ins_batch.add_hold_noise).
    hold_accel_sd: float = Field(1.0, ge=0, description="m/s^2: the vehicle's acceleration during a hold (NED, "
                                 "per axis; default: a ground vehicle's braking and turning)")
    hold_yaw_rate_sd: float = Field(0.3, ge=0, description="rad/s: its rate about down during a hold (a "
                                    "vehicle turns freely)")
    hold_tilt_rate_sd: float = Field(0.02, ge=0, description="rad/s: its rates about north and east during a "
                                     "hold (a ground vehicle stays near level; raise it for an aircraft)")
    hold_motion_tau: float = Field(2.0, gt=0, description="s: correlation time of those motions (a missed "
                                   "sample costs ~nothing, a gap much longer than tau grows as a random walk)")
    hold_max_attitude_sd: float = Field(0.5, gt=0, description="rad: the hold noise's attitude sd of one "
                                        "prediction at most (per axis): what a linearised (EKF) quaternion "
                                        "block can carry; a vehicle that turns further during a gap needs a "
                                        "re-alignment (recovery)")
    align_gyro_bias: bool = Field(True, description="initial alignment also takes the mean static gyro "
                                  "rate as the gyro bias")
    states: Literal[10, 16, 22] = Field(16, description="state set (paper 002): 10 [p v q], 16 + biases "
                                        "[ba bw], 22 + scale factors [sa sw] (eqs. 11-13); see ins_states.py")
    accel_scale_rw: Density = Field(0.0, description="22 states: accelerometer scale-factor random walk "
                                    "(1/s^0.5, eq. 13)")
    gyro_scale_rw: Density = Field(0.0, description="22 states: gyro scale-factor random walk (1/s^0.5, eq. 13)")
    renormalize: bool = Field(True, description="bring the mean quaternion back to unit norm after each "
                              "step; false leaves the norm to eq. 50 (eta) or the quat_norm pseudo-observation")

    gauss_markov: list[GaussMarkovBlock] = Field(
        default_factory=list, description="first-order Gauss-Markov blocks appended to the state (a slowly "
        "varying measurement error, e.g. a fix's height error; ins_gauss_markov.py); none: the state as above")

    @model_validator(mode="before")
    @classmethod
    def _replaced_hold_parameters(cls, data: object) -> object:
        if isinstance(data, dict):
            for old, new in (("hold_accel_rw", "hold_accel_sd (m/s^2)"),
                             ("hold_rate_rw", "hold_yaw_rate_sd and hold_tilt_rate_sd (rad/s)")):
                if old in data:
                    raise ValueError(f"{old} was replaced by {new} and hold_motion_tau (s): the hold noise is "
                                     "now the vehicle's own motion (Gauss-Markov acceleration and rates), "
                                     "accrued over the whole gap however it is cut into steps; see "
                                     "docs/results/imu_dropout.md")
        return data

    @model_validator(mode="after")
    def _earth_rate_needs_latitude(self) -> "InsParams":
        if self.earth_rate and self.latitude_deg is None:
            raise ValueError("earth_rate: true needs latitude_deg")
        if self.states != 22 and (np.any(np.asarray(self.accel_scale_rw)) or np.any(np.asarray(self.gyro_scale_rw))):
            raise ValueError("accel_scale_rw / gyro_scale_rw need states: 22 (the scale-factor states)")
        names = [b.name for b in self.gauss_markov]
        taken = {"p", "v", "q", "ba", "bw", "sa", "sw"}
        if len(set(names)) != len(names) or taken & set(names):
            raise ValueError(f"gauss_markov: block names must be unique and not one of {sorted(taken)}, got {names}")
        return self


def density_variance(density: Density) -> np.ndarray:
    d = np.broadcast_to(np.asarray(density, dtype=float), (3,))
    if np.any(d < 0):
        raise ValueError(f"noise densities must be >= 0, got {density}")
    return d * d


class InsProcess(ProcessModel):
    """What the ``ins`` family shares (``Ins``, ``InsStates``, ``InsGaussMarkov``): the component's name,
    its parameters and the IMU input ``u = [ax ay az gx gy gz]`` (m/s^2, rad/s, FRD); non-linear."""

    name: ClassVar[str] = "ins"
    Params: ClassVar[type[Params]] = InsParams
    input_dim: int = 6
    input_fields = ("ax", "ay", "az", "gx", "gy", "gz")   # m/s^2, rad/s, FRD body frame
    linear: bool = False
