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
    # the receiver's status with the fix delivered (written with each fix)
    ("gps_fix_type", 1),  # MAVLink GPS_FIX_TYPE (3: 3D fix)
    ("gps_sats", 1),  # satellites visible
    ("gps_eph_m", 1),  # its own 1-sigma horizontal position accuracy, per axis [m]
    ("gps_epv_m", 1),  # its own 1-sigma vertical position accuracy [m]
    ("att_t", 1),
    ("att", 3),  # ZYX Euler [rad]
    ("baro_t", 1),
    ("baro_alt", 1),  # height above home [m]
    ("mag_t", 1),
    ("mag", 3),  # body FLU magnetic field [gauss]
)
OUT_IMU_T = MEASUREMENTS.offset("imu_t")
OUT_GYRO = MEASUREMENTS.offset("gyro")
OUT_ACCEL = MEASUREMENTS.offset("accel")
OUT_GPS_T = MEASUREMENTS.offset("gps_t")
OUT_GPS_POS = MEASUREMENTS.offset("gps_pos")
OUT_GPS_VEL = MEASUREMENTS.offset("gps_vel")
OUT_GPS_FIX_TYPE = MEASUREMENTS.offset("gps_fix_type")
OUT_GPS_SATS = MEASUREMENTS.offset("gps_sats")
OUT_GPS_EPH_M = MEASUREMENTS.offset("gps_eph_m")
OUT_GPS_EPV_M = MEASUREMENTS.offset("gps_epv_m")
OUT_ATT_T = MEASUREMENTS.offset("att_t")
OUT_ATT = MEASUREMENTS.offset("att")
OUT_BARO_T = MEASUREMENTS.offset("baro_t")
OUT_BARO_ALT = MEASUREMENTS.offset("baro_alt")
OUT_MAG_T = MEASUREMENTS.offset("mag_t")
OUT_MAG = MEASUREMENTS.offset("mag")
N_OUT = MEASUREMENTS.size

NEW_IMU = 1
NEW_GPS = 2
NEW_ATT = 4
NEW_BARO = 8
NEW_MAG = 16

#: MAVLink GPS_FIX_TYPE_3D_FIX: what the receiver reports with every fix it delivers
GPS_FIX_3D = 3


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


class MagSample(NamedTuple):
    """The magnetic field in the body, FLU [gauss]: the earth's field at home
    (:mod:`heli_common.world.magnetic`) rotated into the body, ``R^T m_nwu``, plus the sensor's
    errors (a hard-iron offset, noise)."""

    t_s: float
    field_flu_gauss: Vec3
