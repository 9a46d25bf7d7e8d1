"""Quaternion helpers, vectorised over leading axes (shapes ``(..., 4)``).

Convention (DESIGN.md): Hamilton product, scalar first ``q = [w x y z]``, body-to-navigation: the
rotation matrix ``C_b^n = to_matrix(q)`` maps FRD body vectors into the NED navigation frame
(paper 000 eq. 35). ``scipy.spatial.transform.Rotation.from_quat(q, scalar_first=True)`` is the same
rotation. These are our own rather than scipy's Rotation because the filters' hot path evaluates
them on whole sigma-point arrays where building a Rotation object costs more than the arithmetic.

Speed: products and rotation matrices are bilinear/quadratic forms evaluated as one small matrix
product on the stacked outer products (``outer(q, p).reshape(16) @ T``), a handful of numpy calls
whatever the number of points.

``to_matrix`` and ``rotate`` divide by ``|q|^2``: they give the rotation of the *direction* of q, so a
slightly non-unit quaternion (a sigma point) still gives an orthonormal matrix.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = [
    "multiply", "conjugate", "normalize", "identity", "left_matrix", "right_matrix", "xi",
    "to_matrix", "from_matrix", "rotate", "rotate_jacobian", "exp", "log", "from_euler",
    "to_euler", "angle_between", "from_gravity", "PRODUCT_FORM", "ROTATION_FORM", "NORM_TERMS",
    "rotation_form", "conj_multiply_floats", "slerp_floats",
]

# --------------------------------------------------------------------------- structure constants
# Hamilton product p (x) q = einsum("jki,...j,...k->...i", _T, p, q).
_T = np.zeros((4, 4, 4))
for _j, _k, _i, _s in [
    (0, 0, 0, 1), (1, 1, 0, -1), (2, 2, 0, -1), (3, 3, 0, -1),      # w = p0q0 - pv.qv
    (0, 1, 1, 1), (1, 0, 1, 1), (2, 3, 1, 1), (3, 2, 1, -1),        # x = p0q1 + p1q0 + p2q3 - p3q2
    (0, 2, 2, 1), (2, 0, 2, 1), (3, 1, 2, 1), (1, 3, 2, -1),        # y = p0q2 + p2q0 + p3q1 - p1q3
    (0, 3, 3, 1), (3, 0, 3, 1), (1, 2, 3, 1), (2, 1, 3, -1),        # z = p0q3 + p3q0 + p1q2 - p2q1
]:
    _T[_j, _k, _i] = _s
_T16 = _T.reshape(16, 4)

# Homogeneous rotation matrix R(q) = |q|^2 C_b^n(q), a quadratic form: R.ravel() = outer(q,q).ravel() @ _K.
# (paper 000 eq. 35 for unit q; each cross term split evenly between (i,j) and (j,i) so _K is symmetric.)
_K4 = np.zeros((4, 4, 3, 3))


def _term(i: int, j: int, r: int, c: int, coef: float) -> None:
    _K4[i, j, r, c] += coef / 2.0
    _K4[j, i, r, c] += coef / 2.0


for _r, _sq in enumerate([(1, -1, -1), (-1, 1, -1), (-1, -1, 1)]):  # diagonal: q0^2 +- q1^2 +- ...
    _term(0, 0, _r, _r, 1.0)
    for _a, _sgn in zip((1, 2, 3), _sq):
        _term(_a, _a, _r, _r, _sgn)
_term(1, 2, 0, 1, 2.0); _term(0, 3, 0, 1, -2.0)   # C01 = 2(q1q2 - q0q3)
_term(1, 3, 0, 2, 2.0); _term(0, 2, 0, 2, 2.0)    # C02 = 2(q1q3 + q0q2)
_term(1, 2, 1, 0, 2.0); _term(0, 3, 1, 0, 2.0)    # C10 = 2(q1q2 + q0q3)
_term(2, 3, 1, 2, 2.0); _term(0, 1, 1, 2, -2.0)   # C12 = 2(q2q3 - q0q1)
_term(1, 3, 2, 0, 2.0); _term(0, 2, 2, 0, -2.0)   # C20 = 2(q1q3 - q0q2)
_term(2, 3, 2, 1, 2.0); _term(0, 1, 2, 1, 2.0)    # C21 = 2(q2q3 + q0q1)
_K = _K4.reshape(16, 9)
_DIAG16 = np.array([0, 5, 10, 15])

#: The structure constants as public, read-only forms, for models that evaluate many quaternions in one
#: product: ``multiply(p, q) = outer(p, q).ravel() @ PRODUCT_FORM`` (16, 4); ``|q|^2 C_b^n(q)`` raveled
#: = ``outer(q, q).ravel() @ ROTATION_FORM`` (16, 9); ``|q|^2 = outer(q, q).ravel()[NORM_TERMS].sum()``.
PRODUCT_FORM = _T16.view()
ROTATION_FORM = _K.view()
NORM_TERMS = _DIAG16.view()
for _a in (PRODUCT_FORM, ROTATION_FORM, NORM_TERMS):
    _a.flags.writeable = False


def rotation_form(v: np.ndarray) -> np.ndarray:
    """(16, 3) form K_v of the rotation of a fixed vector v (3,): ``|q|^2 C_b^n(q) v = outer(q, q).ravel()
    @ K_v`` for any (..., 4) q (divide by ``|q|^2`` for the rotation by q / |q|)."""
    return _K.reshape(16, 3, 3) @ np.asarray(v, dtype=float)


def _outer16(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stacked outer products (..., 16) of (..., 4) arrays."""
    return (a[..., :, None] * b[..., None, :]).reshape(*np.broadcast_shapes(a.shape[:-1], b.shape[:-1]), 16)


