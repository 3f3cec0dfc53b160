"""A waypoint mission -> a smooth, time-parameterised trajectory (NWU) for the TLC.

Design (chosen for exactness and predictability over speed):

* The path is the polyline through the mission's points, flown leg by leg; the vehicle
  stops (zero velocity and acceleration) at every point. So the path is exactly the
  straight lines a GCS draws, corners need no blending, and "reached" is unambiguous.
* Each leg is a rest-to-rest profile along its straight line: a velocity ramp shaped as
  the quintic "smootherstep" v = V (10u^3 - 15u^4 + 6u^5), u = tau / T_ramp, a cruise at
  V, and the mirrored ramp down. Acceleration is continuous (and so is jerk), peak
  |a| = 1.875 V / T_ramp, so T_ramp = 1.875 V / a_max meets the acceleration limit
  exactly; a leg too short to reach V uses the largest V that fits (no cruise). Position,
  velocity and acceleration are closed-form: exact feedforward, never NaN.
* V = min(cruise speed, climb (or descent) speed / |vertical share of the direction|), so
  both the 3-D speed and the vertical speed limits hold on every leg.
* Items: NAV_TAKEOFF climbs vertically to its altitude (then flies to its lat/lon if one
  is given); NAV_WAYPOINT flies to the point then holds param1 s; NAV_LOITER_TIME flies
  to the point (0/0 = here) then holds param1 s; NAV_LAND flies level to above the point
  (0/0 = here) then descends at the landing speed to its altitude (NaN = home ground
  level, flat terrain); NAV_RETURN_TO_LAUNCH flies level to above home then lands there
  and ENDS the mission (later items are never reached, as in PX4); DO_CHANGE_SPEED
  (ground/air speed, climb or descent; -1 = no change, -2 = default) applies from the
  next leg on and is "reached" when passed.
* "Reached" times: a positional item is reached when the vehicle arrives (before any
  hold), as PX4 reports MISSION_ITEM_REACHED; it stays the active item until its hold
  ends. Timed-trajectory items (autopilot.trajectory_codec) are refused here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from autopilot.trajectory.base import Trajectory
from heli_common.frames import flip
from heli_common.geo import GeoPoint
from heli_common.state import FloatArray
from heli_common.wire.mavlink import mission_items as ms

# smootherstep ramp: peak acceleration = RAMP_ACC_FACTOR * V / T_ramp
RAMP_ACC_FACTOR = 1.875


@dataclass(frozen=True)
class FlightLimits:
    """Speeds and acceleration a waypoint trajectory respects."""

    cruise_speed_m_s: float = 2.0
    max_acc_m_s2: float = 1.0
    climb_speed_m_s: float = 1.0
    descent_speed_m_s: float = 1.0
    land_speed_m_s: float = 0.5
    max_speed_m_s: float = 10.0  # cap on DO_CHANGE_SPEED requests

    def __post_init__(self) -> None:
        for name in (
            "cruise_speed_m_s",
            "max_acc_m_s2",
            "climb_speed_m_s",
            "descent_speed_m_s",
            "land_speed_m_s",
            "max_speed_m_s",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")


class MissionBuildError(ValueError):
    """The mission cannot be flown: ``seq`` is the item, ``result`` a MAV_MISSION_RESULT."""

    def __init__(self, seq: int, result: int, text: str) -> None:
        super().__init__(f"item {seq}: {text}")
        self.seq = seq
        self.result = result


@dataclass(frozen=True)
class _Leg:
    """A rest-to-rest straight leg (or a hold, with zero length) starting at ``t0_s``."""

    t0_s: float
    duration_s: float
    start_nwu_m: tuple[float, float, float]
    dir_nwu: tuple[float, float, float]  # unit vector (zeros for a hold)
    length_m: float
    speed_m_s: float
    ramp_s: float
    seq: int


def leg_profile(length_m: float, speed_cap_m_s: float, max_acc_m_s2: float) -> tuple[float, float, float]:
    """(V, T_ramp, duration) of the rest-to-rest profile over ``length_m`` (the shaping of a
    switch between two waypoints; :func:`rest_to_rest` samples it)."""
    if length_m <= 0.0:
        return 0.0, 0.0, 0.0
    v = speed_cap_m_s
    ramp = RAMP_ACC_FACTOR * v / max_acc_m_s2
    if length_m < v * ramp:  # the two ramps alone cover v * ramp: no room to cruise
        v = math.sqrt(max_acc_m_s2 * length_m / RAMP_ACC_FACTOR)
        ramp = RAMP_ACC_FACTOR * v / max_acc_m_s2
    return v, ramp, 2.0 * ramp + (length_m - v * ramp) / v


Profile = tuple[FloatArray, FloatArray, FloatArray]  # distance [m], speed [m/s], acceleration [m/s^2]
Number = FloatArray | float


def smootherstep(w: FloatArray, v: Number, ramp_s: Number) -> Profile:
    """The quintic ramp from rest to ``v`` over ``ramp_s`` at ``w = tau / ramp_s`` in [0, 1]:
    distance s = V T w^4 (5/2 - 3 w + w^2), speed V (10 w^3 - 15 w^4 + 6 w^5), acceleration
    (V / T) 30 w^2 (1 - w)^2 (zero at both ends, peak ``RAMP_ACC_FACTOR V / T`` at w = 1/2)."""
    s = v * ramp_s * w**4 * (2.5 - 3.0 * w + w * w)
    vel = v * w**3 * (10.0 - 15.0 * w + 6.0 * w * w)
    acc = v / ramp_s * 30.0 * w * w * (1.0 - w) ** 2
    return s, vel, acc


def rest_to_rest(
    tau_s: FloatArray, duration_s: Number, ramp_s: Number, v_m_s: Number, length_m: Number
) -> Profile:
    """Distance along a leg [m], speed [m/s] and acceleration [m/s^2] at ``tau_s`` from its
    start (clipped to the leg): the :func:`smootherstep` ramp up on [0, T_ramp], a cruise at
    V, the mirror image on [duration - T_ramp, duration]; all zero for a hold (T_ramp = 0).
    The profile of :func:`leg_profile`; arrays broadcast together."""
    dur, ramp, v, length = duration_s, ramp_s, v_m_s, length_m
    tau = np.clip(tau_s, 0.0, dur)
    moving = ramp > 0.0
    safe_ramp = np.where(moving, ramp, 1.0)
    up = tau < ramp
    down = tau > dur - ramp
    w = np.where(up, tau, np.where(down, dur - tau, ramp)) / safe_ramp
    w = np.clip(w, 0.0, 1.0)
    s_ramp, v_ramp, a_ramp = smootherstep(w, v, safe_ramp)
    s = np.where(up, s_ramp, np.where(down, length - s_ramp, 0.5 * v * ramp + v * (tau - ramp)))
    vel = np.where(up | down, v_ramp, v)
    acc = np.where(up, a_ramp, np.where(down, -a_ramp, 0.0))
    s, vel, acc = (np.where(moving, q, 0.0) for q in (s, vel, acc))
    return s, vel, acc


class WaypointTrajectory(Trajectory):
    """The flown mission: legs and holds, with the items' reached times and active seqs."""

    def __init__(
        self,
        legs: Sequence[_Leg],
        reached: Sequence[tuple[int, float]],
        start_nwu_m: tuple[float, float, float],
    ) -> None:
        self._legs = tuple(legs)
        self.reached = tuple(reached)  # (seq, t_s) in time order
        self._start = np.asarray(start_nwu_m, dtype=float)
        self.duration_s = self._legs[-1].t0_s + self._legs[-1].duration_s if self._legs else 0.0
        n = len(self._legs)
        self._t0 = np.array([lg.t0_s for lg in self._legs]) if n else np.zeros(0)
        self._dur = np.array([lg.duration_s for lg in self._legs])
        self._p0 = np.array([lg.start_nwu_m for lg in self._legs]).reshape(n, 3)
        self._dir = np.array([lg.dir_nwu for lg in self._legs]).reshape(n, 3)
        self._len = np.array([lg.length_m for lg in self._legs])
        self._v = np.array([lg.speed_m_s for lg in self._legs])
        self._ramp = np.array([lg.ramp_s for lg in self._legs])
        self._seq = np.array([lg.seq for lg in self._legs], dtype=np.int64)

    @property
    def end_nwu_m(self) -> FloatArray:
        return self.sample(np.array([self.duration_s]))[0, 0:3]

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        out = np.zeros((t.size, 9))
        if not self._legs:
            out[:, 0:3] = self._start
            return out
        k = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self._legs) - 1)
        s, vel, acc = rest_to_rest(t - self._t0[k], self._dur[k], self._ramp[k], self._v[k], self._len[k])
        d = self._dir[k]
        out[:, 0:3] = self._p0[k] + s[:, None] * d
        out[:, 3:6] = vel[:, None] * d
        out[:, 6:9] = acc[:, None] * d
        return out

    def active_seq(self, t_s: float) -> int | None:
        """The mission item being executed at ``t_s`` (for MISSION_CURRENT); None if none."""
        if not self._legs:
            return self.reached[-1][0] if self.reached else None
        k = int(np.clip(np.searchsorted(self._t0, t_s, side="right") - 1, 0, len(self._legs) - 1))
        return int(self._seq[k])

    def reached_between(self, t_prev_s: float, t_now_s: float) -> list[int]:
        """Items reached in (t_prev_s, t_now_s] (for MISSION_ITEM_REACHED), in order."""
        return [seq for seq, t in self.reached if t_prev_s < t <= t_now_s]

    def reached_time_s(self, seq: int) -> float | None:
        """When item ``seq`` is reached, or None if it never is (e.g. after an RTL)."""
        for s, t in self.reached:
            if s == seq:
                return t
        return None

    def finished(self, t_s: float) -> bool:
        return t_s >= self.duration_s


