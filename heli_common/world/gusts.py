"""The air's slow part, shared by the plant (which flies it) and the autopilot (which
reports it in WIND_COV): ArduPilot's steady-wind convention and the discrete gust shape.
Pure functions, compiled for the plant's step."""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.state import FloatArray


@njit
def mean_wind_nwu(speed_m_s: float, dir_from_deg: float, dir_z_deg: float) -> FloatArray:
    """Steady air velocity [m/s, NWU] from ArduPilot's SIM_WIND_SPD / _DIR / _DIR_Z.

    ``DIR`` is where the wind comes FROM, degrees clockwise from north; ``DIR_Z`` tilts it,
    90 = pure updraft. ArduPilot's ``Aircraft::update_wind`` builds, in NED,
    ``wind_ef = SPD (cos DIR cos DIR_Z, sin DIR cos DIR_Z, sin DIR_Z)`` and adds it to the
    ground velocity to get the air-relative velocity, so the air velocity is ``-wind_ef``:
    in NWU (y = -east, z = -down) ``W = SPD (-cos DIR cos DIR_Z, sin DIR cos DIR_Z, sin DIR_Z)``.
    """
    d = math.radians(dir_from_deg)
    dz = math.radians(dir_z_deg)
    w = np.empty(3)
    w[0] = -speed_m_s * math.cos(d) * math.cos(dz)
    w[1] = speed_m_s * math.sin(d) * math.cos(dz)
    w[2] = speed_m_s * math.sin(dz)
    return w



@njit
def gust_factor(t_s: float, start_s: float, rise_s: float, hold_s: float, fall_s: float) -> float:
    """Discrete gust shape in [0, 1]: 0, 1-cosine rise, hold, cosine fall, 0.

    Rise ``(1 - cos(pi (t - start)/rise))/2`` over ``rise_s`` (MIL-F-8785C 1-cosine gust; the
    MathWorks Discrete Wind Gust Model writes it in distance ``x`` with ``d_m``, here
    ``rise = d_m/V`` at a fixed convection speed); then 1 for ``hold_s`` (``math.inf``: the gust
    stays, the 8785C form); then ``(1 + cos(pi (t - t_fall)/fall))/2`` over ``fall_s`` (JSBSim's
    cosine gust profile ends the same way). Zero durations give steps.
    """
    tau = t_s - start_s
    if not tau >= 0.0:
        return 0.0
    if tau < rise_s:
        return 0.5 * (1.0 - math.cos(math.pi * tau / rise_s))
    tau -= rise_s
    if tau <= hold_s:
        return 1.0
    tau -= hold_s
    if tau < fall_s:
        return 0.5 * (1.0 + math.cos(math.pi * tau / fall_s))
    return 0.0
