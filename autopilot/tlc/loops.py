"""The linearising terms of loops 3 and 4 (A3, A4) and the body-frame force of loop 2.

Each loop's regulator is a PI on ``command - actual`` with positive gains (the spec's
consistent sign), so every error channel obeys e'' + 2 z w e' + w^2 e = 0.
"""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.kinematics import cross, mat_mat, mat_vec, rot_euler_entries
from heli_common.state import FloatArray


@njit
def a3_matrix(phi: float, theta: float, p: float, q: float, r: float) -> FloatArray:
    """A3 = d(E(gamma)^-1 omega)/d gamma at (gamma, omega); the psi column is zero."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, tth = math.cos(theta), math.tan(theta)
    qc_rs = q * cph - r * sph
    qs_rc = q * sph + r * cph
    a = np.zeros((3, 3))
    a[0, 0] = qc_rs * tth
    a[0, 1] = qs_rc / (cth * cth)
    a[1, 0] = -qs_rc
    a[2, 0] = qc_rs / cth
    a[2, 1] = qs_rc * tth / cth
    return a


@njit
def skew(v: FloatArray) -> FloatArray:
    s = np.zeros((3, 3))
    s[0, 1], s[0, 2] = -v[2], v[1]
    s[1, 0], s[1, 2] = v[2], -v[0]
    s[2, 0], s[2, 1] = -v[1], v[0]
    return s


@njit
def a4_matrix(omega: FloatArray, j: FloatArray, j_inv: FloatArray) -> FloatArray:
    """A4 = d(-J^-1 (w x J w))/dw = -J^-1 ([w]x J - [J w]x) at ``omega``."""
    jw = mat_vec(j, omega)
    return -mat_mat(j_inv, mat_mat(skew(omega), j) - skew(jw))


@njit
def a4_times(omega: FloatArray, j: FloatArray, j_inv: FloatArray, v: FloatArray) -> FloatArray:
    """``A4(omega) @ v`` without forming A4: -J^-1 (omega x (J v) - (J omega) x v), the same
    product in five vectors instead of four 3x3 matrices (the kernel needs only this)."""
    return -mat_vec(j_inv, cross(omega, mat_vec(j, v)) - cross(mat_vec(j, omega), v))


# --- the same products on values (tuples the compiler keeps in registers): the kernel's
# per-tick form, no array made. Each is the arithmetic of its array form above operation
# for operation, the structural zeros of A3 and E(gamma) included (0 * inf is NaN there
# too), so a tick is bit for bit the one the array forms compute.

Vec3 = tuple[float, float, float]
Rot = tuple[float, float, float, float, float, float, float, float, float]


@njit
def mat_vec3(m: FloatArray, v: Vec3) -> Vec3:
    """``m @ v`` for a 3x3 ``m``, as :func:`~heli_common.kinematics.mat_vec`."""
    return (m[0, 0] * v[0] + m[0, 1] * v[1] + m[0, 2] * v[2],
            m[1, 0] * v[0] + m[1, 1] * v[1] + m[1, 2] * v[2],
            m[2, 0] * v[0] + m[2, 1] * v[1] + m[2, 2] * v[2])  # fmt: skip


@njit
def cross3(a: Vec3, b: Vec3) -> Vec3:
    """``a x b``, as :func:`~heli_common.kinematics.cross`."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@njit
def a3_times(cph: float, sph: float, cth: float, tth: float, q: float, r: float, v: Vec3) -> Vec3:
    """``A3 @ v`` (:func:`a3_matrix` at phi, theta given by their cosines, sines and
    tangent; its zero entries kept in the sums)."""
    qc_rs = q * cph - r * sph
    qs_rc = q * sph + r * cph
    a00, a01 = qc_rs * tth, qs_rc / (cth * cth)
    a10 = -qs_rc
    a20, a21 = qc_rs / cth, qs_rc * tth / cth
    return (a00 * v[0] + a01 * v[1] + 0.0 * v[2],
            a10 * v[0] + 0.0 * v[1] + 0.0 * v[2],
            a20 * v[0] + a21 * v[1] + 0.0 * v[2])  # fmt: skip


@njit
def euler_rate_times(cph: float, sph: float, cth: float, sth: float, v: Vec3) -> Vec3:
    """``E(gamma) @ v`` (:func:`~heli_common.kinematics.euler_rate_matrix` from the cosines
    and sines of phi, theta; its zero and unit entries kept in the sums)."""
    return (1.0 * v[0] + 0.0 * v[1] + -sth * v[2],
            0.0 * v[0] + cph * v[1] + sph * cth * v[2],
            0.0 * v[0] + -sph * v[1] + cph * cth * v[2])  # fmt: skip


@njit
def a4_times3(omega: Vec3, j: FloatArray, j_inv: FloatArray, v: Vec3) -> Vec3:
    """:func:`a4_times` on values."""
    c1 = cross3(omega, mat_vec3(j, v))
    c2 = cross3(mat_vec3(j, omega), v)
    m = mat_vec3(j_inv, (c1[0] - c2[0], c1[1] - c2[1], c1[2] - c2[2]))
    return -m[0], -m[1], -m[2]


@njit
def rot3(phi: float, theta: float, psi: float) -> Rot:
    """:func:`~heli_common.kinematics.rot_body_to_earth` on values, row-major."""
    return rot_euler_entries(phi, theta, psi)