class _Builder:
    def __init__(self, start_nwu_m: Sequence[float], limits: FlightLimits) -> None:
        self.pos = np.asarray(start_nwu_m, dtype=float).reshape(3)
        if not np.all(np.isfinite(self.pos)):
            raise ValueError("start position must be finite")
        self.t = 0.0
        self.limits = limits
        self.defaults = limits
        self.legs: list[_Leg] = []
        self.reached: list[tuple[int, float]] = []

    def move(self, target_nwu_m: FloatArray, seq: int, speed_cap_m_s: float | None = None) -> None:
        delta = target_nwu_m - self.pos
        length = float(np.linalg.norm(delta))
        if length < 1e-9:
            return
        u = delta / length
        lim = self.limits
        cap = lim.cruise_speed_m_s if speed_cap_m_s is None else speed_cap_m_s
        vertical = abs(float(u[2]))
        if vertical > 0.0:
            vz = lim.climb_speed_m_s if u[2] > 0.0 else lim.descent_speed_m_s
            cap = min(cap, vz / vertical)
        v, ramp, dur = leg_profile(length, cap, lim.max_acc_m_s2)
        self.legs.append(_Leg(self.t, dur, _vec(self.pos), _vec(u), length, v, ramp, seq))
        self.t += dur
        self.pos = target_nwu_m.copy()

    def hold(self, duration_s: float, seq: int) -> None:
        if duration_s <= 0.0:
            return
        self.legs.append(_Leg(self.t, duration_s, _vec(self.pos), (0.0, 0.0, 0.0), 0.0, 0.0, 0.0, seq))
        self.t += duration_s

    def reach(self, seq: int) -> None:
        self.reached.append((seq, self.t))

    def change_speed(self, item: ms.MissionItem) -> None:
        kind, speed = int(item.param1), item.param2
        if speed == ms.SPEED_NO_CHANGE:
            return
        field = {
            ms.SPEED_TYPE_AIRSPEED: "cruise_speed_m_s",
            ms.SPEED_TYPE_GROUNDSPEED: "cruise_speed_m_s",
            ms.SPEED_TYPE_CLIMB: "climb_speed_m_s",
            ms.SPEED_TYPE_DESCENT: "descent_speed_m_s",
        }.get(kind)
        if field is None:
            raise MissionBuildError(item.seq, ms.INVALID_PARAM1, f"speed type {item.param1}")
        if speed == ms.SPEED_DEFAULT:
            value = getattr(self.defaults, field)
        elif math.isfinite(speed) and speed > 0.0:
            value = min(speed, self.limits.max_speed_m_s)
        else:
            raise MissionBuildError(item.seq, ms.INVALID_PARAM2, f"speed {speed}")
        self.limits = replace(self.limits, **{field: value})


