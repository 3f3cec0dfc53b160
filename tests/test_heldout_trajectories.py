"""Held-out scenarios (figure_eight, aggressive_turn, position_step, hover_gust): their
trajectory kinds (continuity, exact derivatives, the shapes promised), the 1-cosine gust
world, the scenario files and their error windows, and each flight with the paper's TLC
on the paper's plant against the error measured when the scenarios were made."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from autopilot.flight_metrics import FlightMetrics
from autopilot.metrics import FlightRecord, window_rms_m
from autopilot.scenario import Run, Scenario
from autopilot.trajectory.analytic import StraightLine
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.factory import KINDS, trajectory_from_table
from autopilot.trajectory.manoeuvres import LEMNISCATE_LAP, ArcTurn, FigureEight, PositionStep
from autopilot.trajectory.waypoints import FlightLimits, build_waypoint_trajectory
from heli_common.config import ConfigError, build
from heli_common.frames import flip
from heli_common.geo import GeoPoint
from heli_common.state import PHI, THETA
from heli_common.wire.mavlink import mission_items as ms
from heli_common.world.config import World
from heli_common.world.gusts import gust_factor
from heli_sitl.engine.closed_loop import SimOptions, simulate

SCENARIOS = ("figure_eight", "aggressive_turn", "position_step", "hover_gust")
DT = 1e-3  # the dense grid the reference is checked on [s]


def dense(traj: Trajectory, dt: float = DT) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, traj.duration_s + 0.5 * dt, dt)
    return t, traj.sample(t)


def speed(rows: np.ndarray) -> np.ndarray:
    return np.asarray(np.linalg.norm(rows[:, 3:6], axis=1))


def heading(rows: np.ndarray) -> np.ndarray:
    return np.asarray(np.arctan2(rows[:, 4], rows[:, 3]))


def check_reference(traj: Trajectory, acc_steps_s: tuple[float, ...] = ()) -> None:
    """Finite, starts at rest, continuous in position and velocity (and acceleration away
    from ``acc_steps_s``); velocity and acceleration are the derivatives of position and
    velocity; ``evaluate_row`` is ``sample``'s row."""
    t, s = dense(traj)
    assert s.shape == (t.size, 9) and np.all(np.isfinite(s))
    assert np.all(s[0, 3:9] == 0.0)  # from hover: no velocity, no acceleration
    v_max = float(speed(s).max())
    a_max = float(np.linalg.norm(s[:, 6:9], axis=1).max())
    steps = np.abs(np.diff(s, axis=0))
    assert steps[:, 0:3].max() <= v_max * DT + 1e-9
    assert steps[:, 3:6].max() <= a_max * DT + 1e-9
    smooth = np.ones(t.size - 1, dtype=bool)
    for ts in acc_steps_s:  # the intervals that straddle an acceleration step
        smooth &= ~((t[:-1] <= ts + 1e-12) & (t[1:] >= ts - 1e-12))
    # the derivative between two samples is the mean of the two ends (error O(dt^2), and
    # O(dt) across a step of the derivative's derivative)
    vel_err = np.abs(np.diff(s[:, 0:3], axis=0) / DT - 0.5 * (s[1:, 3:6] + s[:-1, 3:6]))
    assert vel_err[smooth].max() < 1e-5 and vel_err.max() < a_max * DT / 4.0
    acc_err = np.abs(np.diff(s[:, 3:6], axis=0) / DT - 0.5 * (s[1:, 6:9] + s[:-1, 6:9]))
    assert acc_err[smooth].max() < 1e-5
    assert np.abs(np.diff(s[:, 6:9], axis=0))[smooth].max() < 0.01  # no step in acceleration
    for tk in np.linspace(0.0, traj.duration_s, 37):
        np.testing.assert_allclose(traj.evaluate_row(float(tk)), traj.sample(np.array([tk]))[0], atol=1e-12)


# ------------------------------------------------------------------------------ the kinds


def test_kinds_are_registered_and_built_from_toml_tables() -> None:
    assert KINDS["figure_eight"] is FigureEight
    assert KINDS["arc_turn"] is ArcTurn
    assert KINDS["position_step"] is PositionStep
    turn = trajectory_from_table({"kind": "arc_turn", "radius_m": 30.0, "turn_rad": -1.0}, "t.toml")
    assert turn == ArcTurn(radius_m=30.0, turn_rad=-1.0)
    with pytest.raises(ConfigError, match="radius_m"):
        trajectory_from_table({"kind": "arc_turn", "radius_m": 0.0}, "t.toml")
    with pytest.raises(ConfigError, match="turn_start_s"):  # the arc must be flown at full speed
        trajectory_from_table({"kind": "arc_turn", "ramp_s": 8.0, "turn_start_s": 5.0}, "t.toml")


