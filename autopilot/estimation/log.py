"""The estimator's log: one row per tick (est.csv after the estimate's state columns),
written by either filter's ``log_tick``. The first columns are common to both; the
navigation filter's own (attitude, gyro bias, magnetometer) are NaN for ``ideal-ahrs``.
"""

from __future__ import annotations

from heli_common.layout import Layout

EST_LOG = Layout(
    "estimator log",
    ("sd_pos", 3),  # 1-sigma position, earth NWU [m]
    ("sd_vel", 3),  # 1-sigma velocity, earth NWU [m/s]
    ("bias", 3),  # accelerometer bias seen in the earth frame, NWU [m/s^2]
    ("gps_status", 1),  # the tick's GPS status (NO_FIX, ACCEPTED, REJECTED, RESET, ...)
    ("nis", 1),  # a tick with a fix: its NIS at the validity time
    ("innov", 3),  # and its position innovation, NWU [m]
    ("since_fix_s", 1),  # since the validity time of the newest accepted fix
    ("sd_att", 3),  # 1-sigma local attitude error about body x, y, z [rad]
    ("gyro_bias", 3),  # estimated gyro bias, body FLU [rad/s]
    ("sd_gyro_bias", 3),
    ("accel_bias", 3),  # estimated accelerometer bias, body FLU [m/s^2]
    ("sd_accel_bias", 3),
    ("mag_innov", 1),  # the last heading innovation [rad] and its NIS
    ("mag_nis", 1),
    ("diverged", 1),  # 1 once the filter has declared itself diverged
    # the truth, where a simulation knows it (the in-process loop; NaN over processes):
    ("nees", 1),  # normalised error squared of the 15 navigation states
    ("att_err", 3),  # the true local attitude error d_theta, body [rad]
    ("gyro_bias_err", 3),  # true gyro bias - estimate, body [rad/s]
)
L_SD_POS = EST_LOG.offset("sd_pos")
L_SD_VEL = EST_LOG.offset("sd_vel")
L_BIAS = EST_LOG.offset("bias")
L_GPS_STATUS = EST_LOG.offset("gps_status")
L_NIS = EST_LOG.offset("nis")
L_INNOV = EST_LOG.offset("innov")
L_SINCE_FIX = EST_LOG.offset("since_fix_s")
L_SD_ATT = EST_LOG.offset("sd_att")
L_GYRO_BIAS = EST_LOG.offset("gyro_bias")
L_SD_GYRO_BIAS = EST_LOG.offset("sd_gyro_bias")
L_ACCEL_BIAS = EST_LOG.offset("accel_bias")
L_SD_ACCEL_BIAS = EST_LOG.offset("sd_accel_bias")
L_MAG_INNOV = EST_LOG.offset("mag_innov")
L_MAG_NIS = EST_LOG.offset("mag_nis")
L_DIVERGED = EST_LOG.offset("diverged")
L_NEES = EST_LOG.offset("nees")
L_ATT_ERR = EST_LOG.offset("att_err")
L_GYRO_BIAS_ERR = EST_LOG.offset("gyro_bias_err")
N_EST_LOG = EST_LOG.size
#: the blocks in the body frame (suffixed x, y, z); the others with three values are earth NWU
_BODY = frozenset(
    {"sd_att", "att_err", "gyro_bias_err", "gyro_bias", "sd_gyro_bias", "accel_bias", "sd_accel_bias"}
)
_SUFFIX = {False: "nwu", True: "xyz"}
#: est.csv's column names: a block's name, suffixed with its axis where it has three
EST_LOG_COLUMNS = tuple(
    name if EST_LOG.size_of(name) == 1 else f"{name}_{_SUFFIX[name in _BODY][i]}"
    for name in EST_LOG.names
    for i in range(EST_LOG.size_of(name))
)