# --------------------------------------------------------------------------- algebra
def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternions ``[1 0 0 0]`` of shape ``shape + (4,)``."""
    q = np.zeros(shape + (4,))
    q[..., 0] = 1.0
    return q


def multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p (x) q`` (..., 4), broadcast over leading axes."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    return _outer16(p, q) @ _T16


def conjugate(q: np.ndarray) -> np.ndarray:
    """``[w, -x, -y, -z]``: the inverse rotation for a unit quaternion."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: np.ndarray) -> np.ndarray:
    """``q / |q|`` (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q / np.sqrt(np.einsum("...i,...i->...", q, q))[..., None]


def left_matrix(q: np.ndarray) -> np.ndarray:
    """L(q) (..., 4, 4) with ``q (x) p = L(q) p``."""
    return np.einsum("jki,...j->...ik", _T, np.asarray(q, dtype=float))


def right_matrix(p: np.ndarray) -> np.ndarray:
    """R(p) (..., 4, 4) with ``q (x) p = R(p) q``. For ``p = [0, w]`` it is ``-Omega(w)`` of paper 000
    eq. 39 (corrected), so ``q_dot = -0.5 Omega q = 0.5 q (x) [0, w]``."""
    return np.einsum("jki,...k->...ij", _T, np.asarray(p, dtype=float))


def xi(q: np.ndarray) -> np.ndarray:
    """Xi(q) (..., 4, 3) with ``q (x) [0, v] = Xi(q) v``; ``q_dot = 0.5 Xi(q) w`` (w body rate, rad/s)."""
    return left_matrix(q)[..., :, 1:]


# --------------------------------------------------------------------------- rotation matrices
def to_matrix(q: np.ndarray) -> np.ndarray:
    """C_b^n (..., 3, 3) of (..., 4) quaternions (paper 000 eq. 35, divided by |q|^2)."""
    q = np.asarray(q, dtype=float)
    qq = _outer16(q, q)
    return (qq @ _K / qq[..., _DIAG16].sum(axis=-1, keepdims=True)).reshape(q.shape[:-1] + (3, 3))


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``C_b^n(q) v`` (..., 3): body vector v (FRD) expressed in the navigation frame (NED)."""
    C = to_matrix(q)
    v = np.asarray(v, dtype=float)
    return np.einsum("...ij,...j->...i", C, v)


def rotate_jacobian(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """d(C_b^n(q) v)/dq (..., 3, 4), for the |q|^2-normalised C (so J q = 0: no sensitivity to the norm)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    n2 = np.einsum("...i,...i->...", q, q)[..., None, None]
    Rv = np.einsum("kjrc,...j,...c->...rk", _K4, q, v) * 2.0         # d(R(q) v)/dq, R homogeneous
    Cv = np.einsum("...rk,...k->...r", Rv, q) / (2.0 * n2[..., 0])     # Euler: R(q) v = 0.5 dRv/dq q
    return (Rv - 2.0 * Cv[..., :, None] * q[..., None, :]) / n2


def from_matrix(C: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) with ``w >= 0`` of rotation matrices C_b^n (..., 3, 3) (Shepperd's method)."""
    C = np.asarray(C, dtype=float)
    tr = np.trace(C, axis1=-2, axis2=-1)
    d = np.stack([tr, C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]], axis=-1)
    k = np.argmax(d, axis=-1)
    cands = np.stack([
        np.stack([1 + tr, C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], -1),
        np.stack([C[..., 2, 1] - C[..., 1, 2], 1 + 2 * C[..., 0, 0] - tr, C[..., 0, 1] + C[..., 1, 0], C[..., 0, 2] + C[..., 2, 0]], -1),
        np.stack([C[..., 0, 2] - C[..., 2, 0], C[..., 0, 1] + C[..., 1, 0], 1 + 2 * C[..., 1, 1] - tr, C[..., 1, 2] + C[..., 2, 1]], -1),
        np.stack([C[..., 1, 0] - C[..., 0, 1], C[..., 0, 2] + C[..., 2, 0], C[..., 1, 2] + C[..., 2, 1], 1 + 2 * C[..., 2, 2] - tr], -1),
    ], axis=-2)
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