def test_figure_eight_reference() -> None:
    traj = Scenario.load("figure_eight").trajectory
    assert isinstance(traj, FigureEight)
    check_reference(traj)
    t, s = dense(traj)
    a, v = traj.half_length_m, traj.speed_m_s
    # a lemniscate of Bernoulli about its centre, at a constant altitude
    x, y = s[:, 0] - traj.center_nwu_m[0], s[:, 1] - traj.center_nwu_m[1]
    assert np.abs((x * x + y * y) ** 2 - a * a * (x * x - y * y)).max() < 1e-9 * a**4
    assert np.all(s[:, 2] == traj.center_nwu_m[2]) and np.all(s[:, [5, 8]] == 0.0)
    assert x.max() == pytest.approx(a, abs=1e-3) and x.min() == pytest.approx(-a, abs=1e-3)
    assert np.abs(y).max() == pytest.approx(a / (2.0 * math.sqrt(2.0)), abs=1e-3)
    # 5 m/s path speed after the ramp, reached smoothly from hover
    assert v == 5.0
    cruise = t >= traj.ramp_s
    assert np.abs(speed(s[cruise]) - v).max() < 0.01 * v
    assert np.all(np.diff(speed(s[t <= traj.ramp_s])) >= -1e-12)
    # start at the crossing heading north-west, and fly more than two laps
    assert heading(s[1:2])[0] == pytest.approx(math.pi / 4.0)
    assert traj.lap_length_m == pytest.approx(5.244115 * a, rel=1e-6) == LEMNISCATE_LAP * a
    flown = 0.5 * v * traj.ramp_s + v * (traj.duration_s - traj.ramp_s)
    assert flown / traj.lap_length_m > 2.0
    # curvature 3 r / a^2: lateral acceleration up to 3 v^2 / a at the tips
    lateral = np.linalg.norm(s[cruise, 6:9], axis=1)
    assert lateral.max() == pytest.approx(3.0 * v * v / a, rel=1e-3)


def test_aggressive_turn_reference() -> None:
    traj = Scenario.load("aggressive_turn").trajectory
    assert isinstance(traj, ArcTurn)
    t0, t1 = traj.turn_start_s, traj.turn_end_s
    check_reference(traj, acc_steps_s=(t0, t1))
    t, s = dense(traj)
    v, r = traj.speed_m_s, traj.radius_m
    assert v == 8.0 and t1 - t0 == pytest.approx(r * math.pi / 2.0 / v)
    psi = np.unwrap(heading(s[1:]))
    before, arc, after = t[1:] < t0, (t[1:] > t0) & (t[1:] < t1), t[1:] > t1
    # straight north, a 90 deg turn to the left, straight west
    assert np.abs(psi[before]).max() < 1e-9
    assert np.degrees(psi[after] - psi[before][-1]) == pytest.approx(90.0, abs=1.0)
    assert np.abs(psi[after] - math.pi / 2.0).max() < 1e-9
    # 8 m/s from the end of the ramp on, in the arc too, with v^2 / R across the path
    assert np.abs(speed(s[t >= traj.ramp_s]) - v).max() < 1e-9
    rows = s[1:][arc]
    np.testing.assert_allclose(np.linalg.norm(rows[:, 6:9], axis=1), v * v / r, rtol=1e-9)
    np.testing.assert_allclose(np.sum(rows[:, 3:6] * rows[:, 6:9], axis=1), 0.0, atol=1e-9)
    # a circle: every arc point at R from the centre, left of the first line
    centre = traj.sample(np.array([t0]))[0, 0:2] + [0.0, r]
    np.testing.assert_allclose(np.hypot(rows[:, 0] - centre[0], rows[:, 1] - centre[1]), r, rtol=1e-9)
    # a level flight whose lateral acceleration stays below the 0.35 rad tilt limit's
    assert np.all(s[:, 2] == 20.0)
    assert v * v / r < 9.80665 * math.tan(0.35) and v * v / r < 0.6 * 9.80665


