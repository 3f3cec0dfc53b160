"""The flight state machine on its own: typed commands in, replies and events out, no link.

Every command path (MAVLink or a script) goes through these checks, so they are tested
here once, with an injected time and state, and over the wire in test_ground_client.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.flight import commands as c
from autopilot.flight.manager import FlightConfig, FlightManager, LandedState, MissionState
from autopilot.flight.modes import Mode
from autopilot.links.mavlink_modes import REPORTED
from autopilot.trajectory.analytic import StraightLine
from heli_common.geo import GeoPoint
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink import modes as wm
from heli_common.wire.mavlink.mission_items import MissionItem

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
    assert mgr.mode is Mode.TAKEOFF  # reported as TAKEOFF while it climbs, then it holds
    assert REPORTED[mgr.mode] is wm.TAKEOFF
    end = mgr.flight.trajectory.duration_s if mgr.flight.trajectory else math.nan
    mgr.flight.reference(end + 1.0, ON_GROUND)
    assert mgr.mode is Mode.HOLD


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


def test_a_landing_disarms_on_the_ground_even_if_the_estimated_velocity_runs_away(mgr: FlightManager) -> None:
    """Without a GPS the estimate's velocity can run away at touchdown: half a second with
    the estimated height on the ground ends the landing all the same (a vehicle waiting for
    the velocity to settle flew after its estimate: it took off again and flew 9 m)."""
    x = hovering(0.5)
    mgr.execute(c.Arm(), 0.0, x)
    assert mgr.execute(c.Land(), 0.0, x).accepted
    assert mgr.flight.trajectory is not None
    end = mgr.flight.trajectory.duration_s
    drifting = ON_GROUND.copy()
    drifting[3] = 1.5  # 1.5 m/s forward, dead-reckoned, on the ground
    t0 = end + 0.01
    for k in range(50):  # 0.49 s on the ground: still armed
        mgr.post_tick(t0 + 0.01 * k, drifting)
    assert mgr.armed
    mgr.post_tick(t0 + 0.51, drifting)
    assert not mgr.armed
    assert c.Text(c.Severity.INFO, "Landed: disarmed") in mgr.take_events()


def test_unknown_command_type_is_unsupported(mgr: FlightManager) -> None:
    assert mgr.execute(object(), 0.0, ON_GROUND).result is c.Result.UNSUPPORTED  # type: ignore[arg-type]


def _refs(mgr: FlightManager, t0: float, t1: float, x: np.ndarray, at: dict[float, c.Command]) -> np.ndarray:
    """The reference at every 10 ms tick of [t0, t1], executing ``at[t]`` commands first."""
    rows = []
    for k in range(round((t1 - t0) * 100) + 1):
        t = t0 + k * 0.01
        for when, cmd in at.items():
            if abs(t - when) < 1e-9:
                assert mgr.execute(cmd, t, x).accepted, cmd
        mgr.pre_tick(t, x)
        ref = mgr.flight.reference(t, x)
        assert ref is not None
        rows.append(ref)
        mgr.post_tick(t, x)
    return np.array(rows)


def _assert_continuous(refs: np.ndarray, max_acc: float = 1.0) -> None:
    """Position moves by at most its speed times a tick; velocity by at most max_acc a tick."""
    dp = np.linalg.norm(np.diff(refs[:, 0:3], axis=0), axis=1)
    speed = np.linalg.norm(refs[:-1, 3:6], axis=1) + np.linalg.norm(refs[1:, 3:6], axis=1)
    assert np.all(dp <= 0.5 * speed * 0.01 + 1e-3), dp.max()
    dv = np.linalg.norm(np.diff(refs[:, 3:6], axis=0), axis=1)
    assert np.all(dv <= max_acc * 0.01 + 1e-6), dv.max()


def test_the_end_of_a_moving_trajectory_brakes_to_a_hold(mgr: FlightManager) -> None:
    """The paper's spiral still moves at 0.785 m/s at its end: the reference brakes to rest
    instead of stopping dead (which kicked the vehicle by 0.25 rad of pitch)."""
    from autopilot.scenario import Scenario

    spiral = Scenario.load("paper").trajectory
    x = hovering(20.0)
    mgr.execute(c.FlyTrajectory(spiral), 0.0, x)
    mgr.execute(c.Arm(), 0.0, x)
    refs = _refs(mgr, 118.0, 124.0, x, {})
    _assert_continuous(refs)
    assert mgr.mode is Mode.HOLD and np.allclose(refs[-1, 3:9], 0.0)
    end = spiral.evaluate_row(spiral.duration_s)
    stop = np.linalg.norm(refs[-1, 0:3] - end[0:3])
    assert 0.5 < stop < 0.7  # v^2 / (2 a) = 0.785^2 / 1.0


def test_hold_and_land_mid_flight_start_where_the_reference_is(mgr: FlightManager) -> None:
    line = StraightLine(start_nwu_m=(0.0, 0.0, 5.0), vel_nwu_m_s=(1.0, 0.5, 0.0), duration_s=60.0)
    x = hovering(5.0)
    mgr.execute(c.FlyTrajectory(line), 0.0, x)
    mgr.execute(c.Arm(), 0.0, x)
    away = x.copy()
    away[0:3] = (30.0, -7.0, 4.0)  # the vehicle far off its reference: the switch still starts at it
    refs = _refs(mgr, 9.0, 20.0, away, {10.0: c.Hold(), 15.0: c.Land()})
    _assert_continuous(refs)
    held = refs[round(4.9 * 100)]  # 13.9 s: braked and holding at the line's stop point
    stop = (9.99 + 0.5 * 1.0 * 2.2361, 4.995 + 0.5 * 0.5 * 2.2361, 5.0)  # from the 9.99 s reference
    assert np.allclose(held[0:3], stop, atol=0.01)
    assert np.allclose(refs[-1, 0:2], held[0:2], atol=0.01) and refs[-1, 2] < 4.5  # landing there



def test_gps_loss_holds_then_lands_and_says_so(mgr: FlightManager) -> None:
    """Flying from sensors: GPS lost in flight -> hold on the estimate, land after the set
    time without a fix; rejected fixes and estimator resets are reported."""
    x = hovering(10.0)
    mgr.execute(c.FlyTrajectory(StraightLine((0.0, 0.0, 10.0), (1.0, 0.0, 0.0), 60.0)), 0.0, x)
    mgr.execute(c.Arm(), 0.0, x)
    assert mgr.mode is Mode.AUTO
    mgr.navigation(5.0, x, False, 1, 0)
    mgr.navigation(5.2, x, False, 1, 1)
    mgr.navigation(6.0, x, True, 1, 1)  # lost
    assert mgr.mode is Mode.HOLD
    mgr.navigation(15.9, x, True, 1, 1)
    assert mgr.mode is Mode.HOLD  # 9.9 s: still holding
    mgr.navigation(16.0, x, True, 1, 1)
    assert mgr.mode is Mode.LAND
    mgr.navigation(17.0, x, False, 1, 1)
    assert mgr.mode is Mode.LAND  # a fix back does not resume the flight: it keeps landing
    texts = [(e.severity, e.text) for e in mgr.take_events() if isinstance(e, c.Text)]
    assert texts == [
        (c.Severity.WARNING, "GPS fix rejected (1 so far)"),
        (c.Severity.WARNING, "GPS jump: position estimate reset"),
        (c.Severity.CRITICAL, "GPS lost: holding position"),
        (c.Severity.CRITICAL, "GPS lost 10 s: landing"),
        (c.Severity.INFO, "GPS back"),
    ]


def test_a_diverged_navigation_filter_lands_at_once_and_says_so_once(mgr: FlightManager) -> None:
    x = hovering(10.0)
    mgr.execute(c.FlyTrajectory(StraightLine((0.0, 0.0, 10.0), (1.0, 0.0, 0.0), 60.0)), 0.0, x)
    mgr.execute(c.Arm(), 0.0, x)
    mgr.navigation(5.0, x, False, 0, 0, diverged=False)
    assert mgr.mode is Mode.AUTO
    mgr.navigation(5.01, x, False, 0, 0, diverged=True)
    assert mgr.mode is Mode.LAND
    mgr.navigation(5.02, x, False, 0, 0, diverged=True)
    texts = [(e.severity, e.text) for e in mgr.take_events() if isinstance(e, c.Text)]
    assert texts == [(c.Severity.CRITICAL, "Navigation filter diverged: landing")]


def test_gps_loss_on_the_ground_is_only_reported(mgr: FlightManager) -> None:
    mgr.navigation(1.0, ON_GROUND, True, 0, 0)
    assert not mgr.armed and mgr.mode is not Mode.LAND
    assert [e.text for e in mgr.take_events() if isinstance(e, c.Text)] == ["GPS lost"]
