"""Step 3: body force command -> main thrust and roll/pitch command (eq. 25), yaw rate (eqs 26-28)."""

from __future__ import annotations

import math

from heli_common.jit import njit
from heli_common.state import FloatArray


@njit
def limit_tilt(f: FloatArray, mg: float, tilt_max_rad: float) -> bool:
    """Scale (Fx, Fy) in place so |(Fx, Fy)| <= m g sin(tilt_max); True if it had to."""
    f[0], f[1], limited = limit_tilt2(f[0], f[1], mg, tilt_max_rad)
    return limited


@njit
def limit_tilt2(fx: float, fy: float, mg: float, tilt_max_rad: float) -> tuple[float, float, bool]:
    """:func:`limit_tilt` on values: (Fx, Fy, whether it had to scale them)."""
    h = math.hypot(fx, fy)
    h_max = mg * math.sin(tilt_max_rad)
    if h > h_max:
        k = h_max / h
        return fx * k, fy * k, True
    return fx, fy, False


@njit
def force_to_thrust_attitude(f: FloatArray, mg: float) -> tuple[float, float, float]:
    """(Tm, phi_c, theta_c) with the design model F = [mg s(th), -mg c(th) s(ph), -mg c(th) c(ph) + Tm].

    Requires |(Fx, Fy)| < m g (guaranteed by :func:`limit_tilt`).
    """
    return force_to_thrust_attitude3(f[0], f[1], f[2], mg)


@njit
def force_to_thrust_attitude3(fx: float, fy: float, fz: float, mg: float) -> tuple[float, float, float]:
    """:func:`force_to_thrust_attitude` of the force as values."""
    vert = math.sqrt(mg * mg - fx * fx - fy * fy)  # = mg c(th) c(ph) = Tm - Fz
    tm = fz + vert
    phi_c = math.atan2(-fy, vert)
    theta_c = math.atan2(fx, math.sqrt(mg * mg - fx * fx))
    return tm, phi_c, theta_c


@njit
def yaw_rate_command(vx: float, vy: float, ax: float, ay: float, hold_speed: float) -> float:
    """dpsi_c/dt = (x' y'' - x'' y') / (x'^2 + y'^2): nose along the path; 0 below hold_speed."""
    v2 = vx * vx + vy * vy
    if v2 <= hold_speed * hold_speed or v2 == 0.0:
        return 0.0
    return (vx * ay - ax * vy) / v2