# --------------------------------------------------------------------------- exp / log / Euler angles
def exp(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternion (..., 4) of a rotation vector (..., 3) (rad): ``[cos(t/2), sin(t/2) u]``, t = |rotvec|."""
    rotvec = np.asarray(rotvec, dtype=float)
    half = 0.5 * np.sqrt(np.einsum("...i,...i->...", rotvec, rotvec))
    k = 0.5 * np.sinc(half / np.pi)                    # sin(t/2)/t, exact at t = 0
    return np.concatenate([np.cos(half)[..., None], k[..., None] * rotvec], axis=-1)


def log(q: np.ndarray) -> np.ndarray:
    """Rotation vector (..., 3) (rad, angle in [0, pi]) of quaternions (..., 4) (normalised first)."""
    q = normalize(q)
    q = np.where(q[..., :1] < 0, -q, q)
    nv = np.sqrt(np.einsum("...i,...i->...", q[..., 1:], q[..., 1:]))
    angle = 2.0 * np.arctan2(nv, q[..., 0])
    scale = np.where(nv > 1e-12, angle / np.where(nv > 1e-12, nv, 1.0), 2.0 / np.maximum(q[..., 0], 1e-300))
    return scale[..., None] * q[..., 1:]


def from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Quaternion (..., 4) of aerospace Euler angles (rad): C_b^n = Rz(yaw) Ry(pitch) Rx(roll)
    (scipy ``Rotation.from_euler("ZYX", [yaw, pitch, roll])``)."""
    cr, sr = np.cos(np.asarray(roll, float) / 2), np.sin(np.asarray(roll, float) / 2)
    cp, sp = np.cos(np.asarray(pitch, float) / 2), np.sin(np.asarray(pitch, float) / 2)
    cy, sy = np.cos(np.asarray(yaw, float) / 2), np.sin(np.asarray(yaw, float) / 2)
    return np.stack([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ], axis=-1)


def to_euler(q: np.ndarray) -> np.ndarray:
    """Aerospace Euler angles ``[roll, pitch, yaw]`` (..., 3) (rad) of quaternions (..., 4)."""
    q0, q1, q2, q3 = np.moveaxis(normalize(q), -1, 0)
    roll = np.arctan2(2 * (q0 * q1 + q2 * q3), 1 - 2 * (q1 * q1 + q2 * q2))
    pitch = np.arcsin(np.clip(2 * (q0 * q2 - q1 * q3), -1.0, 1.0))
    yaw = np.arctan2(2 * (q0 * q3 + q1 * q2), 1 - 2 * (q2 * q2 + q3 * q3))
    return np.stack([roll, pitch, yaw], axis=-1)


def angle_between(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) between attitudes q1 and q2 (..., 4); sign of either is irrelevant."""
    d = np.abs(np.einsum("...i,...i->...", normalize(q1), normalize(q2)))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


def from_gravity(specific_force: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """Levelling: attitude (4,) from the mean specific force (3,) (m/s^2, FRD) of a static IMU, NED.

    A static accelerometer reads ``f_b = C_n^b (-g_n)`` with ``g_n = [0 0 g]``, so
    ``roll = atan2(-f_y, -f_z)``, ``pitch = atan2(f_x, sqrt(f_y^2 + f_z^2))``; yaw is unobservable
    from gravity and is given.
    """
    fx, fy, fz = np.asarray(specific_force, dtype=float)
    roll = np.arctan2(-fy, -fz)
    pitch = np.arctan2(fx, np.hypot(fy, fz))
    return from_euler(roll, pitch, yaw)


# --------------------------------------------------------------------------- one pair, as floats
def conj_multiply_floats(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    """``conj(a) (x) b`` for one pair of quaternions as floats (a scalar path: no array overhead)."""
    aw, ax, ay, az = a[0], -a[1], -a[2], -a[3]
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)



def slerp_floats(q0: np.ndarray, q1: np.ndarray, f: float) -> list[float]:
    """Spherical interpolation from unit q0 to q1 (shorter arc) at fraction f; unit result (floats: this
    runs once per estimate, where Python floats beat numpy calls on 4-vectors)."""
    return slerp_lists(q0.tolist(), q1.tolist(), f)


def slerp_lists(a: list[float], b: list[float], f: float) -> list[float]:
    """:func:`slerp_floats` of two quaternions given as lists of 4 floats (the same operations)."""
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    if dot < 0.0:
        b, dot = [-v for v in b], -dot
    if dot > 0.9995:  # nearly equal: normalised lerp (error < 1e-9 rad)
        q = [u + f * (v - u) for u, v in zip(a, b)]
        n = math.sqrt(sum(v * v for v in q))
        return [v / n for v in q]
    th = math.acos(dot)
    s = math.sin(th)
    w0, w1 = math.sin((1.0 - f) * th) / s, math.sin(f * th) / s
    return [w0 * u + w1 * v for u, v in zip(a, b)]
