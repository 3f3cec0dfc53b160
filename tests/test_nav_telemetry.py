"""What the ground station is told about the sensors and the navigation
(autopilot.nav_telemetry) against the models that produce it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as apm

from autopilot import nav_telemetry as nt
from autopilot.estimation.nav import NavStatus
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.wire.measurements import (
    N_OUT,
    OUT_GPS_EPH_M,
    OUT_GPS_EPV_M,
    OUT_GPS_FIX_TYPE,
    OUT_GPS_POS,
    OUT_GPS_SATS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_MAG_T,
)

HOME = GeoPoint(47.397742, 8.545594, 488.0)
OK = NavStatus(False, False, 0.2, 0.3, 0.1, 0.4, 0.5, 0.1, 0, True)


def _meas() -> np.ndarray:
    m = np.full(N_OUT, math.nan)
    m[OUT_GPS_T] = 10.0
    m[OUT_GPS_POS : OUT_GPS_POS + 3] = (30.0, -20.0, 5.0)  # north, west, up
    m[OUT_GPS_VEL : OUT_GPS_VEL + 3] = (3.0, -4.0, 1.0)
    m[OUT_GPS_FIX_TYPE], m[OUT_GPS_SATS], m[OUT_GPS_EPH_M], m[OUT_GPS_EPV_M] = 3, 11, 2.12, 2.5
    return m


def test_gps_raw_int_is_the_receivers_fix_and_no_fix_when_lost_or_stale() -> None:
    m = _meas()
    g = nt.gps_raw_int(1, HOME, np.zeros(12), m, OK, now_s=10.1)
    want = nwu_to_geo(HOME, (30.0, -20.0, 5.0))
    assert (g.fix_type, g.satellites_visible) == (3, 11)
    assert (g.lat, g.lon) == (round(want.lat_deg * 1e7), round(want.lon_deg * 1e7))
    assert g.alt == int(want.alt_amsl_m * 1e3)
    assert g.vel == 500 and g.cog == round(math.degrees(math.atan2(4.0, 3.0)) * 100)  # 5 m/s, east of north
    assert (g.h_acc, g.v_acc, g.eph, g.epv) == (round(1000 * math.sqrt(2) * 2.12), 2500, 65535, 65535)
    lost = OK._replace(gps_lost=True)
    for status, now in ((lost, 10.1), (OK, 10.0 + nt.FIX_MAX_AGE_S + 0.01)):
        g = nt.gps_raw_int(1, HOME, np.zeros(12), m, status, now_s=now)
        assert (g.fix_type, g.satellites_visible) == (1, 0)
    # flying the truth: a perfect receiver at the state
    g = nt.gps_raw_int(1, HOME, np.zeros(12), None, None)
    assert (g.fix_type, g.satellites_visible, g.h_acc) == (3, 14, 14)


def test_sys_status_health_follows_the_estimator() -> None:
    m = _meas()
    present, healthy = nt.sensor_bits(m, OK, True)
    assert present == healthy and present & nt.GPS and present & nt.AHRS and not present & nt.MAG
    m[OUT_MAG_T] = 9.99
    assert nt.sensor_bits(m, OK, True)[0] & nt.MAG
    for status, bit in ((OK._replace(gps_lost=True), nt.GPS), (OK._replace(diverged=True), nt.AHRS),
                        (OK._replace(mag_ok=False), nt.MAG)):  # fmt: skip
        present, healthy = nt.sensor_bits(m, status, True)
        assert present & bit and not healthy & bit and healthy | bit == present
    assert nt.sensor_bits(m, OK, False)[1] == 0  # the plant silent: nothing is measured


@pytest.mark.parametrize(("status", "has", "lacks"), [
    (OK, 1 | 2 | 4 | 8 | 16 | 32, 128 | 1024),
    (OK._replace(gps_lost=True), 1 | 4 | 32 | 128, 2 | 16),
    (OK._replace(pos_horiz_ratio=1.5), 16 | 32768, 0),
    (OK._replace(diverged=True), 1024, 1 | 16),
])  # fmt: skip
def test_ekf_status_report_flags_and_ratios(status: NavStatus, has: int, lacks: int) -> None:
    r = nt.ekf_status_report(status)
    assert r.flags & has == has and not r.flags & lacks
    assert (r.velocity_variance, r.pos_horiz_variance, r.compass_variance) == (
        status.vel_ratio, status.pos_horiz_ratio, status.mag_ratio)
    # it packs, and ArduPilot's dialect (MAVProxy's) reads it back
    mav = apm.MAVLink(None, srcSystem=1)
    back = mav.parse_char(r.pack(mav))
    assert back is not None and back.get_type() == "EKF_STATUS_REPORT" and back.flags == r.flags


def test_sim_state_is_the_truth_in_ned() -> None:
    x = np.zeros(12)
    x[0:3] = (10.0, 5.0, 3.0)
    x[6:9] = (0.1, 0.2, 0.3)
    s = nt.sim_state(HOME, x)
    assert (s.roll, s.pitch, s.yaw) == pytest.approx((0.1, -0.2, -0.3))
    g = nwu_to_geo(HOME, (10.0, 5.0, 3.0))
    assert (s.lat_int, s.lon_int) == (round(g.lat_deg * 1e7), round(g.lon_deg * 1e7))
