"""Waypoint missions -> smooth trajectories; the sampled (spline) trajectory; geo about home."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.sampled import SampledTrajectory
from autopilot.trajectory.waypoints import (
    FlightLimits,
    MissionBuildError,
    WaypointTrajectory,
    build_waypoint_trajectory,
)
from heli_common.frames import flip
from heli_common.geo import (
    GeoPoint,
    geo_to_ned_m,
    geo_to_nwu_m,
    horizontal_distance_m,
    ned_to_geo,
    nwu_to_geo,
)
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem

HOME = GeoPoint(47.397742, 8.545594, 488.0)
LIM = FlightLimits()


def local(seq: int, cmd: int, nwu: tuple[float, float, float], p1: float = 0.0) -> MissionItem:
    n, e, d = flip(nwu)
    return MissionItem(seq, ms.FRAME_LOCAL_NED, cmd, param1=p1, x=round(n * 1e4), y=round(e * 1e4), z=d)


def takeoff(seq: int, up_m: float) -> MissionItem:
    return MissionItem(seq, ms.FRAME_GLOBAL_REL_INT, ms.CMD_TAKEOFF, z=up_m)


def speed(seq: int, kind: int, value: float) -> MissionItem:
    return MissionItem(seq, ms.FRAME_MISSION, ms.CMD_CHANGE_SPEED, param1=kind, param2=value)


def grid(traj: Trajectory, dt: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, traj.duration_s + dt, dt)
    return t, traj.sample(t)


def assert_smooth_and_within_limits(traj: Trajectory, lim: FlightLimits = LIM) -> None:
    t, s = grid(traj)
    assert np.all(np.isfinite(s))
    dt = t[1] - t[0]
    # continuity: no step in position, velocity or acceleration between grid points
    steps = np.abs(np.diff(s, axis=0))
    assert steps[:, 0:3].max() <= (lim.max_speed_m_s + 1e-9) * dt
    assert steps[:, 3:6].max() <= lim.max_acc_m_s2 * dt * 1.01
    assert steps[:, 6:9].max() < 0.05  # jerk-bounded: acceleration moves little per 10 ms
    # exactness: vel and acc are the derivatives of pos and vel
    mid_vel = (s[1:, 0:3] - s[:-1, 0:3]) / dt
    assert np.abs(mid_vel - 0.5 * (s[1:, 3:6] + s[:-1, 3:6])).max() < 1e-4
    mid_acc = (s[1:, 3:6] - s[:-1, 3:6]) / dt
    assert np.abs(mid_acc - 0.5 * (s[1:, 6:9] + s[:-1, 6:9])).max() < 1e-3
    # limits
    assert np.linalg.norm(s[:, 6:9], axis=1).max() <= lim.max_acc_m_s2 + 1e-9
    assert np.linalg.norm(s[:, 3:6], axis=1).max() <= lim.max_speed_m_s + 1e-9


# ------------------------------------------------------------------ waypoint trajectories


def test_takeoff_waypoints_land_pass_through_points_and_stop() -> None:
    items = [
        takeoff(0, 10.0),
        local(1, ms.CMD_WAYPOINT, (20.0, 0.0, 10.0), p1=3.0),
        local(2, ms.CMD_WAYPOINT, (20.0, 15.0, 14.0)),
        MissionItem(3, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, z=math.nan),
    ]
    traj = build_waypoint_trajectory(items, HOME, (0.0, 0.0, 0.0))
    assert isinstance(traj, WaypointTrajectory)
    assert [seq for seq, _ in traj.reached] == [0, 1, 2, 3]
    expected = [(0, 0, 10), (20, 0, 10), (20, 15, 14), (20, 15, 0)]
    for (seq, t), p in zip(traj.reached, expected, strict=True):
        row = traj.evaluate(t)
        assert row.pos_nwu_m == pytest.approx(p, abs=1e-9), seq
        assert row.vel_nwu_m_s == pytest.approx((0, 0, 0), abs=1e-12)
        assert row.acc_nwu_m_s2 == pytest.approx((0, 0, 0), abs=1e-12)
    # hold 3 s at waypoint 1, still the active item
    t1 = traj.reached_time_s(1)
    assert t1 is not None
    assert traj.evaluate(t1 + 2.9).pos_nwu_m == pytest.approx((20, 0, 10))
    assert traj.active_seq(t1 + 2.9) == 1 and traj.active_seq(t1 + 3.01) == 2
    assert traj.duration_s == pytest.approx(traj.reached[-1][1])
    assert traj.finished(traj.duration_s) and not traj.finished(0.5 * traj.duration_s)
    assert_smooth_and_within_limits(traj)


def test_speed_limits_cruise_climb_and_landing() -> None:
    items = [
        takeoff(0, 30.0),
        local(1, ms.CMD_WAYPOINT, (100.0, 0.0, 30.0)),
        MissionItem(2, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, z=math.nan),
    ]
    lim = FlightLimits(cruise_speed_m_s=2.0, climb_speed_m_s=0.8, descent_speed_m_s=1.0, land_speed_m_s=0.4)
    traj = build_waypoint_trajectory(items, HOME, (0.0, 0.0, 0.0), lim)
    _, s = grid(traj)
    horiz = np.hypot(s[:, 3], s[:, 4])
    assert horiz.max() == pytest.approx(2.0, abs=1e-9)  # long leg reaches cruise
    assert s[:, 5].max() == pytest.approx(0.8, abs=1e-9)  # climb limit
    assert s[:, 5].min() == pytest.approx(-0.4, abs=1e-9)  # landing speed
    assert np.linalg.norm(s[:, 6:9], axis=1).max() == pytest.approx(1.0, abs=1e-3)
    assert_smooth_and_within_limits(traj, lim)


def test_short_leg_never_reaches_cruise_but_respects_acceleration() -> None:
    traj = build_waypoint_trajectory([local(0, ms.CMD_WAYPOINT, (1.0, 0.0, 0.0))], HOME, (0.0, 0.0, 0.0))
    _, s = grid(traj, 0.001)
    vmax = math.sqrt(LIM.max_acc_m_s2 * 1.0 / 1.875)
    assert s[:, 3].max() == pytest.approx(vmax, rel=1e-6)
    assert np.abs(s[:, 6]).max() == pytest.approx(1.0, rel=1e-3)
    assert traj.duration_s == pytest.approx(2 * 1.875 * vmax)


def test_diagonal_climb_respects_vertical_limit() -> None:
    traj = build_waypoint_trajectory([local(0, ms.CMD_WAYPOINT, (10.0, 0.0, 20.0))], HOME, (0.0, 0.0, 0.0))
    _, s = grid(traj)
    assert s[:, 5].max() == pytest.approx(LIM.climb_speed_m_s, abs=1e-9)
    assert np.linalg.norm(s[:, 3:6], axis=1).max() < LIM.cruise_speed_m_s


def test_change_speed_applies_to_following_legs_and_default_restores() -> None:
    items = [
        local(0, ms.CMD_WAYPOINT, (50.0, 0.0, 5.0)),
        speed(1, ms.SPEED_TYPE_GROUNDSPEED, 4.0),
        local(2, ms.CMD_WAYPOINT, (100.0, 0.0, 5.0)),
        speed(3, ms.SPEED_TYPE_GROUNDSPEED, ms.SPEED_DEFAULT),
        local(4, ms.CMD_WAYPOINT, (150.0, 0.0, 5.0)),
    ]
    traj = build_waypoint_trajectory(items, HOME, (0.0, 0.0, 5.0))
    t, s = grid(traj)
    r = dict(traj.reached)
    assert r[1] == r[0] and r[3] == r[2]  # DO items are reached when passed

    def peak(a: float, b: float) -> float:
        sel = (t > a) & (t < b)
        return float(s[sel, 3].max())

    assert peak(0, r[0]) == pytest.approx(2.0)
    assert peak(r[0], r[2]) == pytest.approx(4.0)
    assert peak(r[2], r[4]) == pytest.approx(2.0)


def test_change_speed_climb_and_descent() -> None:
    items = [
        speed(0, ms.SPEED_TYPE_CLIMB, 0.5),
        local(1, ms.CMD_WAYPOINT, (0.0, 0.0, 20.0)),
        speed(2, ms.SPEED_TYPE_DESCENT, 0.3),
        local(3, ms.CMD_WAYPOINT, (0.0, 0.0, 10.0)),
    ]
    _, s = grid(build_waypoint_trajectory(items, HOME, (0.0, 0.0, 0.0)))
    assert s[:, 5].max() == pytest.approx(0.5) and s[:, 5].min() == pytest.approx(-0.3)


def test_change_speed_is_capped() -> None:
    lim = FlightLimits(max_speed_m_s=3.0)
    items = [speed(0, 1, 15.0), local(1, ms.CMD_WAYPOINT, (200.0, 0.0, 0.0))]
    _, s = grid(build_waypoint_trajectory(items, HOME, (0.0, 0.0, 0.0), lim))
    assert s[:, 3].max() == pytest.approx(3.0)


def test_rtl_lands_at_home_and_ends_mission() -> None:
    items = [
        takeoff(0, 10.0),
        local(1, ms.CMD_WAYPOINT, (30.0, -20.0, 12.0)),
        MissionItem(2, ms.FRAME_MISSION, ms.CMD_RTL),
        local(3, ms.CMD_WAYPOINT, (99.0, 99.0, 9.0)),
    ]
    traj = build_waypoint_trajectory(items, HOME, (0.0, 0.0, 0.0))
    assert traj.end_nwu_m == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert traj.reached_time_s(3) is None
    assert traj.active_seq(traj.duration_s + 5) == 2
    assert_smooth_and_within_limits(traj)


def test_takeoff_climbs_vertically_from_current_position() -> None:
    traj = build_waypoint_trajectory([takeoff(0, 8.0)], HOME, (4.0, -3.0, 0.5))
    _, s = grid(traj)
    assert np.ptp(s[:, 0]) == 0.0 and np.ptp(s[:, 1]) == 0.0
    assert traj.end_nwu_m == pytest.approx((4.0, -3.0, 8.0))


def test_loiter_time_here_holds() -> None:
    loiter = MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LOITER_TIME, param1=7.0, z=6.0)
    traj = build_waypoint_trajectory([loiter], HOME, (2.0, 2.0, 6.0))
    assert traj.duration_s == pytest.approx(7.0)
    assert traj.evaluate(3.0).pos_nwu_m == pytest.approx((2.0, 2.0, 6.0))


def test_global_frames_convert_through_home() -> None:
    g = nwu_to_geo(HOME, (25.0, 10.0, 0.0))
    lat, lon = round(g.lat_deg * 1e7), round(g.lon_deg * 1e7)
    amsl = MissionItem(0, ms.FRAME_GLOBAL_INT, ms.CMD_WAYPOINT, x=lat, y=lon, z=HOME.alt_amsl_m + 7)
    traj = build_waypoint_trajectory([amsl], HOME, (0.0, 0.0, 7.0))
    assert traj.end_nwu_m == pytest.approx((25.0, 10.0, 7.0), abs=0.01)


def test_start_seq_resumes_with_earlier_speed_change() -> None:
    items = [
        speed(0, 1, 3.0),
        local(1, ms.CMD_WAYPOINT, (10.0, 0.0, 5.0)),
        local(2, ms.CMD_WAYPOINT, (60.0, 0.0, 5.0)),
    ]
    traj = build_waypoint_trajectory(items, HOME, (10.0, 0.0, 5.0), start_seq=2)
    _, s = grid(traj)
    assert s[:, 0].max() == pytest.approx(60.0) and s[:, 3].max() == pytest.approx(3.0)
    assert [seq for seq, _ in traj.reached] == [2]


def test_empty_mission_holds_start() -> None:
    traj = build_waypoint_trajectory([], HOME, (1.0, 2.0, 3.0))
    assert traj.duration_s == 0.0 and traj.active_seq(0.0) is None
    assert traj.evaluate(5.0).pos_nwu_m == pytest.approx((1.0, 2.0, 3.0))


def test_trajectory_items_are_refused() -> None:
    sample = MissionItem(0, ms.FRAME_LOCAL_NED, ms.CMD_TRAJ_SAMPLE, param1=0.0)
    with pytest.raises(MissionBuildError) as exc:
        build_waypoint_trajectory([sample], HOME, (0.0, 0.0, 0.0))
    assert exc.value.result == ms.UNSUPPORTED and exc.value.seq == 0


def test_global_item_without_home_is_refused() -> None:
    wp = MissionItem(0, ms.FRAME_GLOBAL_REL_INT, ms.CMD_WAYPOINT, x=473977420, y=85455940, z=5)
    with pytest.raises(MissionBuildError):
        build_waypoint_trajectory([wp], None, (0.0, 0.0, 0.0))


point = st.tuples(st.floats(-200, 200), st.floats(-200, 200), st.floats(0, 60))


@given(
    start=point,
    points=st.lists(st.tuples(point, st.floats(0, 5)), min_size=1, max_size=6),
    cruise=st.floats(0.3, 8.0),
    acc=st.floats(0.2, 3.0),
)
@settings(max_examples=30, deadline=None)
def test_random_missions_pass_through_points_within_limits(
    start: tuple[float, float, float],
    points: list[tuple[tuple[float, float, float], float]],
    cruise: float,
    acc: float,
) -> None:
    lim = FlightLimits(cruise_speed_m_s=cruise, max_acc_m_s2=acc, max_speed_m_s=8.0)
    items = [local(i, ms.CMD_WAYPOINT, p, p1=hold) for i, (p, hold) in enumerate(points)]
    traj = build_waypoint_trajectory(items, HOME, start, lim)
    for seq, t_reached in traj.reached:
        it = items[seq]
        p = np.array(flip((it.local_north_m, it.local_east_m, it.z)))
        assert np.abs(traj.evaluate(t_reached).pos_nwu_m - p).max() < 1e-3  # 0.1 mm wire quantum
    _, s = grid(traj, 0.02)
    assert np.linalg.norm(s[:, 6:9], axis=1).max() <= acc * (1 + 1e-9)
    assert np.linalg.norm(s[:, 3:6], axis=1).max() <= cruise * (1 + 1e-9)
    assert s[:, 5].max() <= lim.climb_speed_m_s + 1e-9
    assert s[:, 5].min() >= -lim.descent_speed_m_s - 1e-9


# ------------------------------------------------------------------ sampled trajectory


def test_sampled_passes_through_samples_and_is_c2() -> None:
    t = np.linspace(0.0, 10.0, 21)
    pos = np.column_stack([np.sin(t), np.cos(0.5 * t), 0.1 * t**2])
    traj = SampledTrajectory(t, pos)
    assert traj.sample(t)[:, 0:3] == pytest.approx(pos, abs=1e-12)
    eps = 1e-7
    knots = t[1:-1]
    left, right = traj.sample(knots - eps), traj.sample(knots + eps)
    assert np.abs(left - right)[:, 0:9].max() < 1e-5
    assert traj.sample([5.0])[0, 8] == pytest.approx(0.2, abs=1e-9)  # z'' of 0.1 t^2 exact


def test_sampled_outside_span_holds_with_zero_derivatives() -> None:
    traj = SampledTrajectory([1.0, 2.0, 3.0], [[0, 0, 0], [1, 1, 1], [2, 2, 2]])
    before, after = traj.sample([0.0, 5.0])
    assert before == pytest.approx([0, 0, 0, 0, 0, 0, 0, 0, 0])
    assert after == pytest.approx([2, 2, 2, 0, 0, 0, 0, 0, 0])
    assert traj.duration_s == 3.0


def test_sampled_break_keeps_corner_sharp_on_that_axis_only() -> None:
    t = np.arange(0.0, 20.5, 0.5)
    z = 0.5 * np.minimum(t, 10.0)
    x = np.sin(0.3 * t)
    pos = np.column_stack([x, np.zeros_like(t), z])
    mask = np.where(t == 10.0, 4, 0)
    traj = SampledTrajectory(t, pos, break_mask=mask)
    fine = np.arange(0.0, 20.0, 0.01)
    s = traj.sample(fine)
    assert np.abs(s[:, 2] - 0.5 * np.minimum(fine, 10.0)).max() < 1e-12  # z is piecewise linear
    # left-continuous at the break, as PaperSpiralCircle (t <= climb end is climbing)
    assert traj.sample([10.0])[0, 5] == pytest.approx(0.5) and traj.sample([10.001])[0, 5] == 0.0
    assert np.abs(s[:, 0] - np.sin(0.3 * fine)).max() < 1e-4  # x untouched by the z break
    ringing = SampledTrajectory(t, pos).sample(fine)
    assert np.abs(ringing[:, 2] - 0.5 * np.minimum(fine, 10.0)).max() > 1e-3


def test_sampled_yaw_is_interpolated_across_wrap() -> None:
    traj = SampledTrajectory([0.0, 1.0], [[0, 0, 0], [1, 0, 0]], yaw_nwu_rad=[3.0, -3.0])
    mid = traj.yaw_nwu_rad([0.5])[0]
    assert abs(abs(mid) - math.pi) < 1e-9  # went the short way, through +-pi
    assert np.isnan(SampledTrajectory([0.0, 1.0], np.zeros((2, 3))).yaw_nwu_rad([0.5])[0])


@pytest.mark.parametrize(
    ("t", "pos", "mask"),
    [
        ([0.0], [[0, 0, 0]], None),
        ([0.0, 1.0], [[0, 0, 0]], None),
        ([0.0, 0.0], [[0, 0, 0], [1, 1, 1]], None),
        ([0.0, 1.0], [[0, 0, 0], [math.nan, 1, 1]], None),
        ([-1.0, 1.0], [[0, 0, 0], [1, 1, 1]], None),
        ([0.0, 1.0], [[0, 0, 0], [1, 1, 1]], [0, 9]),
    ],
)
def test_sampled_rejects_bad_input(t: list[float], pos: list[list[float]], mask: list[int] | None) -> None:
    with pytest.raises(ValueError):
        SampledTrajectory(t, pos, break_mask=mask)


# ------------------------------------------------------------------ geo


lat = st.floats(-85.0, 85.0)
lon = st.floats(-180.0, 180.0)


@given(
    lat0=lat,
    lon0=lon,
    alt0=st.floats(-400, 8000),
    n=st.floats(-5000, 5000),
    e=st.floats(-5000, 5000),
    d=st.floats(-3000, 300),
)
@settings(max_examples=200, deadline=None)
def test_geo_round_trip(lat0: float, lon0: float, alt0: float, n: float, e: float, d: float) -> None:
    home = GeoPoint(lat0, lon0, alt0)
    g = ned_to_geo(home, (n, e, d))
    assert geo_to_ned_m(home, g.lat_deg, g.lon_deg, g.alt_amsl_m) == pytest.approx((n, e, d), abs=1e-6)
    nwu = flip((n, e, d))
    g2 = nwu_to_geo(home, nwu)
    assert geo_to_nwu_m(home, g2.lat_deg, g2.lon_deg, g2.alt_amsl_m) == pytest.approx(nwu, abs=1e-6)


def test_geo_scale_matches_wgs84() -> None:
    # 0.001 deg of latitude at 47.4 deg is 111.2 m; of longitude 75.4 m (WGS-84)
    n, e, d = geo_to_ned_m(HOME, HOME.lat_deg + 0.001, HOME.lon_deg + 0.001, HOME.alt_amsl_m - 3.0)
    assert n == pytest.approx(111.2, abs=0.1)
    assert e == pytest.approx(75.4, abs=0.1)
    assert d == 3.0
    assert horizontal_distance_m(HOME, HOME.lat_deg + 0.001, HOME.lon_deg) == pytest.approx(n)


def test_geo_across_antimeridian() -> None:
    home = GeoPoint(0.0, 179.9999, 0.0)
    _, e, _ = geo_to_ned_m(home, 0.0, -179.9999, 0.0)
    assert e == pytest.approx(22.26, abs=0.01)
    assert ned_to_geo(home, (0.0, e, 0.0)).lon_deg == pytest.approx(-179.9999)


def test_geo_refuses_bad_points_and_polar_home() -> None:
    with pytest.raises(ValueError):
        GeoPoint(91.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        GeoPoint(0.0, math.nan, 0.0)
    with pytest.raises(ValueError):
        geo_to_ned_m(GeoPoint(89.5, 0.0, 0.0), 89.5, 0.0, 0.0)
