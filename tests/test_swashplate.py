"""The swashplate (heli_common.vehicle.swashplate): ArduPilot's mixing against its source's formulas and
against PWMs recorded from the firmware binary; the physical head's round trips, signs, limits
and bad input; the X-Cell file and its .parm agreeing by construction."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from heli_common.config import CONFIG_DIR, ConfigError, as_table
from heli_common.state import EPS, ETA, THETA_M, THETA_T
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.swashplate import (
    ArduPilotHeli,
    Swashplate,
    SwashType,
    ardupilot_factors,
    ardupilot_mix,
    ardupilot_rsc_pwm,
    ardupilot_tail_pwm,
    read_parm,
    rsc_request,
)

XCELL_TOML = CONFIG_DIR / "swashplate" / "xcell60-h3-120.toml"
XCELL_PARM = CONFIG_DIR / "swashplate" / "xcell60-h3-120.parm"
TAIL = (-0.35, 0.35)

# The heli part of ArduPilot's Tools/autotest/default_params/copter-heli.parm (the shared
# binary's SITL defaults, ../shared/ardupilot/copter-heli.parm).
COPTER_HELI = {
    "H_COL_MAX": 1740.0, "H_COL_MIN": 1460.0, "H_COL_ANG_MAX": 12.0, "H_COL_ANG_MIN": -2.0,
    "H_RSC_MODE": 2.0, "H_RSC_SETPOINT": 66.0, "SERVO8_MIN": 1000.0, "SERVO8_MAX": 2000.0,
}  # fmt: skip

# Recorded from ../shared/ardupilot/arducopter-heli (ArduPilot master 90700977c553, July 2025)
# flown by a resting JSON physics peer, disarmed with H_SV_MAN 1 (passthrough: roll, pitch, yaw =
# (RCn - 1500) / 500, collective = (RC3 - 1000) / 1000), RC1-4 by RC_CHANNELS_OVERRIDE, parameters
# set by PARAM_SET one case after another (they accumulate within a run) on top of copter-heli.parm.
# Each row: parameters set, (RC1, RC2, RC3, RC4), measured (SERVO1, SERVO2, SERVO3, SERVO4);
# FIRMWARE_RUNS holds two runs of the firmware (the second from a wiped EEPROM again).
Recorded = list[tuple[dict[str, float], tuple[int, int, int, int], tuple[int, int, int, int]]]
FIRMWARE_RUN_1: Recorded = [
    ({}, (1500, 1500, 1000, 1500), (1460, 1460, 1460, 1500)),
    ({}, (1700, 1500, 1500, 1500), (1755, 1444, 1600, 1500)),
    ({}, (1500, 1300, 1500, 1500), (1510, 1510, 1780, 1500)),
    ({}, (1900, 1900, 2000, 1900), (1981, 1675, 1563, 1820)),
    ({}, (1500, 1500, 1500, 1100), (1600, 1600, 1600, 1180)),
    ({"H_CYC_MAX": 4500}, (1900, 1200, 1700, 1750), (1832, 1209, 1926, 1700)),
    ({"SERVO1_REVERSED": 1, "SERVO2_TRIM": 1530, "SERVO4_MIN": 1000, "SERVO4_MAX": 2000, "SERVO4_TRIM": 1400},
     (1650, 1380, 1600, 1750), (1310, 1487, 1736, 1700)),
    ({"SERVO1_MIN": 1300, "SERVO1_MAX": 1700}, (1000, 1000, 2000, 1200), (1695, 1886, 2000, 1160)),
    ({"SERVO1_REVERSED": 0, "SERVO2_TRIM": 1500, "H_SW_COL_DIR": 1}, (1650, 1380, 1600, 1500),
     (1434, 1201, 1480, 1400)),
    ({"H_SW_COL_DIR": 0, "H_SW_LIN_SVO": 1}, (1650, 1380, 1600, 1500), (1670, 1462, 1711, 1400)),
    ({"H_SW_LIN_SVO": 0, "H_SW_TYPE": 2}, (1650, 1380, 1600, 1500), (1655, 1385, 1736, 1400)),
    ({"H_SW_TYPE": 1}, (1650, 1380, 1600, 1500), (1635, 1392, 1628, 1400)),
    ({"H_SW_TYPE": 0, "H_SW_H3_SV1_POS": -50, "H_SW_H3_SV2_POS": 70, "H_SW_H3_SV3_POS": 175,
      "H_SW_H3_PHANG": 12}, (1650, 1380, 1600, 1500), (1696, 1456, 1691, 1400)),
    ({"H_COL_MIN": 1250, "H_COL_MAX": 1750}, (1500, 1500, 1250, 1500), (1375, 1375, 1375, 1400)),
]  # fmt: skip
FIRMWARE_RUN_2: Recorded = [
    ({"SERVO1_MIN": 1300, "SERVO1_MAX": 1700}, (1900, 1500, 1000, 1500), (1676, 1243, 1460, 1500)),
    ({"SERVO4_REVERSED": 1, "SERVO4_MIN": 1100, "SERVO4_MAX": 1900, "SERVO4_TRIM": 1550},
     (1500, 1500, 1000, 1800), (1460, 1460, 1460, 1280)),
    ({}, (1500, 1500, 1000, 1234), (1460, 1460, 1460, 1736)),
    ({"H_SW_TYPE": 0, "H_SW_H3_SV1_POS": -60, "H_SW_H3_SV2_POS": 60, "H_SW_H3_SV3_POS": 180,
      "H_SW_H3_PHANG": -20, "H_SW_LIN_SVO": 1, "H_SW_COL_DIR": 1, "SERVO3_REVERSED": 1, "SERVO3_TRIM": 1470},
     (1321, 1777, 1333, 1500), (1517, 1603, 1741, 1550)),
    ({"H_SW_TYPE": 3, "H_SW_H3_PHANG": 25, "H_SW_LIN_SVO": 0, "H_SW_COL_DIR": 0, "SERVO3_REVERSED": 0,
      "SERVO3_TRIM": 1500, "H_CYC_MAX": 1000}, (1800, 1300, 1500, 1500), (1644, 1500, 1655, 1550)),
    ({"H_SW_TYPE": 1, "H_CYC_MAX": 2500}, (1100, 1950, 1999, 1500), (1333, 1686, 1739, 1550)),
]  # fmt: skip

C30 = math.cos(math.radians(30.0))


def heli(**params: float) -> ArduPilotHeli:
    return ArduPilotHeli.from_params({**COPTER_HELI, **params})


def plate(params: dict[str, float]) -> Swashplate:
    return Swashplate.from_ardupilot_params({**COPTER_HELI, **params}, tail_theta_t_rad=TAIL)


# One parameter set per swash type, with trims, reversals, phase, COL_DIR and LIN_SVO in play.
SETUPS: dict[str, dict[str, float]] = {
    "H3_120": {"H_SW_TYPE": 3},
    "H3_140": {"H_SW_TYPE": 2, "SERVO2_REVERSED": 1, "SERVO3_TRIM": 1480},
    "H1": {"H_SW_TYPE": 1, "H_SW_COL_DIR": 1},
    "H3": {
        "H_SW_TYPE": 0, "H_SW_H3_SV1_POS": -50, "H_SW_H3_SV2_POS": 70, "H_SW_H3_SV3_POS": 175,
        "H_SW_H3_PHANG": 12, "SERVO1_TRIM": 1520,
    },
    "H3_lin": {"H_SW_TYPE": 0, "H_SW_H3_PHANG": -20, "H_SW_LIN_SVO": 1, "SERVO3_REVERSED": 1},
}
INPUTS = [(0.0, 0.0, 0.5), (0.2, 0.0, 0.3), (0.0, -0.3, 0.8), (-0.25, 0.15, 0.6), (0.1, 0.35, 0.05)]


# --- ArduPilot's factors and mixing, against the source's formulas --------------------------------


def test_factors_as_arducopter_writes_them() -> None:
    # AP_MotorsHeli_Swash::calculate_roll_pitch_collective_factors; H3_120 was a literal table
    # (0.866025f, -0.866025f, 0 / 0.5f, 0.5f, -1) before add_servo_angle(-60, 60, 180) replaced it.
    f = ardupilot_factors(SwashType.H3_120)
    np.testing.assert_allclose(f.roll, (C30, -C30, 0.0), atol=1e-15)
    np.testing.assert_allclose(f.pitch, (0.5, 0.5, -1.0), atol=1e-15)
    assert f.collective == (1.0, 1.0, 1.0)
    np.testing.assert_allclose(f.roll, (0.866025, -0.866025, 0.0), atol=1e-6)
    f = ardupilot_factors(SwashType.H3_140)  # add_servo_raw(1, 1, 1), (-1, 1, 1), (0, -1, 1)
    assert (f.roll, f.pitch, f.collective) == ((1.0, -1.0, 0.0), (1.0, 1.0, -1.0), (1.0, 1.0, 1.0))
    f = ardupilot_factors(SwashType.H1)  # add_servo_raw(1, 0, 0), (0, 1, 0), (0, 0, 1)
    assert (f.roll, f.pitch, f.collective) == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    # H3: add_servo_angle(n, SVn_POS - PHANG): roll cos(a + 90 deg), pitch cos(a)
    f = ardupilot_factors(SwashType.H3, (-50.0, 70.0, 175.0), 12.0)
    a = np.radians([-62.0, 58.0, 163.0])
    np.testing.assert_allclose(f.roll, np.cos(a + math.pi / 2), atol=1e-15)
    np.testing.assert_allclose(f.pitch, np.cos(a), atol=1e-15)
    # single precision as the firmware stores them
    f32 = ardupilot_factors(SwashType.H3_120, float32=True)
    assert f32.pitch[0] == float(np.float32(math.cos(float(np.float32(-math.pi / 3)))))
    assert abs(f32.roll[2]) < 1e-7 and f32.roll[2] != 0.0  # cosf(radians(270)) is not exactly 0


@pytest.mark.parametrize("name", list(SETUPS))
def test_swash_outputs_follow_calculate(name: str) -> None:
    """AP_MotorsHeli_Swash::calculate: 2 (0.45 (rf r + pf p) + cf c [+ 0.5 H1 servos 1, 2]) - 1,
    c = 1 - c with H_SW_COL_DIR 1, then asin(0.766044 x) 1.145916 with H_SW_LIN_SVO."""
    h = heli(**SETUPS[name])
    f = h.factors()
    for r, p, c in INPUTS:
        cc = 1.0 - c if h.sw_col_dir == 1 else c
        want = []
        for i in range(3):
            s = 0.45 * (f.roll[i] * r + f.pitch[i] * p) + f.collective[i] * cc
            s += 0.5 if (h.sw_type == SwashType.H1 and i < 2) else 0.0
            o = 2.0 * s - 1.0
            if h.sw_lin_svo:
                o = math.asin(0.766044 * max(-1.0, min(1.0, o))) * 1.145916
            want.append(o)
        np.testing.assert_allclose(h.swash_outputs(r, p, c), want, rtol=0, atol=1e-15)
        np.testing.assert_allclose(h.swash_outputs(r, p, c, float32=True), want, rtol=0, atol=2e-6)


def test_h3_120_hand_computed() -> None:
    """roll 0.2, pitch -0.31, collective 0.6 on H3_120 (copter-heli's 1460..1740 us):
    servo 1 = 0.45 (0.866025 * 0.2 + 0.5 * -0.31) + 0.46 + 0.6 * 0.28, out 2 s - 1, PWM 1000 + 1000 s:
    0.636192 -> 1636 us, 0.480308 -> 1480 us, 0.7675 -> 1767 us (truncated)."""
    for float32 in (False, True):
        m = ardupilot_mix(0.2, -0.31, 0.6, heli(), float32=float32)
        scaled = 0.6 * 0.28 + 0.46
        s1 = 0.45 * (C30 * 0.2 + 0.5 * -0.31) + scaled
        s2 = 0.45 * (-C30 * 0.2 + 0.5 * -0.31) + scaled
        s3 = 0.45 * (0.0 * 0.2 - 1.0 * -0.31) + scaled
        tol = 1e-6 if float32 else 1e-15
        assert m.collective_scaled == pytest.approx(scaled, abs=tol)
        np.testing.assert_allclose(m.outputs, [2 * s - 1 for s in (s1, s2, s3)], atol=2 * tol)
        want = [1000 + 1000 * s for s in (s1, s2, s3)]
        np.testing.assert_allclose(m.pwm_exact, want, atol=1e-3 if float32 else 1e-9)
        assert (s1, s2, s3) == pytest.approx((0.6361923, 0.4803077, 0.7675), abs=1e-7)
        assert m.pwm == (1636, 1480, 1767)


def test_cyclic_limit_and_collective_clip() -> None:
    """move_actuators: |(pitch, roll)| > H_CYC_MAX / 4500 scales both onto that circle; collective
    clipped to 0..1, scaled to (H_COL_MIN + c (H_COL_MAX - H_COL_MIN) - 1000) / 1000."""
    h = heli(H_CYC_MAX=2250)
    m = ardupilot_mix(0.6, -0.8, 1.3, h, float32=False)
    assert m.cyclic_limited and m.collective_limited
    assert (m.roll, m.pitch) == pytest.approx((0.3, -0.4), abs=1e-15)
    assert m.collective == 1.0 and m.collective_scaled == pytest.approx(0.74, abs=1e-15)
    m = ardupilot_mix(0.3, -0.3, 0.5, h, float32=False)
    assert not m.cyclic_limited and not m.collective_limited and (m.roll, m.pitch) == (0.3, -0.3)
    m = ardupilot_mix(0.0, 0.0, -0.2, h, float32=False)
    assert m.collective_limited and m.pwm == (1460, 1460, 1460)


def test_trim_reversal_and_forced_endpoints() -> None:
    """SRV_Channels::set_output_pwm_trimmed: pwm - 1500 + trim (1500 - pwm + trim reversed),
    clipped to 1000..2000 whatever SERVOn_MIN/MAX say (the swash forces them)."""
    base = ardupilot_mix(0.3, 0.1, 0.5, heli(), float32=False).pwm_exact
    h = heli(SERVO1_TRIM=1530, SERVO2_REVERSED=1, SERVO3_TRIM=1460, SERVO3_REVERSED=1)
    m = ardupilot_mix(0.3, 0.1, 0.5, h, float32=False)
    np.testing.assert_allclose(m.pwm_exact, [base[0] + 30, 3000 - base[1], 2960 - base[2]], atol=1e-9)
    m = ardupilot_mix(1.0, 0.0, 1.0, heli(H_CYC_MAX=4500, SERVO1_MAX=1900))
    assert m.pwm[0] == 2000 and m.pwm[1] < 1500


@pytest.mark.parametrize("run", [FIRMWARE_RUN_1, FIRMWARE_RUN_2])
def test_firmware_recorded_pwms_reproduced_to_the_microsecond(run: Recorded) -> None:
    params: dict[str, float] = dict(COPTER_HELI)
    for update, rc, want in run:
        params.update(update)
        h = ArduPilotHeli.from_params(params)
        roll, pitch, yaw = ((v - 1500) / 500 for v in (rc[0], rc[1], rc[3]))
        got = (*ardupilot_mix(roll, pitch, (rc[2] - 1000) / 1000, h).pwm, ardupilot_tail_pwm(yaw, h))
        assert got == want, (update, rc)
    assert ardupilot_rsc_pwm(0.0, h) == 1000  # channel 8 at rest, rotor off


@pytest.mark.parametrize("name", list(SETUPS))
def test_unmix_inverts_calculate(name: str) -> None:
    h = heli(**SETUPS[name])
    for r, p, c in INPUTS:
        cs = h.collective_scaled(c)
        assert h.unmix(h.swash_outputs(r, p, cs)) == pytest.approx((r, p, cs), abs=1e-9)


# --- the physical head ------------------------------------------------------------------------------


def expected_pitches(h: ArduPilotHeli, roll: float, pitch: float, coll: float) -> tuple[float, float, float]:
    """What the head built from the same parameters must do: collective linear between
    H_COL_ANG_MIN and MAX; cyclic k 450 per unit, k = blade pitch per us of collective."""
    k = math.radians(h.col_ang_max_deg - h.col_ang_min_deg) / (h.col_max_us - h.col_min_us)
    theta = math.radians(h.col_ang_min_deg + coll * (h.col_ang_max_deg - h.col_ang_min_deg))
    return theta, -k * 450.0 * pitch, k * 450.0 * roll


@pytest.mark.parametrize("name", list(SETUPS))
def test_firmware_and_plant_agree_by_construction(name: str) -> None:
    h, s = heli(**SETUPS[name]), plate(SETUPS[name])
    for r, p, c in INPUTS:
        m = ardupilot_mix(r, p, c, h, float32=False)
        (theta, eps, eta), refused, saturated = s.swash_pitches(m.pwm_exact)
        assert (refused, saturated) == (0, 0)
        # H_SW_LIN_SVO's constants 0.766044 and 1.145916 are sin(50 deg) and 1/(50 deg) to 6-7
        # digits: against an exact 50-degree arm they leave a relative 6e-7
        tol = 2e-7 if h.sw_lin_svo else 1e-9
        assert (theta, eps, eta) == pytest.approx(expected_pitches(h, m.roll, m.pitch, m.collective), abs=tol)
        # the firmware's truncated integers: within 1 us of travel
        (theta_i, eps_i, eta_i), _, _ = s.swash_pitches(m.pwm)
        k = s.head.theta_m_per_us_rad
        assert abs(theta_i - theta) < 1.01 * k and abs(eps_i - eps) < 2.01 * k and abs(eta_i - eta) < 2.01 * k


@pytest.mark.parametrize("name", list(SETUPS))
def test_plant_round_trip_interior(name: str) -> None:
    s = plate(SETUPS[name])
    rng = np.random.default_rng(7)
    h = s.head
    # interior: collective in the middle of its range, cyclic inside the firmware's circle (an
    # H3_140 plate's corners need up to sqrt(2) times the travel of a tilt: they may clip servos)
    mid, half = np.mean(h.theta_m_rad), 0.5 * np.ptp(h.theta_m_rad)
    for _ in range(40):
        r, az = s.cyclic_max_rad * math.sqrt(rng.uniform(0.0, 0.45)), rng.uniform(-math.pi, math.pi)
        u = np.array([mid + half * rng.uniform(-0.6, 0.6), rng.uniform(-0.3, 0.3), r * math.cos(az),
                      r * math.sin(az)])  # fmt: skip
        pwm = s.pwm_from_pitches(u)
        reading = s.pitches_from_pwm(pwm)
        assert (reading.refused, reading.saturated) == (0, 0)
        np.testing.assert_allclose(reading.as_array(), u, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.pwm_from_pitches(reading.as_array()), pwm, rtol=0, atol=1e-6)


def test_sign_conventions() -> None:
    s, h = Swashplate.load(XCELL_TOML), ArduPilotHeli.from_params(read_parm(XCELL_PARM))

    def pitches(roll: float, pitch: float, coll: float, yaw: float = 0.0) -> np.ndarray:
        m = ardupilot_mix(roll, pitch, coll, h, float32=False)
        return s.pitches_from_pwm([*m.pwm_exact, ardupilot_tail_pwm(yaw, h)]).as_array()

    level = pitches(0.0, 0.0, 0.5)
    assert level == pytest.approx([0.1, 0.0, 0.0, 0.0], abs=1e-12)
    fwd = pitches(0.0, -0.3, 0.5)  # ArduPilot pitch < 0: nose down, forward stick
    assert fwd[EPS] == pytest.approx(0.0008 * 450 * 0.3, abs=1e-12) and abs(fwd[ETA]) < 1e-12
    right = pitches(0.3, 0.0, 0.5)  # roll right
    assert right[ETA] == pytest.approx(0.108, abs=1e-12) and abs(right[EPS]) < 1e-12
    # beyond H_CYC_MAX (1750 / 4500 = 0.389) the firmware's circle lands on the plant's limit
    assert pitches(0.0, -0.8, 0.5)[EPS] == pytest.approx(0.14, abs=1e-12)
    assert pitches(0.0, 0.0, 0.9)[THETA_M] == pytest.approx(0.26, abs=1e-12)
    # the firmware's integer PWMs: within a microsecond of plate travel (8e-4 rad)
    m = ardupilot_mix(0.0, -0.3, 0.5, h)
    assert s.pitches_from_pwm([*m.pwm, 1500]).pitches_rad[EPS] == pytest.approx(0.108, abs=8e-4)
    assert pitches(0.0, 0.0, 0.5, yaw=0.5)[THETA_T] == pytest.approx(-0.175, abs=1e-12)  # nose right
    # clockwise main rotor: the nose-right tail pitch is the positive one
    cw = Swashplate.from_ardupilot_params(read_parm(XCELL_PARM), tail_theta_t_rad=TAIL,
                                          main_rotor_rotation="clockwise")  # fmt: skip
    assert cw.tail_pitch(ardupilot_tail_pwm(0.5, h))[0] == pytest.approx(0.175)
    # the firmware's own forward-stick frame (recorded: RC2 1300 -> 1510, 1510, 1780 us)
    # (pitch -0.4: eps = k 450 0.4 with k = 14 deg / 280 us, i.e. 9 deg; integer PWMs within 1 us)
    (_, eps, eta), _, _ = plate({}).swash_pitches((1510, 1510, 1780))
    assert eps == pytest.approx(math.radians(9.0), abs=1e-12) and abs(eta) < 1e-12
    (_, eps, eta), _, _ = plate({}).swash_pitches((1755, 1444, 1600))  # roll right 0.4, RC1 1700
    assert eta == pytest.approx(math.radians(9.0), abs=math.radians(0.05)) and abs(eps) < math.radians(0.05)


def test_phase_angle_is_compensated_only_where_the_firmware_does() -> None:
    """H3 with H_SW_H3_PHANG: a head lagging by that angle gets pure pitch from pure pitch."""
    for phang in (-25, 10, 30):
        s, h = plate({"H_SW_TYPE": 0, "H_SW_H3_PHANG": phang}), heli(H_SW_TYPE=0, H_SW_H3_PHANG=phang)
        assert s.head.phase_deg == phang
        (_, eps, eta), _, _ = s.swash_pitches(ardupilot_mix(0.0, -0.4, 0.5, h, float32=False).pwm_exact)
        assert eta == pytest.approx(0.0, abs=1e-12) and eps > 0
    # H3_120 ignores PHANG: the head is taken as phase-correct
    assert plate({"H_SW_TYPE": 3, "H_SW_H3_PHANG": 20}).head.phase_deg == 0.0


# --- the X-Cell file ---------------------------------------------------------------------------------


def test_xcell_file_matches_its_parm() -> None:
    s = Swashplate.load(XCELL_TOML)
    assert s == Swashplate.load() and s.kind == SwashType.H3_120
    t = Swashplate.from_ardupilot_params(read_parm(XCELL_PARM), tail_theta_t_rad=TAIL, name=s.name)

    def flat(x: object) -> list[object]:
        if isinstance(x, dict):
            return [v for k in sorted(x) for v in flat(x[k])]
        return [v for item in x for v in flat(item)] if isinstance(x, list) else [x]

    for a, b in zip(flat(as_table(s)), flat(as_table(t)), strict=True):
        assert a == (pytest.approx(b, rel=1e-7, abs=1e-12) if isinstance(b, float) else b)
    h = ArduPilotHeli.from_params(read_parm(XCELL_PARM))
    assert h.collective_for_pitch(0.0997) == pytest.approx(h.col_hover, abs=1e-3)  # hover trim ~0.10 rad


def test_xcell_pwm_range_maps_into_the_plant_limits() -> None:
    s = Swashplate.load(XCELL_TOML)
    lim = Airframe.load().limits
    grid = np.linspace(1000.0, 2000.0, 11)
    lo = np.array([lim.theta_m_rad[0], lim.theta_t_rad[0], lim.eps_rad[0], lim.eta_rad[0]])
    hi = np.array([lim.theta_m_rad[1], lim.theta_t_rad[1], lim.eps_rad[1], lim.eta_rad[1]])
    for a, b, c in itertools.product(grid, grid, grid):
        u = s.pitches_from_pwm((a, b, c, a)).as_array()
        assert np.all(u >= lo - 1e-12) and np.all(u <= hi + 1e-12)
    # ArduPilot's whole collective range is the plant's, and its cyclic circle touches the box
    h = ArduPilotHeli.from_params(read_parm(XCELL_PARM))
    for coll, want in ((0.0, -0.10), (1.0, 0.30)):
        assert s.swash_pitches(ardupilot_mix(0.0, 0.0, coll, h).pwm)[0][0] == pytest.approx(want, abs=1e-12)
    assert s.cyclic_max_rad == pytest.approx(0.0008 * 450 * h.cyc_max / 4500, abs=1e-15) == lim.eps_rad[1]
    assert s.tail_pitch(1000.0)[0] == lim.theta_t_rad[1] and s.tail_pitch(2000.0)[0] == lim.theta_t_rad[0]
    # every corner of the plant's pitch box is reachable without clipping a servo
    for corner in itertools.product(*zip(lo, hi, strict=True)):
        pwm = s.pwm_from_pitches(corner)
        assert np.all((pwm >= 1000.0) & (pwm <= 2000.0))
        assert s.pitches_from_pwm(pwm).as_array() == pytest.approx(corner, abs=1e-12)


# --- bad input ---------------------------------------------------------------------------------------


def test_bad_pwm_gives_finite_clipped_pitches_and_counts() -> None:
    s = Swashplate.load(XCELL_TOML)
    for bad in (math.nan, 0.0, 65535.0, math.inf, -math.inf, -5.0):
        r = s.pitches_from_pwm((bad, bad, bad, bad))
        assert np.all(np.isfinite(r.as_array())) and r.refused == 4
    assert s.pitches_from_pwm((0, 0, 0, 0)).pitches_rad == pytest.approx((-0.10, 0.35, 0.0, 0.0), abs=1e-12)
    r = s.pitches_from_pwm((65535, 65535, 65535, 65535))
    assert r.pitches_rad == pytest.approx((0.30, -0.35, 0.0, 0.0), abs=1e-12)
    r = s.pitches_from_pwm((math.nan, math.nan, math.nan, math.nan))  # neutral / mid travel
    assert r.pitches_rad == pytest.approx((0.10, 0.0, 0.0, 0.0), abs=1e-12)
    r = s.pitches_from_pwm((math.nan, 1500, 1500, 1500))  # one servo replaced by its neutral
    assert r.refused == 1 and r.pitches_rad == pytest.approx((0.10, 0.0, 0.0, 0.0), abs=1e-12)
    # one servo pinned at an end: the plate tilts past the cyclic box and is clipped there
    r = s.pitches_from_pwm((2000, 1000, 1500, 1500))
    assert r.refused == 0 and r.saturated == 1 and r.pitches_rad[ETA] == 0.14
    assert s.pitches_from_pwm(np.full(16, 1500.0)).refused == 0  # a whole 16-channel frame
    with pytest.raises(ValueError, match="4 channels"):
        s.pitches_from_pwm((1500, 1500, 1500))
    with pytest.raises(ValueError, match="finite pitches"):
        s.pwm_from_pitches((math.nan, 0, 0, 0))
    # pitches beyond the limits are clipped before mixing
    np.testing.assert_allclose(s.pwm_from_pitches((9.0, 9.0, 0.0, 0.0)), [1750, 1750, 1750, 1000])
    with pytest.raises(ValueError, match="roll_in"):
        ardupilot_mix(math.nan, 0.0, 0.5, heli())


def test_rotor_request_from_channel_8() -> None:
    h = heli(H_RSC_IDLE=10)
    for t in (0.0, 0.1, 0.66, 1.0):
        pwm = ardupilot_rsc_pwm(t, h)
        r = rsc_request(pwm, idle=h.rsc_idle_pct / 100)
        assert r.throttle == pytest.approx(t, abs=1e-3) and r.refused == 0
        assert r.interlock == (t > 0.1)
    assert ardupilot_rsc_pwm(0.66, heli(H_RSC_SETPOINT=66)) == 1660
    r = rsc_request(1200.0, pwm_min_us=1100, pwm_max_us=1900, reversed=True)
    assert r.throttle == pytest.approx(0.875) and r.interlock
    for bad, want in ((math.nan, 0.0), (0.0, 0.0), (65535.0, 1.0)):
        r = rsc_request(bad)
        assert r.refused == 1 and r.throttle == want and math.isfinite(r.throttle)
    assert not rsc_request(math.nan).interlock


# --- configuration errors ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "want"),
    [
        ('swash_type = "H3_120"', 'swash_type = "H4_90"', "swash_type: expected one of H3, H1, H3_140"),
        ('swash_type = "H3_120"', 'swash_type = "H3"', "swash_type H3 needs servo_azimuth_deg"),
        ("theta_m_per_us_rad = 0.0008", "theta_m_per_us_rad = 0.0", "head.theta_m_per_us_rad: expected"),
        ("reversed = [false, false, false]", "reversed = [false, 0, false]", "servos.reversed[1]: expected"),
        ("pwm_neutral_us = [1500.0, 1500.0, 1500.0]", "pwm_neutral_us = [1500.0, 2100.0, 1500.0]",
         "servo 2: need pwm_min_us < pwm_neutral_us < pwm_max_us"),
        ("eps_rad = [-0.14, 0.14]", "eps_rad = [0.14, -0.14]", "eps_rad: lower limit 0.14 must be below"),
        ("theta_t_rad = [0.35, -0.35]", "theta_t_rad = [0.35, nan]", "tail.theta_t_rad[1]: expected"),
        ("cyclic_ratio = 1.0", "cyclic_ratio = 1.0\ncyclic_gain = 2.0", "unknown key 'cyclic_gain'"),
    ],
)
def test_toml_errors_name_the_key(tmp_path: Path, old: str, new: str, want: str) -> None:
    text = XCELL_TOML.read_text()
    assert old in text
    p = tmp_path / "swash.toml"
    p.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError, match=want.replace("[", r"\[").replace("(", r"\(")) as exc:
        Swashplate.load(p)
    assert str(p) in str(exc.value)


@pytest.mark.parametrize(
    ("params", "want"),
    [
        ({"H_SW_TYPE": 4}, "only 0 \\(H3\\)"),
        ({"H_TAIL_TYPE": 3}, "H_TAIL_TYPE 3"),
        ({"H_COL_MIN": 1700, "H_COL_MAX": 1600}, "H_COL_MIN 1700 must be below"),
        ({"H_COL_ANG_MIN": 5, "H_COL_ANG_MAX": 5}, "H_COL_ANG_MIN"),
        ({"SERVO2_FUNCTION": 0}, "SERVO2_FUNCTION 0"),
        ({"H_SW_TYPE": 0, "H_SW_H3_PHANG": 40}, "H_SW_H3_PHANG"),
        ({"H_CYC_MAX": math.nan}, "not a finite number"),
        ({"SERVO3_TRIM": 2100, "SERVO3_MAX": 1900}, "TRIM"),
        ({"H_SW_TYPE": 0, "H_SW_H3_SV1_POS": 0, "H_SW_H3_SV2_POS": 0, "H_SW_H3_SV3_POS": 180}, "do not span"),
    ],
)
def test_parameter_errors(params: dict[str, float], want: str) -> None:
    with pytest.raises(ValueError, match=want):
        plate(params)


def test_read_parm(tmp_path: Path) -> None:
    p = tmp_path / "x.parm"
    p.write_text("# comment\nH_COL_MIN 1460.000000\nH_COL_MAX,1740 # trailing\n\nH_COL_MIN 1450\n")
    assert read_parm(p) == {"H_COL_MIN": 1450.0, "H_COL_MAX": 1740.0}
    # integer parameters as AP_Param::set_float stores them: + 0.01 away from zero, truncated
    assert heli(H_COL_MIN=1459.995).col_min_us == 1460
    assert heli(H_SW_H3_PHANG=-4.995, H_SW_TYPE=0).sw_h3_phang_deg == -5
    p.write_text("H_COL_MIN\n")
    with pytest.raises(ConfigError, match="expected NAME VALUE"):
        read_parm(p)
    p.write_text("H_COL_MIN abc\n")
    with pytest.raises(ConfigError, match="not a number"):
        read_parm(p)


# --- the compiled PWM -> pitches kernel against the numpy formulation it replaced ------------------


def _reference_swash_pitches(s: Swashplate, pwm: np.ndarray) -> tuple[np.ndarray, int, int]:
    """SERVO1-3 PWM -> ((theta_m, eps, eta), refused, saturated), as Swashplate computed it in
    numpy before swash_pitches_kernel: ball travel, plate, blades, clip."""
    sv, h = s.servos, s.head
    lo, hi, mid = np.array(sv.pwm_min_us), np.array(sv.pwm_max_us), np.array(sv.pwm_neutral_us)
    finite = np.isfinite(pwm)
    p = np.where(finite, pwm, mid)
    bad = ~finite | (p < lo) | (p > hi)
    u = (np.clip(p, lo, hi) - mid) / 500.0 * np.where(np.array(sv.reversed), -1.0, 1.0)
    if sv.arm_max_deg > 0.0:
        a = math.radians(sv.arm_max_deg)
        u = np.sin(a * u) / math.sin(a)
    height, tilt_p, tilt_r = np.linalg.inv(s.servo_matrix) @ (500.0 * u)
    c, sn = math.cos(math.radians(h.phase_deg)), math.sin(math.radians(h.phase_deg))
    disc_p, disc_r = tilt_p * c - tilt_r * sn, tilt_r * c + tilt_p * sn
    k, kc = h.theta_m_per_us_rad, h.cyclic_ratio * h.theta_m_per_us_rad
    sign = -1.0 if h.collective_reversed else 1.0
    blades = np.array([h.theta_m_at_neutral_rad + sign * k * height, -kc * disc_p, kc * disc_r])
    lim_lo = np.array([h.theta_m_rad[0], h.eps_rad[0], h.eta_rad[0]])
    lim_hi = np.array([h.theta_m_rad[1], h.eps_rad[1], h.eta_rad[1]])
    clipped = np.clip(blades, lim_lo, lim_hi)
    return clipped, int(np.count_nonzero(bad)), int(np.count_nonzero(clipped != blades))


@pytest.mark.parametrize("setup", [*SETUPS, "xcell_toml", "collective_reversed"])
def test_compiled_swash_pitches_equal_the_numpy_reference(setup: str) -> None:
    if setup == "xcell_toml":
        s = Swashplate.load(XCELL_TOML)
    elif setup == "collective_reversed":
        s = Swashplate.from_ardupilot_params({**COPTER_HELI, "H_SW_COL_DIR": 1, "SERVO2_TRIM": 1450},
                                             tail_theta_t_rad=TAIL, cyclic_ratio=1.3)  # fmt: skip
    else:
        s = plate(SETUPS[setup])
    rng = np.random.default_rng(11)
    specials = (math.nan, math.inf, -math.inf, 0.0, 65535.0, 999.0, 2001.0)
    for n in range(3000):
        pwm = rng.uniform(900.0, 2100.0, 3)
        if n % 5 == 0:
            pwm[rng.integers(0, 3)] = specials[n % len(specials)]
        want, refused, saturated = _reference_swash_pitches(s, pwm)
        got, got_refused, got_saturated = s.swash_pitches(pwm)
        assert (got_refused, got_saturated) == (refused, saturated), pwm
        np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12)
