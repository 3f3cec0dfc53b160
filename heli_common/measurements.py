"""What the vehicle's sensors deliver to the autopilot: the contract between the plant's
sensor models and the autopilot's estimator (frames and units as everywhere: earth NWU,
body FLU, SI). Each sample carries its time of validity ``t_s`` (vehicle time at which the
quantity was measured); a sensor with latency delivers it later than that.
"""

from __future__ import annotations

from typing import NamedTuple

from heli_common.layout import Layout

Vec3 = tuple[float, float, float]

# --- the same samples as one flat float64 array (what compiled code passes around) -------
# Each slot holds that sensor's latest sample (NaN before its first); a bit mask says which
# are new this step. The plant's sensor models write it, the sim link carries it, the
# autopilot's estimator reads it: the in-process loop and the processes share one layout.
MEASUREMENTS = Layout(
    "measurements",
    ("imu_t", 1),
    ("gyro", 3),  # body FLU [rad/s]
    ("accel", 3),  # body FLU specific force [m/s^2]
    ("gps_t", 1),  # validity time of the fix delivered
    ("gps_pos", 3),  # earth NWU [m]
    ("gps_vel", 3),  # earth NWU [m/s]
    ("att_t", 1),
    ("att", 3),  # ZYX Euler [rad]
    ("baro_t", 1),
    ("baro_alt", 1),  # height above home [m]
)
OUT_IMU_T = MEASUREMENTS.offset("imu_t")
OUT_GYRO = MEASUREMENTS.offset("gyro")
OUT_ACCEL = MEASUREMENTS.offset("accel")
OUT_GPS_T = MEASUREMENTS.offset("gps_t")
OUT_GPS_POS = MEASUREMENTS.offset("gps_pos")
OUT_GPS_VEL = MEASUREMENTS.offset("gps_vel")
OUT_ATT_T = MEASUREMENTS.offset("att_t")
OUT_ATT = MEASUREMENTS.offset("att")
OUT_BARO_T = MEASUREMENTS.offset("baro_t")
OUT_BARO_ALT = MEASUREMENTS.offset("baro_alt")
N_OUT = MEASUREMENTS.size

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
