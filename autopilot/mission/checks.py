"""What this vehicle accepts in a mission item: :func:`check_item` -> MAV_MISSION_RESULT.

Frames: GLOBAL(_INT) (altitude AMSL, converted with the home altitude),
GLOBAL_RELATIVE_ALT(_INT) (above home), LOCAL_NED (about home, the local origin) and
MAV_FRAME_MISSION for items without a position (RTL, DO_CHANGE_SPEED, the trajectory
header). MAV_FRAME_LOCAL_ENU is refused (MAV_MISSION_UNSUPPORTED_FRAME): neither PX4 nor
ArduPilot take it in missions, and an ENU <-> NED change would be a second place where
frames change besides heli_common.frames. Terrain frames are refused (no terrain).
Commands: NAV_TAKEOFF, NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LAND, NAV_RETURN_TO_LAUNCH,
DO_CHANGE_SPEED, and the two commands of the timed-trajectory encoding
(:mod:`autopilot.trajectory_codec`): MAV_CMD_USER_1 (header) and MAV_CMD_WAYPOINT_USER_1
(samples). Anything else -> MAV_MISSION_UNSUPPORTED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from heli_common.geo import GeoPoint, geo_to_ned_m
from heli_common.wire.mavlink.mission_items import (
    ACCEPTED,
    AMSL_FRAMES,
    BREAK_MASK_ALL,
    CMD_CHANGE_SPEED,
    CMD_LAND,
    CMD_LOITER_TIME,
    CMD_RTL,
    CMD_TAKEOFF,
    CMD_TRAJ_HEADER,
    CMD_TRAJ_SAMPLE,
    CMD_WAYPOINT,
    FRAME_LOCAL_NED,
    FRAME_MISSION,
    INVALID_PARAM1,
    INVALID_PARAM2,
    INVALID_PARAM3,
    INVALID_PARAM4,
    INVALID_X,
    INVALID_Y,
    INVALID_Z,
    POSITION_FRAMES,
    SPEED_DEFAULT,
    SPEED_NO_CHANGE,
    SPEED_TYPE_AIRSPEED,
    SPEED_TYPE_CLIMB,
    SPEED_TYPE_DESCENT,
    SPEED_TYPE_GROUNDSPEED,
    SUPPORTED_COMMANDS,
    UNSUPPORTED,
    UNSUPPORTED_FRAME,
    MissionItem,
    no_position_given,
)


@dataclass(frozen=True)
class ItemLimits:
    """What this vehicle accepts in a mission item."""

    max_range_m: float = 5_000.0  # horizontal distance from home
    min_alt_m: float = -100.0  # altitude relative to home
    max_alt_m: float = 1_000.0
    max_hold_s: float = 3_600.0  # NAV_WAYPOINT hold, NAV_LOITER_TIME
    max_speed_m_s: float = 20.0  # DO_CHANGE_SPEED
    max_time_s: float = 86_400.0  # timed-trajectory sample times


DEFAULT_LIMITS = ItemLimits()


def _in(value: float, lo: float, hi: float) -> bool:
    return math.isfinite(value) and lo <= value <= hi


def _check_position(
    item: MissionItem, home: GeoPoint | None, limits: ItemLimits, here_ok: bool, nan_z_ok: bool
) -> int:
    """Frame and x/y/z checks of a positional item -> MAV_MISSION_RESULT."""
    if item.frame not in POSITION_FRAMES:
        return UNSUPPORTED_FRAME
    if item.frame == FRAME_LOCAL_NED:
        if abs(item.local_north_m) > limits.max_range_m:
            return INVALID_X
        if abs(item.local_east_m) > limits.max_range_m:
            return INVALID_Y
        up_m = -item.z
    else:
        if no_position_given(item):
            if not here_ok:
                return INVALID_X  # a waypoint needs a position; 0/0 is "none given"
        else:
            if not -90.0 <= item.lat_deg <= 90.0:
                return INVALID_X
            if not -180.0 <= item.lon_deg <= 180.0:
                return INVALID_Y
            if home is not None:
                n, e, _ = geo_to_ned_m(home, item.lat_deg, item.lon_deg, home.alt_amsl_m)
                if abs(n) > limits.max_range_m:
                    return INVALID_X
                if abs(e) > limits.max_range_m:
                    return INVALID_Y
        if item.frame in AMSL_FRAMES:
            # Without home the AMSL altitude cannot be related to the ground: range-check
            # only when it can be converted.
            up_m = item.z - home.alt_amsl_m if home is not None else 0.0
            if math.isnan(item.z):
                up_m = math.nan
        else:
            up_m = item.z
    if math.isnan(up_m) and nan_z_ok:
        return ACCEPTED
    if not _in(up_m, limits.min_alt_m, limits.max_alt_m):
        return INVALID_Z
    return ACCEPTED


def check_item(item: MissionItem, home: GeoPoint | None, limits: ItemLimits = DEFAULT_LIMITS) -> int:
    """Validate one item -> MAV_MISSION_ACCEPTED or the MAV_MISSION_RESULT error code.

    Order: command, frame, params 1-4, x, y, z (the first failure is reported). Params a
    command does not use on this vehicle are not checked (e.g. NAV_WAYPOINT acceptance
    radius and yaw: the trajectory passes exactly through the point and the TLC holds
    heading along the velocity).
    """
    cmd = item.command
    if cmd not in SUPPORTED_COMMANDS:
        return UNSUPPORTED
    if cmd in (CMD_RTL, CMD_CHANGE_SPEED):
        if item.frame not in POSITION_FRAMES | {FRAME_MISSION}:
            return UNSUPPORTED_FRAME
        if cmd == CMD_CHANGE_SPEED:
            if item.param1 not in (
                SPEED_TYPE_AIRSPEED,
                SPEED_TYPE_GROUNDSPEED,
                SPEED_TYPE_CLIMB,
                SPEED_TYPE_DESCENT,
            ):
                return INVALID_PARAM1
            speed = item.param2
            if speed not in (SPEED_NO_CHANGE, SPEED_DEFAULT) and not (
                _in(speed, 0.0, limits.max_speed_m_s) and speed > 0.0
            ):
                return INVALID_PARAM2
        return ACCEPTED
    if cmd == CMD_TRAJ_HEADER:
        if item.frame != FRAME_MISSION:
            return UNSUPPORTED_FRAME
        for code, v in (
            (INVALID_PARAM1, item.param1),
            (INVALID_PARAM2, item.param2),
            (INVALID_PARAM3, item.param3),
            (INVALID_PARAM4, item.param4),
        ):
            if not math.isfinite(v):
                return code
        return ACCEPTED if math.isfinite(item.z) else INVALID_Z
    if cmd == CMD_TRAJ_SAMPLE:
        if item.frame != FRAME_LOCAL_NED:
            return UNSUPPORTED_FRAME
        if not _in(item.param1, 0.0, limits.max_time_s):
            return INVALID_PARAM1
        if not (_in(item.param2, 0.0, BREAK_MASK_ALL) and item.param2.is_integer()):
            return INVALID_PARAM2  # axis bit mask
        if item.param3 != 0.0:
            return INVALID_PARAM3  # reserved
        if not (math.isnan(item.param4) or _in(item.param4, -360.0, 360.0)):
            return INVALID_PARAM4
        return _check_position(item, home, limits, here_ok=False, nan_z_ok=False)
    if cmd in (CMD_WAYPOINT, CMD_LOITER_TIME) and not _in(item.param1, 0.0, limits.max_hold_s):
        return INVALID_PARAM1  # hold time [s]
    return _check_position(
        item,
        home,
        limits,
        here_ok=cmd in (CMD_TAKEOFF, CMD_LAND, CMD_LOITER_TIME),
        nan_z_ok=cmd == CMD_LAND,
    )