def test_position_step_reference_is_the_missions_waypoint_switch() -> None:
    traj = Scenario.load("position_step").trajectory
    assert isinstance(traj, PositionStep)
    check_reference(traj)
    t, s = dense(traj)
    start = np.array(traj.start_nwu_m)
    hover = t <= traj.step_time_s
    assert np.all(s[hover, 0:3] == start) and np.all(s[hover, 3:9] == 0.0)
    # ends 5 m north of the start, at rest, once the leg is flown
    np.testing.assert_allclose(s[-1, 0:3], start + [5.0, 0.0, 0.0], atol=1e-12)
    done = t >= traj.step_time_s + traj.step_duration_s
    assert np.all(s[done, 3:9] == 0.0) and np.abs(s[done, 0:3] - s[-1, 0:3]).max() < 1e-12
    assert np.all(s[:, 1:3] == start[1:3]) and np.all(np.diff(s[:, 0]) >= 0.0)
    # the same shaping a waypoint mission gives its switch to the next waypoint: hold at
    # the start until the step, then fly to the point 5 m north with the default limits
    lim = FlightLimits()
    assert (traj.speed_m_s, traj.max_acc_m_s2) == (lim.cruise_speed_m_s, lim.max_acc_m_s2)

    def wp(seq: int, nwu: np.ndarray, hold_s: float = 0.0) -> ms.MissionItem:
        n, e, d = flip((float(nwu[0]), float(nwu[1]), float(nwu[2])))
        return ms.MissionItem(seq, ms.FRAME_LOCAL_NED, ms.CMD_WAYPOINT, param1=hold_s,
                              x=round(n * 1e4), y=round(e * 1e4), z=d)  # fmt: skip

    mission = build_waypoint_trajectory(
        [wp(0, start, traj.step_time_s), wp(1, start + [5.0, 0.0, 0.0])], GeoPoint(47.0, 8.0, 400.0), start
    )
    assert mission.duration_s == pytest.approx(traj.step_time_s + traj.step_duration_s)
    np.testing.assert_allclose(mission.sample(t), s, atol=1e-12)
    assert traj.step_duration_s == pytest.approx(6.124, abs=1e-3)  # too short to cruise at 2 m/s


def test_hover_reference() -> None:
    traj = Scenario.load("hover_gust").trajectory
    assert isinstance(traj, StraightLine) and traj.duration_s == 60.0
    _, s = dense(traj)
    assert np.all(s[:, 0:3] == [0.0, 0.0, 20.0]) and np.all(s[:, 3:9] == 0.0)


# ------------------------------------------------------------------------- the gust world


def test_gust_world_is_one_full_one_cosine_from_the_side() -> None:
    g = World.load("gust-1cos").gust
    assert (g.amplitude_m_s, g.from_deg, g.hold_s) == (4.0, 90.0, 0.0)
    duration = g.rise_s + g.fall_s
    assert duration == 3.0 and g.rise_s == g.fall_s
    t = g.start_s + np.linspace(-1.0, duration + 1.0, 5001)
    k = np.array([gust_factor(float(x), g.start_s, g.rise_s, g.hold_s, g.fall_s) for x in t])
    tau = t - g.start_s
    inside = (tau >= 0.0) & (tau <= duration)
    one_cos = 0.5 * (1.0 - np.cos(2.0 * math.pi * tau / duration))
    np.testing.assert_allclose(k[inside], one_cos[inside], atol=1e-12)
    assert np.all(k[~inside] == 0.0)
    assert gust_factor(g.start_s, g.start_s, g.rise_s, g.hold_s, g.fall_s) == 0.0
    assert gust_factor(g.start_s + duration, g.start_s, g.rise_s, g.hold_s, g.fall_s) == pytest.approx(0.0)
    assert gust_factor(g.start_s + duration / 2.0, g.start_s, g.rise_s, g.hold_s, g.fall_s) == 1.0
    assert float(t[np.argmax(k)]) == pytest.approx(g.start_s + duration / 2.0, abs=1e-3)


# ------------------------------------------------------------- scenario files and windows


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_loads_and_starts_on_its_trajectory(name: str) -> None:
    sc = Scenario.load(name)
    run = sc.run
    assert run.name == name and sc.gains.name == "paper Table 2"
    assert (run.airframe, run.gains, run.rate_hz, run.feedforward, run.plant_substeps) == (
        "xcell60.toml", "gains_paper.toml", 100.0, "pseudo", 1
    )  # fmt: skip
    assert run.duration_s == sc.trajectory.duration_s
    start = sc.trajectory.sample(np.array([0.0]))[0]
    np.testing.assert_allclose(sc.initial.pos_nwu_m, start[0:3], atol=1e-12)
    assert start[2] == 20.0 and sc.initial.vel_flu_m_s == (0.0, 0.0, 0.0)
    windows = run.error_windows_s
    assert len(windows) >= 2 and all(0.0 <= a < b <= run.duration_s for a, b in windows)


def test_error_windows_are_optional_and_checked() -> None:
    assert Scenario.load("paper").run.error_windows_s == ()
    table = {"name": "x", "duration_s": 10.0}
    run = build(Run, {**table, "error_windows_s": [[0.0, 2.0], [2.0, 10.0]]}, "s.toml")
    assert run.error_windows_s == ((0.0, 2.0), (2.0, 10.0))
    with pytest.raises(ConfigError, match="t0 < t1"):
        build(Run, {**table, "error_windows_s": [[5.0, 5.0]]}, "s.toml")
    with pytest.raises(ConfigError, match="expected 2 values"):
        build(Run, {**table, "error_windows_s": [[0.0, 1.0, 2.0]]}, "s.toml")
    with pytest.raises(ConfigError, match="error_windows_s"):
        build(Run, {**table, "error_windows_s": [[-1.0, 1.0]]}, "s.toml")


