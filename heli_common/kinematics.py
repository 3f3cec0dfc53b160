"""Rotation and Euler-rate kinematics shared by the plant and the controller (ZYX, NWU/FLU)."""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.state import FloatArray


@njit
def rot_body_to_earth(phi: float, theta: float, psi: float) -> FloatArray:
    """Rt(gamma) = Rz(psi) Ry(theta) Rx(phi): maps FLU body vectors to NWU earth vectors."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cps, sps = math.cos(psi), math.sin(psi)
    r = np.empty((3, 3))
    r[0, 0] = cth * cps
    r[0, 1] = sph * sth * cps - cph * sps
    r[0, 2] = cph * sth * cps + sph * sps
    r[1, 0] = cth * sps
    r[1, 1] = sph * sth * sps + cph * cps
    r[1, 2] = cph * sth * sps - sph * cps
    r[2, 0] = -sth
    r[2, 1] = sph * cth
    r[2, 2] = cph * cth
    return r


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
