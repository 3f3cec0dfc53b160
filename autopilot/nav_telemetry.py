"""What the vehicle tells a ground station about its sensors and its navigation: built
from the models that produce it, never from the truth it is flying.

* GPS_RAW_INT: the receiver's own fix (its position, velocity, fix type, satellites and
  accuracies, as the sim link delivered them); "no fix" and no satellites while the GPS is
  lost (no accepted fix for the estimator's ``gps_timeout_s``). eph/epv (dilutions of
  precision) are UINT16_MAX, "unknown", as MAVLink asks: the receiver model has no
  satellite geometry; its accuracies go in h_acc, v_acc and vel_acc.
* SYS_STATUS: which sensors exist, and their health from the estimator (GPS lost, filter
  diverged, magnetometer failing its gate).
* ESTIMATOR_STATUS (common) and EKF_STATUS_REPORT (ArduPilot's, which MAVProxy and Mission
  Planner show): flags and innovation test ratios (1 = at the gate).
* SIM_STATE: the truth, for logs (what ArduPilot's SITL sends).

A vehicle flying the true state (a world without sensors) has a perfect receiver: a 3-D
fix, the configured satellites, centimetre accuracy.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import development as m2

from autopilot.estimation.nav import NavStatus
from heli_common import frames
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import EULER, OMEGA, POS, VEL, FloatArray
from heli_common.wire.measurements import (
    GPS_FIX_3D,
    OUT_GPS_EPH_M,
    OUT_GPS_EPV_M,
    OUT_GPS_FIX_TYPE,
    OUT_GPS_POS,
    OUT_GPS_SATS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_MAG_T,
)

UINT16_MAX = 65535
PERFECT_ACCURACY_M = 0.01  # an ideal receiver's reported accuracy (as the sensor model's floor)
PERFECT_SATELLITES = 14
# a GPS velocity accuracy when the receiver reports none [m/s]
VEL_ACCURACY_M_S = 0.1

GROUND_SENSORS = m2.MAV_SYS_STATUS_SENSOR_3D_GYRO | m2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
GPS = m2.MAV_SYS_STATUS_SENSOR_GPS
MAG = m2.MAV_SYS_STATUS_SENSOR_3D_MAG
BARO = m2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
AHRS = m2.MAV_SYS_STATUS_AHRS


def _mm(v: float) -> int:
    return int(min(max(round(v * 1000.0), 0), 2**32 - 1)) if math.isfinite(v) else 0


#: a receiver whose newest fix is older than this has no fix (a 5 Hz receiver that missed two)
FIX_MAX_AGE_S = 0.5


def gps_raw_int(
    t_us: int, home: GeoPoint, x: FloatArray, meas: FloatArray | None, status: NavStatus | None,
    now_s: float = math.inf,
) -> m2.MAVLink_gps_raw_int_message:
    """The receiver's last fix (``meas``, the measurement layout; "no fix" once it is older
    than :data:`FIX_MAX_AGE_S` at the sensors' time ``now_s``, or the GPS is lost), or a
    perfect receiver's at the state ``x`` when the vehicle flies the truth (``meas`` None)."""
    if meas is None or status is None:
        pos, vel = x[POS], rot_body_to_earth(*x[EULER]) @ x[VEL]
        fix, sats, eph, epv = GPS_FIX_3D, PERFECT_SATELLITES, PERFECT_ACCURACY_M, PERFECT_ACCURACY_M
    else:
        pos, vel = meas[OUT_GPS_POS : OUT_GPS_POS + 3], meas[OUT_GPS_VEL : OUT_GPS_VEL + 3]
        fix = int(meas[OUT_GPS_FIX_TYPE]) if math.isfinite(meas[OUT_GPS_FIX_TYPE]) else 0
        sats = meas[OUT_GPS_SATS]
        eph, epv = float(meas[OUT_GPS_EPH_M]), float(meas[OUT_GPS_EPV_M])
        age = now_s - meas[OUT_GPS_T]
        if status.gps_lost or not math.isfinite(meas[OUT_GPS_T]) or age > FIX_MAX_AGE_S:
            fix, sats = m2.GPS_FIX_TYPE_NO_FIX, 0
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
        pos, vel = np.zeros(3), np.zeros(3)  # no fix yet: nothing to report where
        fix, sats = m2.GPS_FIX_TYPE_NO_FIX, 0
    geo = nwu_to_geo(home, [float(v) for v in pos])
    vn, ve, _ = frames.nwu_to_ned(vel)
    ground = math.hypot(vn, ve)
    cog = math.degrees(math.atan2(ve, vn)) % 360.0
    return m2.MAVLink_gps_raw_int_message(
        t_us, fix, int(round(geo.lat_deg * 1e7)), int(round(geo.lon_deg * 1e7)), int(geo.alt_amsl_m * 1000),
        UINT16_MAX, UINT16_MAX, int(round(ground * 100)), int(round(cog * 100)) % 36000,
        int(sats) if math.isfinite(sats) else 0, 0,
        # h_acc: the horizontal (radial) 1-sigma of a per-axis sigma is sqrt(2) times it
        _mm(math.sqrt(2.0) * eph), _mm(epv), _mm(VEL_ACCURACY_M_S), 0, 0,
    )  # fmt: skip