def test_window_rms_is_the_summarys() -> None:
    t = np.arange(0.0, 10.001, 0.5)
    x = np.zeros((t.size, 12))
    x[:, 0] = np.sin(t)
    ref = np.zeros((t.size, 9))
    rec = FlightRecord(t, x, ref, np.zeros((t.size, 4)), np.zeros(t.size), np.zeros(t.size, bool), 1.0)
    m = (t >= 2.0) & (t <= 6.0)
    assert window_rms_m(rec, 2.0, 6.0) == pytest.approx(math.sqrt(np.mean(np.sin(t[m]) ** 2)), rel=1e-15)
    assert math.isnan(window_rms_m(rec, 20.0, 30.0))
    assert rec.summary()["rms_pos_err_m"]["0-10"] == window_rms_m(rec, 0.0, 10.0)
    assert rec.summary()["rms_pos_err_windows_m"] == {}  # the scenario named none
    # a scenario's own windows, as a process run's summary.json reports them
    named = dataclasses.replace(rec, extra={"error_windows_s": [[2.0, 6.0], [20.0, 30.0]]})
    summary = json.loads(json.dumps(named.summary()))
    by_window = FlightMetrics.from_summary(summary).rms_windows_m
    assert by_window["2-6"] == window_rms_m(rec, 2.0, 6.0) and math.isnan(by_window["20-30"])
    assert FlightMetrics.of(named).rms_windows_m["2-6"] == by_window["2-6"]


# ---------------------------------------------------------------- the flights, paper TLC

# RMS 3-D position error [m] per error window, measured with the paper's TLC (pseudo
# feedforward, 100 Hz) on the paper's plant when the scenarios were made (to the 4 digits
# here, docs/comparison/report.md's figure_eight 1.2162 m among them) and again on this code
# (the digits pinned: the flights are deterministic, no random input and no clock);
# hover_gust in configs/world/gust-1cos.toml. Every flight starts with the paper TLC's
# sideways drift (about 0.4 m at 3 s, while loop 2 learns the tail rotor's side force).
MEASURED_RMS_M = {
    "figure_eight": (0.8732911134, 1.2161874925),
    "aggressive_turn": (0.5651258822, 1.0514451074, 0.4426440566),
    "position_step": (0.2385338971, 0.2315648794, 0.02218429092),
    "hover_gust": (0.1817191673, 0.2427643088, 0.06232375848),
}


_flights: dict[str, tuple[Scenario, FlightRecord]] = {}


def fly(name: str) -> tuple[Scenario, FlightRecord]:
    if name not in _flights:
        sc = Scenario.load(name)
        world = World.load("gust-1cos") if name == "hover_gust" else None
        _flights[name] = sc, simulate(sc, SimOptions(world=world))
    return _flights[name]


def window_rms(name: str) -> list[float]:
    """The scenario's own windows, as the summary (summary.json, FlightMetrics) reports them."""
    sc, rec = fly(name)
    by_window = FlightMetrics.of(rec).rms_windows_m
    assert list(by_window) == [f"{a:g}-{b:g}" for a, b in sc.run.error_windows_s]
    assert rec.summary()["rms_pos_err_windows_m"] == by_window
    return [by_window[f"{a:g}-{b:g}"] for a, b in sc.run.error_windows_s]


@pytest.mark.parametrize("name", SCENARIOS)
def test_scenario_flies_with_the_paper_tlc(name: str) -> None:
    sc, rec = fly(name)
    assert rec.t_s[-1] == pytest.approx(sc.run.duration_s)
    assert np.all(np.isfinite(rec.x))
    tilt = np.arccos(np.cos(rec.x[:, PHI]) * np.cos(rec.x[:, THETA]))
    assert tilt.max() < 0.5  # never near a tumble (the turn's entry overshoots 0.35 rad)
    assert rec.pos_err_m.max() < 2.5
    for got, measured in zip(window_rms(name), MEASURED_RMS_M[name], strict=True):
        assert got == pytest.approx(measured, rel=1e-6)


def test_the_windows_see_each_scenarios_event() -> None:
    """Each event shows in its own window: the turn costs more than the straight line, the
    step's transient more than its steady state, the gust more than the calm hover."""
    turn, step, gust = window_rms("aggressive_turn"), window_rms("position_step"), window_rms("hover_gust")
    assert turn[1] > 1.5 * turn[0]
    assert step[1] > 5.0 * step[2]
    no_gust = dataclasses.replace(World.load("gust-1cos"), gust=World().gust)  # the same air, still
    calm = simulate(Scenario.load("hover_gust"), SimOptions(world=no_gust))
    assert gust[1] > 10.0 * window_rms_m(calm, 30.0, 45.0)
