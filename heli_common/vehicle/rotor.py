"""Rotor thrust/torque coefficient maps (Zhu & Huo eqs 16-17) and their exact inverse (eq 34).

``tc(theta)`` is the hover blade-element/momentum solution, valid for theta >= 0; negative
pitch uses the odd extension tc(theta) = sign(theta) tc(|theta|), and qc uses |tc|^1.5.
"""

from __future__ import annotations

import math

from heli_common.jit import njit


@njit
def thrust_coeff(pitch_rad: float, lift_slope: float, solidity: float) -> float:
    """tc = (1/4) [ -(a/4) sqrt(s/2) + sqrt(a^2 s/32 + (2/3) a |theta|) ]^2, odd in theta."""
    a, s = lift_slope, solidity
    root = -(a / 4.0) * math.sqrt(s / 2.0) + math.sqrt(
        a * a * s / 32.0 + (2.0 / 3.0) * a * abs(pitch_rad)
    )
    return math.copysign(0.25 * root * root, pitch_rad)


@njit
def torque_coeff(tc: float, solidity: float, delta: float) -> float:
    """qc = delta/8 + 1.13 |tc|^1.5 sqrt(s/2): profile plus induced torque (always >= 0)."""
    return delta / 8.0 + 1.13 * math.pow(abs(tc), 1.5) * math.sqrt(solidity / 2.0)


@njit
def pitch_from_thrust_coeff(tc: float, lift_slope: float, solidity: float) -> float:
    """Exact inverse of :func:`thrust_coeff`: theta = (3/2)[sqrt(s|tc|/2) + 4|tc|/a] sign(tc)."""
    mag = abs(tc)
    return math.copysign(1.5 * (math.sqrt(solidity * mag / 2.0) + 4.0 * mag / lift_slope), tc)