def sensor_bits(meas: FloatArray | None, status: NavStatus | None, plant_ok: bool) -> tuple[int, int]:
    """(present, healthy) SYS_STATUS sensor bits of the IMU, GPS, magnetometer, barometer
    and the attitude estimate (enabled = present)."""
    present = GROUND_SENSORS | GPS | AHRS
    if meas is not None and math.isfinite(meas[OUT_MAG_T]):
        present |= MAG
    if meas is not None:
        present |= BARO
    if not plant_ok:
        return present, 0
    healthy = present
    if status is not None:
        if status.gps_lost:
            healthy &= ~GPS
        if status.diverged:
            healthy &= ~AHRS
        if not status.mag_ok:
            healthy &= ~MAG
    return present, healthy


def _flags(status: NavStatus, ekf: bool) -> int:
    """The estimator's solution flags, ESTIMATOR_STATUS's or EKF_STATUS_REPORT's (the same
    bit values for the first ten)."""
    if status.diverged:
        return int(apm.EKF_UNINITIALIZED) if ekf else 0
    f = (m2.ESTIMATOR_ATTITUDE | m2.ESTIMATOR_VELOCITY_VERT | m2.ESTIMATOR_POS_VERT_ABS
         | m2.ESTIMATOR_PRED_POS_HORIZ_REL)  # fmt: skip
    if status.gps_lost:
        f |= m2.ESTIMATOR_CONST_POS_MODE  # dead reckoning: the position is predicted
    else:
        f |= (m2.ESTIMATOR_VELOCITY_HORIZ | m2.ESTIMATOR_POS_HORIZ_REL | m2.ESTIMATOR_POS_HORIZ_ABS
              | m2.ESTIMATOR_PRED_POS_HORIZ_ABS)  # fmt: skip
    if status.pos_horiz_ratio > 1.0:  # the last fix failed its gate
        f |= apm.EKF_GPS_GLITCHING if ekf else m2.ESTIMATOR_GPS_GLITCH
    return int(f)


def _r(v: float) -> float:
    return float(v) if math.isfinite(v) else 0.0


def estimator_status(t_us: int, status: NavStatus) -> m2.MAVLink_estimator_status_message:
    return m2.MAVLink_estimator_status_message(
        t_us, _flags(status, ekf=False), _r(status.vel_ratio), _r(status.pos_horiz_ratio),
        _r(status.pos_vert_ratio), _r(status.mag_ratio), 0.0, 0.0, status.pos_horiz_sd_m,
        status.pos_vert_sd_m,
    )  # fmt: skip


def ekf_status_report(status: NavStatus) -> apm.MAVLink_ekf_status_report_message:
    """ArduPilot's report: its "variances" are the square roots of the innovation test
    ratios (AP_NavEKF3 send_status_report), which our ratios already are."""
    return apm.MAVLink_ekf_status_report_message(
        _flags(status, ekf=True), _r(status.vel_ratio), _r(status.pos_horiz_ratio),
        _r(status.pos_vert_ratio), _r(status.mag_ratio), 0.0, 0.0,
    )  # fmt: skip


def sim_state(home: GeoPoint, x: FloatArray) -> m2.MAVLink_sim_state_message:
    """The true state, for logs: attitude (FRD/NED quaternion and Euler), body rates,
    position and NED velocity (the accelerations are not in the state: zero)."""
    roll, pitch, yaw = frames.euler_flu_to_frd(x[EULER])
    q = frames.euler_to_quaternion(roll, pitch, yaw)
    p, q_, r = frames.flip(x[OMEGA])
    geo = nwu_to_geo(home, [float(v) for v in x[POS]])
    vn, ve, vd = frames.nwu_to_ned(rot_body_to_earth(*x[EULER]) @ x[VEL])
    return m2.MAVLink_sim_state_message(
        *q, roll, pitch, yaw, 0.0, 0.0, 0.0, p, q_, r, geo.lat_deg, geo.lon_deg, geo.alt_amsl_m, 0.0, 0.0,
        vn, ve, vd, int(round(geo.lat_deg * 1e7)), int(round(geo.lon_deg * 1e7)),
    )  # fmt: skip