def _vec(v: npt.ArrayLike) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float).reshape(3)
    return (float(a[0]), float(a[1]), float(a[2]))


def _target_nwu(item: ms.MissionItem, home: GeoPoint | None, here_nwu_m: FloatArray) -> FloatArray:
    """The item's position in NWU; "here" parts (0/0 lat/lon, NaN z) from ``here_nwu_m``."""
    try:
        p = ms.item_position_ned_m(item, home)
    except ValueError as exc:
        raise MissionBuildError(item.seq, ms.UNSUPPORTED_FRAME, str(exc)) from exc
    here_ned = flip(_vec(here_nwu_m))
    north, east = p.north_east_m if p.north_east_m is not None else (here_ned[0], here_ned[1])
    down = p.down_m if p.down_m is not None else here_ned[2]
    return np.array(flip((north, east, down)))


def build_waypoint_trajectory(
    items: Sequence[ms.MissionItem],
    home: GeoPoint | None,
    start_nwu_m: Sequence[float],
    limits: FlightLimits | None = None,
    start_seq: int = 0,
) -> WaypointTrajectory:
    """Turn ``items`` (from ``start_seq``) flown from ``start_nwu_m`` into a trajectory.

    DO_CHANGE_SPEED items before ``start_seq`` still apply (resuming a mission keeps the
    speed it set). Raises :class:`MissionBuildError` for an item that cannot be flown.
    """
    b = _Builder(start_nwu_m, limits or FlightLimits())
    for item in items[:start_seq]:
        if item.command == ms.CMD_CHANGE_SPEED:
            b.change_speed(item)
    for item in items[start_seq:]:
        cmd, seq = item.command, item.seq
        if cmd == ms.CMD_CHANGE_SPEED:
            b.change_speed(item)
            b.reach(seq)
        elif cmd == ms.CMD_TAKEOFF:
            target = _target_nwu(item, home, b.pos)
            b.move(np.array([b.pos[0], b.pos[1], target[2]]), seq)  # straight up first
            b.move(target, seq)
            b.reach(seq)
        elif cmd in (ms.CMD_WAYPOINT, ms.CMD_LOITER_TIME):
            b.move(_target_nwu(item, home, b.pos), seq)
            b.reach(seq)
            b.hold(item.param1, seq)
        elif cmd == ms.CMD_LAND:
            target = _target_nwu(item, home, b.pos)
            if math.isnan(item.z):
                target[2] = 0.0  # home ground level (flat terrain)
            b.move(np.array([target[0], target[1], b.pos[2]]), seq)
            b.move(target, seq, b.limits.land_speed_m_s)
            b.reach(seq)
        elif cmd == ms.CMD_RTL:
            b.move(np.array([0.0, 0.0, b.pos[2]]), seq)
            b.move(np.zeros(3), seq, b.limits.land_speed_m_s)
            b.reach(seq)
            break  # the mission ends on the ground at home
        else:
            raise MissionBuildError(seq, ms.UNSUPPORTED, f"command {cmd} is not a waypoint item")
    return WaypointTrajectory(b.legs, b.reached, _vec(np.asarray(start_nwu_m, dtype=float)))
