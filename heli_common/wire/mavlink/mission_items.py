"""Mission items as MAVLink carries them: the codes, frames and commands this bench uses,
:class:`MissionItem` (the MISSION_ITEM_INT encoding, with its legacy MISSION_ITEM
conversion) and where a positional item points (:func:`item_position_ned_m`).

Encoding rules (https://mavlink.io/en/services/mission.html): global frames carry degE7
latitude/longitude in x/y for every global frame, the _INT variants and (as
QGroundControl, MAVProxy and PX4 do) MAV_FRAME_GLOBAL / GLOBAL_RELATIVE_ALT too; local
frames carry metres * 1e4; z is a float in metres. Both the vehicle (``autopilot.mission``)
and the ground tools use this module, so the two ends cannot disagree.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import development as mavlink

from heli_common.geo import GeoPoint, geo_to_ned_m
from heli_common.wire.mavlink.udp import Message
from heli_common.wire.mavlink.wire import f32

# MAV_MISSION_RESULT codes, named once so the rest of the module reads as the spec.
ACCEPTED: int = mavlink.MAV_MISSION_ACCEPTED
ERROR: int = mavlink.MAV_MISSION_ERROR
UNSUPPORTED_FRAME: int = mavlink.MAV_MISSION_UNSUPPORTED_FRAME
UNSUPPORTED: int = mavlink.MAV_MISSION_UNSUPPORTED
NO_SPACE: int = mavlink.MAV_MISSION_NO_SPACE
INVALID: int = mavlink.MAV_MISSION_INVALID
INVALID_PARAM1: int = mavlink.MAV_MISSION_INVALID_PARAM1
INVALID_PARAM2: int = mavlink.MAV_MISSION_INVALID_PARAM2
INVALID_PARAM3: int = mavlink.MAV_MISSION_INVALID_PARAM3
INVALID_PARAM4: int = mavlink.MAV_MISSION_INVALID_PARAM4
INVALID_X: int = mavlink.MAV_MISSION_INVALID_PARAM5_X
INVALID_Y: int = mavlink.MAV_MISSION_INVALID_PARAM6_Y
INVALID_Z: int = mavlink.MAV_MISSION_INVALID_PARAM7
INVALID_SEQUENCE: int = mavlink.MAV_MISSION_INVALID_SEQUENCE
DENIED: int = mavlink.MAV_MISSION_DENIED
CANCELLED: int = mavlink.MAV_MISSION_OPERATION_CANCELLED

TYPE_MISSION: int = mavlink.MAV_MISSION_TYPE_MISSION
TYPE_FENCE: int = mavlink.MAV_MISSION_TYPE_FENCE
TYPE_RALLY: int = mavlink.MAV_MISSION_TYPE_RALLY
TYPE_ALL: int = mavlink.MAV_MISSION_TYPE_ALL
# Fence and rally are "accepted empty" (see the module docstring).
EMPTY_TYPES: frozenset[int] = frozenset({TYPE_FENCE, TYPE_RALLY})

CMD_TAKEOFF: int = mavlink.MAV_CMD_NAV_TAKEOFF
CMD_WAYPOINT: int = mavlink.MAV_CMD_NAV_WAYPOINT
CMD_LOITER_TIME: int = mavlink.MAV_CMD_NAV_LOITER_TIME
CMD_LAND: int = mavlink.MAV_CMD_NAV_LAND
CMD_RTL: int = mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
CMD_CHANGE_SPEED: int = mavlink.MAV_CMD_DO_CHANGE_SPEED
# The timed-trajectory encoding (autopilot.trajectory_codec): the "user defined" commands
# whose params the MAVLink spec leaves to the vehicle, so no standard meaning is bent.
CMD_TRAJ_HEADER: int = mavlink.MAV_CMD_USER_1
CMD_TRAJ_SAMPLE: int = mavlink.MAV_CMD_WAYPOINT_USER_1
SUPPORTED_COMMANDS: frozenset[int] = frozenset(
    {
        CMD_TAKEOFF,
        CMD_WAYPOINT,
        CMD_LOITER_TIME,
        CMD_LAND,
        CMD_RTL,
        CMD_CHANGE_SPEED,
        CMD_TRAJ_HEADER,
        CMD_TRAJ_SAMPLE,
    }
)

FRAME_GLOBAL: int = mavlink.MAV_FRAME_GLOBAL
FRAME_GLOBAL_INT: int = mavlink.MAV_FRAME_GLOBAL_INT
FRAME_GLOBAL_REL: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
FRAME_GLOBAL_REL_INT: int = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
FRAME_LOCAL_NED: int = mavlink.MAV_FRAME_LOCAL_NED
FRAME_MISSION: int = mavlink.MAV_FRAME_MISSION
AMSL_FRAMES: frozenset[int] = frozenset({FRAME_GLOBAL, FRAME_GLOBAL_INT})
RELATIVE_FRAMES: frozenset[int] = frozenset({FRAME_GLOBAL_REL, FRAME_GLOBAL_REL_INT})
# Frames whose x/y are latitude/longitude (the terrain ones are listed only so that a
# legacy MISSION_ITEM in them is scaled right before being refused).
GLOBAL_FRAMES: frozenset[int] = frozenset(
    AMSL_FRAMES
    | RELATIVE_FRAMES
    | {mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}
)
LOCAL_FRAMES: frozenset[int] = frozenset(
    {
        FRAME_LOCAL_NED,
        mavlink.MAV_FRAME_LOCAL_ENU,
        mavlink.MAV_FRAME_LOCAL_OFFSET_NED,
        mavlink.MAV_FRAME_BODY_NED,
        mavlink.MAV_FRAME_BODY_OFFSET_NED,
        mavlink.MAV_FRAME_BODY_FRD,
        mavlink.MAV_FRAME_LOCAL_FRD,
        mavlink.MAV_FRAME_LOCAL_FLU,
    }
)
POSITION_FRAMES: frozenset[int] = frozenset(AMSL_FRAMES | RELATIVE_FRAMES | {FRAME_LOCAL_NED})

DEG_E7 = 1e7  # MISSION_ITEM_INT x/y scale in global frames
LOCAL_E4 = 1e4  # MISSION_ITEM_INT x/y scale in local frames: metres * 1e4
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
UINT16_MAX = 2**16 - 1

# DO_CHANGE_SPEED param1 speed types and param2 special values (MAVLink common.xml)
SPEED_TYPE_AIRSPEED, SPEED_TYPE_GROUNDSPEED, SPEED_TYPE_CLIMB, SPEED_TYPE_DESCENT = 0, 1, 2, 3
SPEED_NO_CHANGE, SPEED_DEFAULT = -1.0, -2.0

# Timed-trajectory sample: param2 is a bit mask of axes (N=1, E=2, D=4) whose spline is
# split at this sample (a corner: the derivative may jump). See trajectory_codec.
BREAK_MASK_ALL = 7

class ItemError(ValueError):
    """A MISSION_ITEM that cannot be represented; ``result`` is the MAV_MISSION_RESULT."""

    def __init__(self, result: int, text: str) -> None:
        super().__init__(text)
        self.result = result


@dataclass(frozen=True, eq=False)
class MissionItem:
    """One mission item in MISSION_ITEM_INT encoding (what is stored and downloaded).

    ``x``/``y`` are int32 as on the wire: degE7 in global frames, metres * 1e4 in local
    frames, raw values otherwise. ``param1..4`` and ``z`` are rounded to float32 on
    construction, so an item equals itself after a trip through MAVLink. Equality treats
    NaN params as equal (NaN is a legitimate value: "unchanged yaw", "land here").
    """

    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    autocontinue: bool = True
    current: bool = False
    mission_type: int = TYPE_MISSION

    def __post_init__(self) -> None:
        if not 0 <= self.seq <= UINT16_MAX:
            raise ValueError(f"seq must be a uint16, got {self.seq}")
        for name in ("x", "y"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not INT32_MIN <= v <= INT32_MAX:
                raise ValueError(f"{name} must be an int32, got {v!r}")
        for name in ("param1", "param2", "param3", "param4", "z"):
            object.__setattr__(self, name, f32(getattr(self, name)))  # equal after a round trip

    def _key(self) -> tuple[object, ...]:
        return tuple(
            "nan" if isinstance(v, float) and math.isnan(v) else v for v in dataclasses.astuple(self)
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MissionItem):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @classmethod
    def from_message(cls, msg: Message) -> MissionItem:
        """A decoded MISSION_ITEM_INT or legacy MISSION_ITEM -> item (raises ItemError)."""
        kind = msg.get_type()
        if kind == "MISSION_ITEM_INT":
            x, y = int(msg.x), int(msg.y)
        elif kind == "MISSION_ITEM":
            x, y = _legacy_xy(int(msg.frame), float(msg.x), float(msg.y))
        else:
            raise TypeError(f"not a mission item: {kind}")
        return cls(
            seq=int(msg.seq),
            frame=int(msg.frame),
            command=int(msg.command),
            param1=float(msg.param1),
            param2=float(msg.param2),
            param3=float(msg.param3),
            param4=float(msg.param4),
            x=x,
            y=y,
            z=float(msg.z),
            autocontinue=bool(msg.autocontinue),
            current=bool(msg.current),
            mission_type=int(getattr(msg, "mission_type", TYPE_MISSION)),
        )

    def to_message(self, target_system: int, target_component: int, current: bool | None = None) -> Message:
        """This item as a MISSION_ITEM_INT to ``target_system``/``target_component``."""
        return mavlink.MAVLink_mission_item_int_message(
            target_system,
            target_component,
            self.seq,
            self.frame,
            self.command,
            int(self.current if current is None else current),
            int(self.autocontinue),
            self.param1,
            self.param2,
            self.param3,
            self.param4,
            self.x,
            self.y,
            self.z,
            self.mission_type,
        )

    @property
    def lat_deg(self) -> float:
        return self.x / DEG_E7

    @property
    def lon_deg(self) -> float:
        return self.y / DEG_E7

    @property
    def local_north_m(self) -> float:
        return self.x / LOCAL_E4

    @property
    def local_east_m(self) -> float:
        return self.y / LOCAL_E4


def _legacy_xy(frame: int, x: float, y: float) -> tuple[int, int]:
    """Float x/y of a legacy MISSION_ITEM -> the int32 MISSION_ITEM_INT encoding."""
    if frame in GLOBAL_FRAMES:
        if math.isnan(x) and math.isnan(y):
            return 0, 0  # "no position given" (e.g. land here), as 0/0 in MISSION_ITEM_INT
        scale = DEG_E7
    elif frame in LOCAL_FRAMES:
        scale = LOCAL_E4
    else:
        # MAV_FRAME_MISSION: x/y are free integer params; none of our commands use them.
        return (round(x) if math.isfinite(x) else 0, round(y) if math.isfinite(y) else 0)
    out = []
    for value, code, name in ((x, INVALID_X, "x"), (y, INVALID_Y, "y")):
        if not math.isfinite(value):
            raise ItemError(code, f"{name} is not finite: {value}")
        scaled = round(value * scale)
        if not INT32_MIN <= scaled <= INT32_MAX:
            raise ItemError(code, f"{name} out of range: {value}")
        out.append(scaled)
    return out[0], out[1]


@dataclass(frozen=True)
class ItemPosition:
    """Where a positional item goes, local NED about home; None = "where the vehicle is"."""

    north_east_m: tuple[float, float] | None
    down_m: float | None


def no_position_given(item: MissionItem) -> bool:
    """0/0 lat/lon in a global frame means "no position given" (land/take off here)."""
    return item.frame in GLOBAL_FRAMES and item.x == 0 and item.y == 0


def item_position_ned_m(item: MissionItem, home: GeoPoint | None) -> ItemPosition:
    """The item's target in local NED [m] about home (needs home for global frames).

    In global frames 0/0 lat/lon means "current horizontal position" and a NaN z means
    "current altitude"; the caller supplies the vehicle position for those.
    """
    down: float | None = None if math.isnan(item.z) else item.z
    if item.frame == FRAME_LOCAL_NED:
        return ItemPosition((item.local_north_m, item.local_east_m), down)
    if item.frame in AMSL_FRAMES or item.frame in RELATIVE_FRAMES:
        if home is None:
            raise ValueError("a global-frame mission item needs the home position")
        ne: tuple[float, float] | None = None
        if not no_position_given(item):
            n, e, _ = geo_to_ned_m(home, item.lat_deg, item.lon_deg, home.alt_amsl_m)
            ne = (n, e)
        if down is not None and item.frame in AMSL_FRAMES:
            down = home.alt_amsl_m - item.z
        elif down is not None:
            down = -item.z
        return ItemPosition(ne, down)
    raise ValueError(f"frame {item.frame} carries no position")
