"""The parameter table: names, ranges, typed views, and PARAM_* over real pymavlink packing."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from autopilot.params_table import (
    INT32,
    REAL32,
    SPECS,
    Access,
    FailsafeTimeouts,
    ParamTable,
)
from autopilot.tlc.gains import Gains
from heli_common.geo import GeoPoint
from heli_common.vehicle.airframe import Airframe

GAINS = Gains.load()
AIRFRAME = Airframe.load()
HOME = GeoPoint(47.397742, 8.545594, 488.0)


@pytest.fixture
def table() -> ParamTable:
    return ParamTable(GAINS, AIRFRAME.limits, 100.0, home=HOME)


class Link:
    def __init__(self, table: ParamTable) -> None:
        self.table = table
        self.gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.veh_in, self.gcs_in = mavlink.MAVLink(None), mavlink.MAVLink(None)

    def send(self, msg: Any, armed: bool = False) -> list[Any]:
        (decoded,) = self.veh_in.parse_buffer(bytearray(msg.pack(self.gcs)))
        out: list[Any] = []
        for reply in self.table.handle(decoded, armed):
            out.extend(self.gcs_in.parse_buffer(bytearray(reply.pack(self.veh))))
        return out


def param_set(name: str, value: float, ptype: int = REAL32, target: int = 1) -> Any:
    return mavlink.MAVLink_param_set_message(target, 1, name.encode(), value, ptype)


def f32(x: float) -> float:
    return float(np.float32(x))


# ------------------------------------------------------------------ table


def test_names_are_unique_short_and_stable() -> None:
    names = [s.name for s in SPECS]
    # 44 of the vehicle, 30 PID_ of the baseline, 10 SIM_ of the world, 8 of its sensors
    assert len(names) == len(set(names)) == 97
    assert all(0 < len(n) <= 16 and n.isascii() and n.upper() == n for n in names)
    assert names[:3] == ["TLC_L1_W_X", "TLC_L1_W_Y", "TLC_L1_W_Z"]
    for required in (
        "TLC_L1_Z_X",
        "TLC_L4_W_Y",
        "TLC_DIFF_W",
        "TLC_DIFF_Z",
        "LIM_TM_MIN",
        "LIM_ETA_MAX",
        "TLC_TILT_MAX",
        "TLC_YAW_HOLD_V",
        "TLC_MAX_SPEED",
        "TLC_RATE_HZ",
        "FS_STATE_TMO",
        "FS_OFFB_TMO",
        "HOME_LAT",
    ):
        assert required in names


def test_defaults_come_from_the_loaded_config(table: ParamTable) -> None:
    assert table.gains() == GAINS
    assert table.pitch_limits() == AIRFRAME.limits
    assert table.rate_hz() == 100.0
    assert table.failsafe() == FailsafeTimeouts()
    assert table.get("TLC_L2_W_Y") == GAINS.loop2_position_dynamics.omega_rad_s[1]
    assert table.get("TLC_L3_Z_R") == GAINS.loop3_attitude_kinematics.zeta[0]
    assert table.get("LIM_TM_MAX") == AIRFRAME.limits.theta_m_rad[1]
    assert table.get("HOME_LAT") == HOME.lat_deg
    assert table.get(table.index("TLC_DIFF_W")) == GAINS.differentiator.omega_rad_s


def test_ranges_come_from_the_config_specs() -> None:
    spec = {s.name: s for s in SPECS}
    assert (spec["TLC_L1_W_X"].lo, spec["TLC_L1_W_X"].hi) == (0.001, 200.0)
    assert (spec["TLC_DIFF_W"].lo, spec["TLC_DIFF_W"].hi) == (0.1, 200.0)
    assert (spec["LIM_TT_MIN"].lo, spec["LIM_TT_MIN"].hi) == (-0.8, 0.8)
    assert (spec["TLC_TILT_MAX"].lo, spec["TLC_TILT_MAX"].hi) == (0.01, 1.2)
    assert spec["TLC_RATE_HZ"].access is Access.DISARMED_ONLY
    assert spec["LIM_EPS_MAX"].access is Access.DISARMED_ONLY
    assert spec["HOME_ALT"].access is Access.READ_ONLY
    assert all(s.param_type == REAL32 for s in SPECS)  # one encoding every GCS reads alike


def test_set_updates_the_typed_views(table: ParamTable) -> None:
    g0 = table.generation
    assert table.set("TLC_L1_W_Z", 0.25).accepted
    assert table.set("TLC_L4_Z_P", 0.9).accepted
    assert table.set("TLC_DIFF_W", 7.0).accepted
    assert table.set("TLC_TILT_MAX", 0.5).accepted
    assert table.set("LIM_EPS_MIN", -0.1).accepted
    assert table.set("FS_OFFB_TMO", 2.0).accepted
    assert table.set("TLC_RATE_HZ", 200.0).accepted
    assert table.generation == g0 + 7
    g = table.gains()
    assert g.loop1_position_kinematics.omega_rad_s == (0.1875, 0.1875, 0.25)
    assert g.loop4_attitude_dynamics.zeta == (0.707, 0.9, 0.707)
    assert g.differentiator.omega_rad_s == 7.0 and g.limits.tilt_max_rad == 0.5
    assert g.name == GAINS.name
    assert table.pitch_limits().eps_rad == (-0.1, 0.14)
    assert table.failsafe().offboard_timeout_s == 2.0 and table.rate_hz() == 200.0


def test_same_value_is_accepted_without_change(table: ParamTable) -> None:
    g0 = table.generation
    r = table.set("TLC_L1_Z_X", f32(0.707))  # what a GCS echoes back after a read
    assert r.accepted and table.get("TLC_L1_Z_X") == 0.707 and table.generation == g0


def test_float32_bound_is_accepted_as_the_bound(table: ParamTable) -> None:
    r = table.set("TLC_TILT_MAX", f32(1.2))  # 1.2000000477 > 1.2 but means 1.2
    assert r.accepted and table.get("TLC_TILT_MAX") == 1.2


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("TLC_L1_W_X", math.nan),
        ("TLC_L1_W_X", math.inf),
        ("TLC_L1_W_X", -math.inf),
        ("TLC_L1_W_X", 0.0),
        ("TLC_L1_W_X", 201.0),
        ("TLC_L2_Z_Y", 0.01),
        ("TLC_DIFF_Z", 6.0),
        ("TLC_TILT_MAX", 1.3),
        ("TLC_YAW_HOLD_V", -0.1),
        ("TLC_RATE_HZ", 20.0),
        ("LIM_TM_MIN", -0.7),
        ("FS_STATE_TMO", 0.0),
    ],
)
def test_out_of_range_or_non_finite_is_refused_unchanged(table: ParamTable, name: str, value: float) -> None:
    before, g0 = table.get(name), table.generation
    r = table.set(name, value)
    assert not r.accepted and r.value == before and r.reason
    assert table.get(name) == before and table.generation == g0


def test_unknown_name_is_refused(table: ParamTable) -> None:
    r = table.set("NOPE", 1.0)
    assert not r.accepted and math.isnan(r.value)


def test_read_only_is_refused(table: ParamTable) -> None:
    assert not table.set("HOME_ALT", 10.0).accepted
    assert not table.set("MAV_SYS_ID", 2).accepted
    assert table.get("HOME_ALT") == HOME.alt_amsl_m


def test_disarmed_only_is_refused_while_armed(table: ParamTable) -> None:
    assert not table.set("TLC_RATE_HZ", 200.0, armed=True).accepted
    assert not table.set("LIM_TM_MAX", 0.25, armed=True).accepted
    assert table.set("TLC_L1_W_X", 0.2, armed=True).accepted  # gains: any time
    assert table.rate_hz() == 100.0


def test_min_not_below_max_is_refused(table: ParamTable) -> None:
    r = table.set("LIM_TM_MIN", 0.35)  # above LIM_TM_MAX = 0.30, though inside [-0.6, 0.6]
    assert not r.accepted and "theta_m" in r.reason
    assert table.pitch_limits() == AIRFRAME.limits


def test_initial_value_out_of_range_is_an_error() -> None:
    with pytest.raises(ValueError, match="TLC_RATE_HZ"):
        ParamTable(GAINS, AIRFRAME.limits, 5000.0)


param_names = st.sampled_from([s.name for s in SPECS if s.access is not Access.READ_ONLY])


@given(name=param_names, u=st.floats(0.0, 1.0))
@settings(max_examples=200, deadline=None)
def test_any_in_range_value_is_accepted_unless_inconsistent(name: str, u: float) -> None:
    table = ParamTable(GAINS, AIRFRAME.limits, 100.0)
    s = table.spec(name)
    value = s.lo + u * (s.hi - s.lo)
    if s.lo_open and value == s.lo:
        value = s.hi
    r = table.set(name, value)
    if name.startswith("LIM_"):
        short = name[4:-4]
        other = table.get(f"LIM_{short}_{'MAX' if name.endswith('MIN') else 'MIN'}")
        consistent = value < other if name.endswith("MIN") else value > other
        assert r.accepted == consistent
    else:
        assert r.accepted
    assert table.get(name) == r.value
    if r.accepted:  # exactly the value, or a bound/current value it rounds to in float32
        assert f32(r.value) == f32(value)


@given(name=param_names, value=st.one_of(st.floats(allow_nan=True), st.floats(1e3, 1e30)))
@settings(max_examples=200, deadline=None)
def test_refused_sets_never_change_anything(name: str, value: float) -> None:
    table = ParamTable(GAINS, AIRFRAME.limits, 100.0)
    before = [table.get(i) for i in range(len(table))]
    if not table.set(name, value).accepted:
        assert [table.get(i) for i in range(len(table))] == before


# ------------------------------------------------------------------ messages


def test_request_list_sends_every_param_with_count_and_index(table: ParamTable) -> None:
    out = Link(table).send(mavlink.MAVLink_param_request_list_message(1, 1))
    assert [m.get_type() for m in out] == ["PARAM_VALUE"] * len(SPECS)
    assert [m.param_index for m in out] == list(range(len(SPECS)))
    assert {m.param_count for m in out} == {len(SPECS)}
    assert [m.param_id for m in out] == [s.name for s in SPECS]
    by = {m.param_id: m for m in out}
    assert by["TLC_L1_Z_X"].param_value == pytest.approx(0.707)
    assert by["TLC_L1_Z_X"].param_type == REAL32


def test_request_read_by_name_and_by_index(table: ParamTable) -> None:
    link = Link(table)
    (m,) = link.send(mavlink.MAVLink_param_request_read_message(1, 1, b"TLC_DIFF_W", -1))
    assert (m.param_id, m.param_value, m.param_index) == ("TLC_DIFF_W", 5.0, table.index("TLC_DIFF_W"))
    (m,) = link.send(mavlink.MAVLink_param_request_read_message(1, 1, b"ignored", 3))
    assert m.param_id == SPECS[3].name and m.param_index == 3


def test_request_read_unknown_is_statustext(table: ParamTable) -> None:
    link = Link(table)
    (m,) = link.send(mavlink.MAVLink_param_request_read_message(1, 1, b"NOPE", -1))
    assert m.get_type() == "STATUSTEXT"
    (m,) = link.send(mavlink.MAVLink_param_request_read_message(1, 1, b"", 999))
    assert m.get_type() == "STATUSTEXT"


def test_param_set_accepted_echoes_new_value(table: ParamTable) -> None:
    (m,) = Link(table).send(param_set("TLC_L2_W_X", 0.8))
    assert (m.param_id, m.param_value, m.param_index) == ("TLC_L2_W_X", f32(0.8), table.index("TLC_L2_W_X"))
    assert m.param_count == len(SPECS)
    assert table.gains().loop2_position_dynamics.omega_rad_s[0] == f32(0.8)


def test_param_set_refused_echoes_unchanged_value(table: ParamTable) -> None:
    out = Link(table).send(param_set("TLC_L2_W_X", 500.0))
    assert [m.get_type() for m in out] == ["PARAM_VALUE", "STATUSTEXT"]
    assert out[0].param_value == pytest.approx(0.75)


def test_param_set_while_armed_refused_for_rate(table: ParamTable) -> None:
    out = Link(table).send(param_set("TLC_RATE_HZ", 200.0), armed=True)
    assert out[0].param_value == 100.0 and out[1].get_type() == "STATUSTEXT"


def test_param_set_unknown_is_statustext_only(table: ParamTable) -> None:
    (m,) = Link(table).send(param_set("NOPE", 1.0))
    assert m.get_type() == "STATUSTEXT"


def test_sixteen_character_name_without_terminator(table: ParamTable) -> None:
    # every one of our names is shorter, but the decoder must cope with exactly 16
    link = Link(table)
    (m,) = link.send(param_set("TLC_YAW_HOLD_V__", 1.0))
    assert m.get_type() == "STATUSTEXT" and b"TLC_YAW_HOLD_V__" in m.text.encode()


def test_messages_for_other_systems_are_ignored(table: ParamTable) -> None:
    assert Link(table).send(param_set("TLC_L2_W_X", 0.8, target=7)) == []
    assert table.get("TLC_L2_W_X") == 0.75
    assert Link(table).send(mavlink.MAVLink_param_request_list_message(7, 1)) == []
    assert len(Link(table).send(mavlink.MAVLink_param_request_list_message(0, 0))) == len(SPECS)


def test_the_system_id_reads_as_the_number_it_is(table: ParamTable) -> None:
    (m,) = Link(table).send(mavlink.MAVLink_param_request_read_message(1, 1, b"MAV_SYS_ID", -1))
    assert m.param_type == REAL32 and m.param_value == 1.0


@given(value=st.integers(-(2**24), 2**24))
@settings(max_examples=200, deadline=None)
def test_c_cast_int32_survives_pack_and_parse(value: int) -> None:
    """Should a client send an INT32 anyway, its C-cast value is decoded as itself."""
    table = ParamTable(GAINS, AIRFRAME.limits, 100.0)
    msg = mavlink.MAVLink_param_set_message(1, 1, b"MAV_SYS_ID", float(value), INT32)
    (parsed,) = mavlink.MAVLink(None).parse_buffer(bytearray(msg.pack(mavlink.MAVLink(None, 255, 190))))
    assert table.decode_value(parsed.param_value, INT32) == value


@given(name=st.sampled_from([s.name for s in SPECS if s.param_type == REAL32]))
@settings(max_examples=60, deadline=None)
def test_param_value_round_trips_through_a_gcs_set(name: str) -> None:
    """Read a value, send it straight back: accepted, unchanged (float32 rounding aside)."""
    table = ParamTable(GAINS, AIRFRAME.limits, 100.0, home=HOME)
    link = Link(table)
    (m,) = link.send(mavlink.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
    before = table.get(name)
    out = link.send(param_set(name, m.param_value))
    assert out[0].param_value == m.param_value
    assert table.get(name) == before


def numbers_in(gains: object) -> int:
    """How many numbers a gain set's sections hold (an array counts its elements)."""
    n = 0
    for f in dataclasses.fields(gains):  # type: ignore[arg-type]
        value = getattr(gains, f.name)
        if dataclasses.is_dataclass(value):
            for sub in dataclasses.fields(value):
                v = getattr(value, sub.name)
                n += len(v) if isinstance(v, tuple) else int(isinstance(v, (int, float)))
    return n


