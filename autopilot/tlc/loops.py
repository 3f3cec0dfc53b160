"""The linearising terms of loops 3 and 4 (A3, A4) and the body-frame force of loop 2.

Each loop's regulator is a PI on ``command - actual`` with positive gains (the spec's
consistent sign), so every error channel obeys e'' + 2 z w e' + w^2 e = 0.
"""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.kinematics import cross, mat_mat, mat_vec
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
