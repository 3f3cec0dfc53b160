"""What the vehicle's sensors deliver to the autopilot: the contract between the plant's
sensor models and the autopilot's estimator (frames and units as everywhere: earth NWU,
body FLU, SI). Each sample carries its time of validity ``t_s`` (vehicle time at which the
quantity was measured); a sensor with latency delivers it later than that.
"""

from __future__ import annotations

from typing import NamedTuple

Vec3 = tuple[float, float, float]

# --- the same samples as one flat float64 array (what compiled code passes around) -------
# Each slot holds that sensor's latest sample (NaN before its first); a bit mask says which
# are new this step. The plant's sensor models write it, the sim link carries it, the
# autopilot's estimator reads it: the in-process loop and the processes share one layout.
OUT_IMU_T = 0
OUT_GYRO = 1  # 3, body FLU [rad/s]
OUT_ACCEL = 4  # 3, body FLU specific force [m/s^2]
OUT_GPS_T = 7  # validity time of the fix delivered
OUT_GPS_POS = 8  # 3, earth NWU [m]
OUT_GPS_VEL = 11  # 3, earth NWU [m/s]
OUT_ATT_T = 14
OUT_ATT = 15  # 3, ZYX Euler [rad]
OUT_BARO_T = 18
OUT_BARO_ALT = 19  # height above home [m]
N_OUT = 20

NEW_IMU = 1
NEW_GPS = 2
NEW_ATT = 4
NEW_BARO = 8


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
