"""What the vehicle's sensors deliver to the autopilot: the contract between the plant's
sensor models and the autopilot's estimator (frames and units as everywhere: earth NWU,
body FLU, SI). Each sample carries its time of validity ``t_s`` (vehicle time at which the
quantity was measured); a sensor with latency delivers it later than that.
"""

from __future__ import annotations

from typing import NamedTuple

Vec3 = tuple[float, float, float]


class ImuSample(NamedTuple):
    """Gyro and accelerometer, body FLU. The accelerometer measures specific force,
    ``f = R^T (a_earth - g_earth)`` with ``g_earth = (0, 0, -g)``: at rest, level, it reads
    ``(0, 0, +g)``."""

    t_s: float
    gyro_flu_rad_s: Vec3
    accel_flu_m_s2: Vec3


class GpsFix(NamedTuple):
    """Position and velocity, earth NWU (relative to home), valid at ``t_s``."""

    t_s: float
    pos_nwu_m: Vec3
    vel_nwu_m_s: Vec3


class AttitudeSample(NamedTuple):
    """An attitude source (an AHRS): ZYX Euler angles (roll, pitch, yaw) [rad], FLU/NWU."""

    t_s: float
    euler_rad: Vec3


class BaroSample(NamedTuple):
    """Barometric height above home [m]."""

    t_s: float
    alt_m: float