def test_gains_dataclass_fields_all_mapped() -> None:
    """Every float in Gains has a parameter (a new gain field must get a name)."""
    gain_params = [s for s in SPECS if s.name.startswith("TLC_") and s.name != "TLC_RATE_HZ"]
    assert len(gain_params) == numbers_in(GAINS)


def test_pid_gains_all_mapped_and_live() -> None:
    """Every number in PidGains has a PID_ parameter; the table starts at the loaded gains,
    and a set changes just that element of the typed view."""
    from autopilot.pid.gains import PidGains

    pid = PidGains.load()
    assert len([s for s in SPECS if s.name.startswith("PID_")]) == numbers_in(pid)
    t = ParamTable(GAINS, AIRFRAME.limits, 100.0, pid_gains=pid)
    assert t.pid_gains() == pid
    assert t.get("PID_RATE_P_Y") == pid.rate.kp[2] and t.get("PID_TILT_MAX") == pid.limits.tilt_max_rad
    assert t.set("PID_RATE_P_P", 21.5, armed=True).accepted
    assert t.set("PID_VEL_IMAX", 99.0).accepted is False  # out of its range in gains.py
    got = t.pid_gains()
    assert got.rate.kp == (pid.rate.kp[0], 21.5, pid.rate.kp[2])
    assert dataclasses.replace(got, rate=pid.rate) == pid


