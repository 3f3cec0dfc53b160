"""Rotation and Euler-rate kinematics shared by the plant and the controller (ZYX, NWU/FLU)."""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.state import FloatArray


@njit
def rot_body_to_earth(phi: float, theta: float, psi: float) -> FloatArray:
    """Rt(gamma) = Rz(psi) Ry(theta) Rx(phi): maps FLU body vectors to NWU earth vectors."""
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    return rot_at(cph, sph, cth, sth, math.cos(psi), math.sin(psi))


# the nine entries of Rt, row by row
RotEntries = tuple[float, float, float, float, float, float, float, float, float]


@njit
def rot_entries(cph: float, sph: float, cth: float, sth: float, cps: float, sps: float) -> RotEntries:
    """:func:`rot_at`'s entries as scalars, row by row: the one place their expressions are
    written, so the matrix and the array-free products below give the same bits."""
    return (
        cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps,
        cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps,
        -sth, sph * cth, cph * cth,
    )  # fmt: skip


@njit
def rot_euler_entries(phi: float, theta: float, psi: float) -> RotEntries:
    """:func:`rot_body_to_earth`'s entries as scalars, row by row, from the Euler angles (no
    array made: the control law and the sensors take them several times a tick)."""
    cph, sph, cth, sth = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    return rot_entries(cph, sph, cth, sth, math.cos(psi), math.sin(psi))


@njit
def rot_at(cph: float, sph: float, cth: float, sth: float, cps: float, sps: float) -> FloatArray:
    """:func:`rot_body_to_earth` from the Euler angles' cosines and sines."""
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2], r[1, 0], r[1, 1], r[1, 2], r[2, 0], r[2, 1], r[2, 2] = rot_entries(
        cph, sph, cth, sth, cps, sps
    )
    return r


@njit
def earth_to_body_at(
    cph: float, sph: float, cth: float, sth: float, cps: float, sps: float, vx: float, vy: float, vz: float
) -> tuple[float, float, float]:
    """``Rt^T v`` (earth NWU -> body FLU) from the Euler angles' cosines and sines, without the
    matrix: the same sums as ``rot_at(...)[:, i] . v`` (so the same bits), for code that runs
    once per derivative evaluation and should not allocate."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot_entries(cph, sph, cth, sth, cps, sps)
    return (
        r00 * vx + r10 * vy + r20 * vz,
        r01 * vx + r11 * vy + r21 * vz,
        r02 * vx + r12 * vy + r22 * vz,
    )


@njit
def euler_rate_matrix(phi: float, theta: float) -> FloatArray:
    """E(gamma) with omega = E(gamma) d(gamma)/dt."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    e = np.zeros((3, 3))
    e[0, 0] = 1.0
    e[0, 2] = -sth
    e[1, 1] = cph
    e[1, 2] = sph * cth
    e[2, 1] = -sph
    e[2, 2] = cph * cth
    return e


@njit
def euler_rates(phi: float, theta: float, p: float, q: float, r: float) -> FloatArray:
    """E(gamma)^-1 omega = d(gamma)/dt."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth = math.cos(theta)
    qr = q * sph + r * cph
    out = np.empty(3)
    out[0] = p + qr * math.tan(theta)
    out[1] = q * cph - r * sph
    out[2] = qr / cth
    return out


@njit
def mat_vec(m: FloatArray, v: FloatArray) -> FloatArray:
    """``m @ v`` for a 3x3 ``m``: written out, because numba's ``@`` calls BLAS (dgemv and an
    output allocation behind a library call), about 60 ns more a product at this size."""
    out = np.empty(3)
    for i in range(3):
        out[i] = m[i, 0] * v[0] + m[i, 1] * v[1] + m[i, 2] * v[2]
    return out


@njit
def mat_t_vec(m: FloatArray, v: FloatArray) -> FloatArray:
    """``m.T @ v`` for a 3x3 ``m`` (earth -> body with ``m`` body -> earth), written out."""
    out = np.empty(3)
    for i in range(3):
        out[i] = m[0, i] * v[0] + m[1, i] * v[1] + m[2, i] * v[2]
    return out


@njit
def mat_mat(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for 3x3 matrices, written out (see :func:`mat_vec`)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


@njit
def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit
def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    a = angle_rad - 2.0 * math.pi * math.ceil((angle_rad - math.pi) / (2.0 * math.pi))
    # the quotient can round across an integer near +-pi: fold the one-ulp overshoot back
    if a > math.pi:
        a -= 2.0 * math.pi
    elif a <= -math.pi:
        a += 2.0 * math.pi
    return a


# --- unit quaternions q = (w, x, y, z) of the body-to-earth rotation (FLU -> NWU), the same
# rotation as rot_body_to_earth: R(q) = Rz(psi) Ry(theta) Rx(phi). Hamilton product,
# right-handed (Sola 2017, "Quaternion kinematics for the error-state Kalman filter", s. 2-4).


@njit
def quat_from_euler(phi: float, theta: float, psi: float) -> FloatArray:
    """The quaternion of the ZYX Euler angles (w >= 0 is not enforced)."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    q = np.empty(4)
    q[0] = cr * cp * cy + sr * sp * sy
    q[1] = sr * cp * cy - cr * sp * sy
    q[2] = cr * sp * cy + sr * cp * sy
    q[3] = cr * cp * sy - sr * sp * cy
    return q


@njit
def rot_from_quat(q: FloatArray) -> FloatArray:
    """R(q), body to earth."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return r


@njit
def euler_from_rot(r: FloatArray) -> tuple[float, float, float]:
    """ZYX Euler angles (phi, theta, psi) of a body-to-earth rotation matrix."""
    s = max(-1.0, min(1.0, -r[2, 0]))
    return math.atan2(r[2, 1], r[2, 2]), math.asin(s), math.atan2(r[1, 0], r[0, 0])


@njit
def quat_mul(a: FloatArray, b: FloatArray) -> FloatArray:
    """The Hamilton product a (x) b: rotate by b, then by a."""
    out = np.empty(4)
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    return out


@njit
def quat_from_rotvec(vx: float, vy: float, vz: float) -> FloatArray:
    """Exp of a rotation vector [rad] (axis times angle); exact, with the series near 0."""
    angle = math.sqrt(vx * vx + vy * vy + vz * vz)
    q = np.empty(4)
    if angle < 1e-8:
        q[0], s = 1.0 - angle * angle / 8.0, 0.5 - angle * angle / 48.0
    else:
        q[0], s = math.cos(0.5 * angle), math.sin(0.5 * angle) / angle
    q[1], q[2], q[3] = s * vx, s * vy, s * vz
    return q
