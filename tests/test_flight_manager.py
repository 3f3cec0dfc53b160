"""The flight state machine on its own: typed commands in, replies and events out, no link.

Every command path (MAVLink or a script) goes through these checks, so they are tested
here once, with an injected time and state, and over the wire in test_ground_client.
"""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.flight import commands as c
from autopilot.flight.manager import FlightConfig, FlightManager, LandedState, MissionState
from autopilot.flight.modes import Mode
from autopilot.trajectory.analytic import StraightLine
from heli_common.geo import GeoPoint
from heli_common.mavlink import mission_items as ms
from heli_common.mavlink.mission_items import MissionItem

HOME = GeoPoint(47.4, 8.5, 488.0)
ON_GROUND = np.zeros(12)


def hovering(alt_m: float = 3.0) -> np.ndarray:
    x = np.zeros(12)
    x[2] = alt_m
    return x


def takeoff_mission() -> tuple[MissionItem, ...]:
    return (
        MissionItem(0, ms.FRAME_LOCAL_NED, ms.CMD_TAKEOFF, z=-2.5),
        MissionItem(1, ms.FRAME_LOCAL_NED, ms.CMD_WAYPOINT, x=20_000, z=-2.5),
    )


@pytest.fixture
def mgr() -> FlightManager:
    return FlightManager(FlightConfig(home=HOME, offboard_timeout_s=1.0))


def test_arming_needs_no_plan_and_holds_where_it_is(mgr: FlightManager) -> None:
    assert mgr.armable()
    assert mgr.execute(c.Arm(), 0.0, ON_GROUND).accepted
    assert mgr.armed and mgr.mode is Mode.HOLD
    assert mgr.execute(c.Takeoff(3.0), 0.0, ON_GROUND).accepted  # then a take-off (MAVSDK)
    assert mgr.mode is Mode.AUTO


def test_mission_mode_while_disarmed_starts_on_the_arming_tick(mgr: FlightManager) -> None:
    assert mgr.execute(c.SelectMission(), 0.0, ON_GROUND).result is c.Result.DENIED  # no mission
    mgr.set_mission_source(takeoff_mission)
    assert mgr.execute(c.SelectMission(), 0.0, ON_GROUND).accepted
    assert mgr.mode is Mode.AUTO and not mgr.armed  # reported as mission mode already
    reply = mgr.execute(c.Arm(), 7.0, ON_GROUND)
    assert reply.accepted and reply.text == "Armed: mission started"
    assert mgr.flight.t0_s == 7.0 and mgr.mission_state() is MissionState.ACTIVE


def test_arming_keeps_a_started_trajectory(mgr: FlightManager) -> None:
    """The scenario's autostart: the trajectory is started, then the vehicle armed."""
    line = StraightLine(start_nwu_m=(0.0, 0.0, 5.0), vel_nwu_m_s=(1.0, 0.0, 0.0), duration_s=10.0)
    assert mgr.execute(c.FlyTrajectory(line), 0.0, ON_GROUND).accepted
    assert mgr.execute(c.Arm(), 0.0, ON_GROUND).accepted
    assert mgr.mode is Mode.AUTO
    ref = mgr.flight.reference(2.0, ON_GROUND)
    assert ref is not None and ref[0] == pytest.approx(2.0) and ref[2] == pytest.approx(5.0)


def test_commands_that_need_the_vehicle_armed(mgr: FlightManager) -> None:
    for cmd in (c.Takeoff(), c.Land(), c.ReturnToLaunch(), c.StartMission()):
        assert mgr.execute(cmd, 0.0, ON_GROUND).result is c.Result.DENIED, cmd


@pytest.mark.parametrize(("alt", "ok"), [(None, True), (3.0, True), (0.2, False), (600.0, False),
                                         (float("nan"), False), (-485.0, False)])  # fmt: skip
def test_takeoff_altitude_range(mgr: FlightManager, alt: float | None, ok: bool) -> None:
    mgr.execute(c.FlyTrajectory(StraightLine(duration_s=1.0)), 0.0, ON_GROUND)
    assert mgr.execute(c.Arm(), 0.0, ON_GROUND).accepted
    assert mgr.execute(c.Takeoff(alt), 0.0, ON_GROUND).accepted is ok


def test_disarm_is_refused_in_the_air_unless_forced(mgr: FlightManager) -> None:
    mgr.execute(c.FlyTrajectory(StraightLine(duration_s=1.0)), 0.0, hovering())
    mgr.execute(c.Arm(), 0.0, hovering())
    assert mgr.execute(c.Disarm(), 1.0, hovering()).result is c.Result.DENIED
    assert mgr.landed_state(hovering()) is LandedState.IN_AIR
    assert mgr.execute(c.Disarm(force=True), 1.0, hovering()).accepted
    assert not mgr.armed


def test_offboard_needs_a_live_stream_and_falls_back_to_hold(mgr: FlightManager) -> None:
    x = hovering()
    assert mgr.execute(c.StartOffboard(), 0.0, x).result is c.Result.DENIED
    ref = np.full(9, np.nan)
    ref[0:3] = (1.0, 2.0, 3.0)
    assert mgr.execute(c.Setpoint(ref), 0.0, x).accepted
    velocity_only = np.full(9, np.nan)
    velocity_only[3:6] = 1.0
    assert mgr.execute(c.Setpoint(velocity_only), 0.0, x).result is c.Result.DENIED
    assert mgr.execute(c.StartOffboard(), 0.5, x).accepted
    assert mgr.execute(c.Arm(), 0.5, x).accepted and mgr.mode is Mode.GUIDED
    mgr.pre_tick(1.0, x)
    assert mgr.mode is Mode.GUIDED and np.array_equal(mgr.flight.guided_ref, ref, equal_nan=True)
    mgr.pre_tick(1.01, x)  # 1.01 s after the last setpoint: the failsafe holds
    assert mgr.mode is Mode.HOLD
    assert mgr.take_events() == [c.Text(c.Severity.WARNING, "Offboard setpoints lost: holding position")]
    assert mgr.take_events() == []  # taken once


def test_mission_progress_is_reported_as_events(mgr: FlightManager) -> None:
    mgr.set_mission_source(takeoff_mission)
    mgr.execute(c.Arm(), 0.0, ON_GROUND)
    assert mgr.execute(c.StartMission(), 0.0, ON_GROUND).accepted
    reached: list[int] = []
    t = 0.0
    while mgr.mission_state() is MissionState.ACTIVE and t < 120.0:
        t += 0.01
        mgr.post_tick(t, ON_GROUND)
        reached += [e.seq for e in mgr.take_events() if isinstance(e, c.ItemReached)]
    assert reached == [0, 1]
    assert mgr.mission_state() is MissionState.COMPLETE


def test_landing_ends_disarmed_with_a_message(mgr: FlightManager) -> None:
    x = hovering(0.5)
    mgr.execute(c.FlyTrajectory(StraightLine(duration_s=1.0)), 0.0, x)
    mgr.execute(c.Arm(), 0.0, x)
    assert mgr.execute(c.Land(), 0.0, x).accepted
    assert mgr.landed_state(x) is LandedState.LANDING
    assert mgr.flight.trajectory is not None
    end = mgr.flight.trajectory.duration_s
    mgr.post_tick(end + 0.01, ON_GROUND)
    assert not mgr.armed
    assert c.Text(c.Severity.INFO, "Landed: disarmed") in mgr.take_events()


def test_unknown_command_type_is_unsupported(mgr: FlightManager) -> None:
    assert mgr.execute(object(), 0.0, ON_GROUND).result is c.Result.UNSUPPORTED  # type: ignore[arg-type]