def test_the_world_knobs_read_and_set_as_parameters() -> None:
    """SIM_ parameters start at the loaded world's values, are range-checked like the rest,
    and the table's world() is the loaded world with them applied (a knob set to the value
    it has changes nothing, even where the file sets servos one by one)."""
    from heli_common.world.config import World

    sc_world = World.load("everything")
    t = ParamTable(GAINS, AIRFRAME.limits, 100.0, world=sc_world)
    assert t.get("SIM_WIND_SPD") == 3.0 and t.get("SIM_WIND_DIR") == 270.0
    assert t.get("SIM_SERVO_DELAY") == 0.01 and t.get("SIM_SERVO_SPEED") == pytest.approx(0.14, rel=2e-3)
    assert t.world() == sc_world
    assert t.set("SIM_WIND_SPD", 150.0).accepted is False and t.get("SIM_WIND_SPD") == 3.0
    assert t.set("SIM_WIND_SPD", 8.0, armed=True).accepted  # a live knob: settable in flight
    assert t.world().wind.speed_m_s == 8.0
    assert t.set("SIM_SERVO_SPEED", 0.07).accepted  # twice as fast: every rate limit doubles
    assert t.world().servos.rate_rad_s[2] == pytest.approx(2 * 0.178 * math.pi / 3 / 0.14, rel=1e-6)
