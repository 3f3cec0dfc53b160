"""The vehicle side of the MAVLink mission protocol, without I/O or clock.

:class:`MissionServer` is a pure state machine: the GCS link feeds it every decoded
pymavlink message with ``handle(msg, now_s)`` and calls ``tick(now_s)`` periodically
(at 10 Hz or faster); both return the pymavlink messages to send. It never reads a
clock and never touches a socket, so tests drive it with an injected ``now_s``.

Protocol (https://mavlink.io/en/services/mission.html), and the choices made here:

* Upload: MISSION_COUNT -> MISSION_REQUEST_INT(0) -> MISSION_ITEM_INT(0) -> ... ->
  MISSION_ACK. Legacy MISSION_ITEM is accepted too; once a partner sends one, it is asked
  with legacy MISSION_REQUEST (as PX4 does). Each item is validated on arrival
  (:func:`check_item`); the whole mission by the ``check_mission`` callback before the
  final ACK. Uploads are ATOMIC: the stored mission is replaced only when the final
  MISSION_ACK is MAV_MISSION_ACCEPTED; any error, cancellation or timeout leaves the
  previous mission untouched (spec: "A new mission should be fully uploaded and accepted
  before the old mission is replaced").
* Timeouts: an item that does not arrive within ``item_timeout_s`` (spec: 250 ms for
  mission items) is re-requested, up to ``max_retries`` (spec: 5) times in a row; then the
  upload is abandoned with MISSION_ACK MAV_MISSION_OPERATION_CANCELLED (as ArduPilot).
* Out-of-sequence items (spec: recoverable, not errors): an item *ahead* of the expected
  one is dropped and the expected one re-requested at once (once per expected seq, so a
  GCS that streams items does not cause a request storm; the timer does the rest); a
  *duplicate* of an item already stored (a GCS answering our retry as well as the
  original request) is dropped silently, since re-requesting would double every
  following item. An item that arrives when no upload is in progress is answered with
  MAV_MISSION_INVALID_SEQUENCE, except a repeat of the last item of the upload just
  completed, which gets the final ACK again (the GCS missed it; PX4 does the same).
* MISSION_COUNT from another partner during an upload -> MAV_MISSION_DENIED; from the
  same partner -> the upload restarts (the GCS restarted it, or our first request was
  lost). count > ``max_items`` -> MAV_MISSION_NO_SPACE. count == 0 clears the mission.
* Download: MISSION_REQUEST_LIST -> MISSION_COUNT; then every MISSION_REQUEST_INT (or
  legacy MISSION_REQUEST, answered with MISSION_ITEM_INT as the spec says) is answered
  independently, in any order and as often as asked: MAVProxy sends requests for all
  missing items at once. The items come from a snapshot taken at MISSION_REQUEST_LIST so
  an upload completing meanwhile cannot mix two missions; the GCS's final MISSION_ACK
  (or ``download_timeout_s`` of silence) drops the snapshot.
* MISSION_CLEAR_ALL -> MISSION_ACK; refused with MAV_MISSION_ERROR during an upload.
* MISSION_SET_CURRENT -> MISSION_CURRENT (broadcast), or a STATUSTEXT if the seq is not
  in the mission or the ``on_set_current`` callback refuses.
* Mission types: only MAV_MISSION_TYPE_MISSION is stored. Geofence and rally are
  "accepted empty", as PX4 does for rally: their download reports 0 items, uploading 0
  items or clearing them is ACCEPTED, uploading any item is MAV_MISSION_UNSUPPORTED.
  So the vehicle must NOT advertise MAV_PROTOCOL_CAPABILITY_MISSION_FENCE/_RALLY.
  MAV_MISSION_TYPE_ALL is valid only in MISSION_CLEAR_ALL.
* MISSION_ITEM_INT positions: global frames carry degE7 latitude/longitude in x/y for
  every global frame, the _INT variants and (as QGroundControl, MAVProxy and PX4 do)
  MAV_FRAME_GLOBAL / GLOBAL_RELATIVE_ALT too; local frames carry metres * 1e4
  (spec: "position in meters x 1E4"); z is a float in metres.
* Frames: GLOBAL(_INT) (altitude AMSL, converted with the home altitude),
  GLOBAL_RELATIVE_ALT(_INT) (above home), LOCAL_NED (about home, the local origin) and
  MAV_FRAME_MISSION for items without a position (RTL, DO_CHANGE_SPEED, the trajectory
  header). MAV_FRAME_LOCAL_ENU is refused (MAV_MISSION_UNSUPPORTED_FRAME): neither PX4
  nor ArduPilot take it in missions, and an ENU <-> NED change would be a second place
  where frames change besides heli_common.frames. Terrain frames are refused (no terrain).
* Commands: NAV_TAKEOFF, NAV_WAYPOINT, NAV_LOITER_TIME, NAV_LAND, NAV_RETURN_TO_LAUNCH,
  DO_CHANGE_SPEED, and the two commands of the timed-trajectory encoding
  (:mod:`autopilot.trajectory_codec`): MAV_CMD_USER_1 (header) and
  MAV_CMD_WAYPOINT_USER_1 (samples). Anything else -> MAV_MISSION_UNSUPPORTED.

pymavlink 2.4.50's common dialect has no ``opaque_id`` fields, so plan ids are not sent.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

from pymavlink.dialects.v20 import development as mavlink

from autopilot.mission.checks import DEFAULT_LIMITS, ItemLimits, check_item
from heli_common.geo import GeoPoint
from heli_common.wire.mavlink.mission_items import (
    ACCEPTED,
    CANCELLED,
    DENIED,
    EMPTY_TYPES,
    ERROR,
    INVALID,
    INVALID_SEQUENCE,
    NO_SPACE,
    TYPE_ALL,
    TYPE_MISSION,
    UINT16_MAX,
    UNSUPPORTED,
    ItemError,
    MissionItem,
)
from heli_common.wire.mavlink.udp import Message, addressed_to

MissionCheck = Callable[[tuple[MissionItem, ...]], int]
SetCurrentCheck = Callable[[int], bool]
MissionChanged = Callable[[tuple[MissionItem, ...]], None]
Partner = tuple[int, int]


@dataclass
class _Upload:
    partner: Partner
    count: int
    items: list[MissionItem]
    last_request_s: float
    retries: int = 0
    legacy: bool = False  # the partner sends MISSION_ITEM: ask with MISSION_REQUEST
    rerequested: bool = False  # the expected seq was re-requested on an early item


@dataclass
class _Download:
    items: tuple[MissionItem, ...]
    last_s: float


@dataclass
class _Done:
    partner: Partner
    count: int
    result: int


@dataclass
class MissionServer:
    """Vehicle side of the mission protocol (see the module docstring for the rules).

    ``check_mission(items)`` validates a complete upload before it replaces the stored
    mission (return MAV_MISSION_ACCEPTED or an error code, e.g. MAV_MISSION_DENIED while
    flying when the mission cannot be turned into a trajectory; a ValueError counts as
    MAV_MISSION_INVALID). It is also asked about clearing (an empty tuple).
    ``on_set_current(seq)`` lets the flight logic refuse MISSION_SET_CURRENT.
    ``on_mission_changed(items)`` is called after the stored mission was replaced.
    """

    system_id: int = 1
    component_id: int = 1
    home: GeoPoint | None = None
    limits: ItemLimits = DEFAULT_LIMITS
    max_items: int = 2_000
    item_timeout_s: float = 0.25  # spec: "Timeout (mission items): 250 ms"
    max_retries: int = 5  # spec: "Retries (max): 5"
    download_timeout_s: float = 5.0
    check_mission: MissionCheck | None = None
    on_set_current: SetCurrentCheck | None = None
    on_mission_changed: MissionChanged | None = None
    _mission: tuple[MissionItem, ...] = field(default=(), init=False)
    current_seq: int = field(default=0, init=False)
    generation: int = field(default=0, init=False)  # bumps whenever the mission changes
    _upload: _Upload | None = field(default=None, init=False)
    _last_done: _Done | None = field(default=None, init=False)
    _downloads: dict[tuple[Partner, int], _Download] = field(default_factory=dict, init=False)

    def __post_init__(self) -> None:
        if not 0 < self.max_items <= UINT16_MAX:
            raise ValueError(f"max_items must be in (0, {UINT16_MAX}], got {self.max_items}")
        if not self.item_timeout_s > 0.0 or self.max_retries < 0:
            raise ValueError("item_timeout_s must be > 0 and max_retries >= 0")

    # ----------------------------------------------------------------- state access

    @property
    def mission(self) -> tuple[MissionItem, ...]:
        """The stored (accepted) mission."""
        return self._mission

    @property
    def upload_in_progress(self) -> bool:
        return self._upload is not None

    def load(self, items: Sequence[MissionItem]) -> None:
        """Replace the stored mission directly (e.g. from a file at start-up), renumbered."""
        self._replace(tuple(replace(it, seq=i, mission_type=TYPE_MISSION) for i, it in enumerate(items)))

    # ----------------------------------------------------------------- input

    def handle(self, msg: Message, now_s: float) -> list[Message]:
        """Process one decoded message; returns the messages to send (maybe none)."""
        kind = msg.get_type()
        handler = self._HANDLERS.get(kind)
        if handler is None or not self._addressed_to_me(msg):
            return []
        return handler(self, msg, now_s)

    def tick(self, now_s: float) -> list[Message]:
        """Timeouts: re-request a missing item, abandon a dead upload, drop stale snapshots."""
        out: list[Message] = []
        up = self._upload
        # 1 us slack: a caller ticking every 50 ms must not miss 250 ms by float rounding.
        if up is not None and now_s - up.last_request_s >= self.item_timeout_s - 1e-6:
            if up.retries >= self.max_retries:
                # Give up; the previous mission stays (atomic upload). Tell the GCS, as
                # ArduPilot does, in case it is still there.
                self._upload = None
                out.append(self._ack(up.partner, CANCELLED, TYPE_MISSION))
                out.append(self._text(mavlink.MAV_SEVERITY_WARNING, "Mission upload timed out"))
            else:
                up.retries += 1
                out.append(self._request(up, now_s))
        for key, dl in list(self._downloads.items()):
            if now_s - dl.last_s > self.download_timeout_s:
                del self._downloads[key]
        return out

    # ----------------------------------------------------------------- flight logic

    def set_current(self, seq: int) -> list[Message]:
        """The flight logic moved to item ``seq``: broadcast MISSION_CURRENT if it changed."""
        if not 0 <= seq < max(len(self._mission), 1) or seq == self.current_seq:
            return []
        self.current_seq = seq
        return [self.mission_current_message()]

    def item_reached(self, seq: int) -> list[Message]:
        """The flight logic reached item ``seq``: MISSION_ITEM_REACHED to broadcast."""
        return [mavlink.MAVLink_mission_item_reached_message(seq)]

    def mission_current_message(self, mission_state: int | None = None, mission_mode: int = 0) -> Message:
        """MISSION_CURRENT for the telemetry stream (spec: total = UINT16_MAX if no mission)."""
        total = len(self._mission) if self._mission else UINT16_MAX
        if mission_state is None:
            mission_state = (
                mavlink.MISSION_STATE_NOT_STARTED if self._mission else mavlink.MISSION_STATE_NO_MISSION
            )
        return mavlink.MAVLink_mission_current_message(self.current_seq, total, mission_state, mission_mode)

    # ----------------------------------------------------------------- handlers

    def _on_count(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        count = int(msg.count)
        up = self._upload
        if up is not None and up.partner != partner:
            return [self._ack(partner, DENIED, mtype)]  # one upload at a time
        self._upload = None  # the same partner restarting: start again from scratch
        if mtype in EMPTY_TYPES:
            return [self._ack(partner, ACCEPTED if count == 0 else UNSUPPORTED, mtype)]
        if mtype != TYPE_MISSION:
            return [self._ack(partner, UNSUPPORTED, mtype)]
        if count > self.max_items:
            return [self._ack(partner, NO_SPACE, mtype)]
        if count == 0:
            result = self._accept(())
            self._last_done = _Done(partner, 0, result)
            return [self._ack(partner, result, mtype)]
        self._last_done = None
        self._upload = _Upload(partner, count, [], now_s)
        return [self._request(self._upload, now_s)]

    def _on_item(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        seq = int(msg.seq)
        up = self._upload
        if up is None:
            done = self._last_done
            if done is not None and done.partner == partner and seq == done.count - 1:
                return [self._ack(partner, done.result, mtype)]  # our final ACK was lost
            return [self._ack(partner, INVALID_SEQUENCE, mtype)]
        if partner != up.partner:
            return [self._ack(partner, DENIED, mtype)]
        if msg.get_type() == "MISSION_ITEM":
            up.legacy = True
        expected = len(up.items)
        if seq < expected:
            return []  # duplicate of a stored item: drop (see module docstring)
        if seq > expected:
            if up.rerequested:
                return []
            up.rerequested = True
            return [self._request(up, now_s)]
        if mtype != TYPE_MISSION:
            return self._abort(up, ERROR)
        try:
            item = MissionItem.from_message(msg)
        except ItemError as exc:
            return self._abort(up, exc.result)
        result = check_item(item, self.home, self.limits)
        if result != ACCEPTED:
            return self._abort(up, result)
        up.items.append(item)
        up.retries = 0
        up.rerequested = False
        if len(up.items) < up.count:
            return [self._request(up, now_s)]
        self._upload = None
        result = self._accept(tuple(up.items))
        self._last_done = _Done(partner, up.count, result)
        return [self._ack(partner, result, TYPE_MISSION)]

    def _stored(self, mission_type: int) -> tuple[MissionItem, ...] | None:
        """What is stored for ``mission_type``: fence and rally are empty; None: no such type."""
        if mission_type == TYPE_MISSION:
            return self._mission
        return () if mission_type in EMPTY_TYPES else None

    def _on_request_list(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        items = self._stored(mtype)
        if items is None:
            return [self._ack(partner, UNSUPPORTED, mtype)]
        self._downloads[(partner, mtype)] = _Download(items, now_s)
        return [mavlink.MAVLink_mission_count_message(partner[0], partner[1], len(items), mtype)]

    def _on_request(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        seq = int(msg.seq)
        dl = self._downloads.get((partner, mtype))
        if dl is not None:
            dl.last_s = now_s
        items = dl.items if dl is not None else self._stored(mtype)
        if items is None:
            return [self._ack(partner, UNSUPPORTED, mtype)]
        if not 0 <= seq < len(items):
            return [self._ack(partner, INVALID_SEQUENCE, mtype)]
        is_current = mtype == TYPE_MISSION and seq == self.current_seq
        return [items[seq].to_message(partner[0], partner[1], current=is_current)]

    def _on_ack(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        # The end of a download (any result), or a cancellation of our upload by the GCS.
        self._downloads.pop((partner, mtype), None)
        up = self._upload
        if up is not None and up.partner == partner and int(msg.type) != ACCEPTED:
            self._upload = None
        return []

    def _on_clear_all(self, msg: Message, now_s: float) -> list[Message]:
        partner = _partner(msg)
        mtype = int(getattr(msg, "mission_type", TYPE_MISSION))
        if self._upload is not None:
            return [self._ack(partner, ERROR, mtype)]  # busy: "not accepting ... right now"
        if mtype in EMPTY_TYPES:
            return [self._ack(partner, ACCEPTED, mtype)]
        if mtype not in (TYPE_MISSION, TYPE_ALL):
            return [self._ack(partner, UNSUPPORTED, mtype)]
        return [self._ack(partner, self._accept(()), mtype)]

    def _on_set_current(self, msg: Message, now_s: float) -> list[Message]:
        seq = int(msg.seq)
        if not 0 <= seq < len(self._mission):
            return [self._text(mavlink.MAV_SEVERITY_WARNING, f"Mission seq {seq} not in mission")]
        if self.on_set_current is not None and not self.on_set_current(seq):
            return [self._text(mavlink.MAV_SEVERITY_WARNING, f"Mission seq {seq} refused")]
        self.current_seq = seq
        return [self.mission_current_message()]

    _HANDLERS: ClassVar[dict[str, Callable[[MissionServer, Message, float], list[Message]]]] = {
        "MISSION_COUNT": _on_count,
        "MISSION_ITEM_INT": _on_item,
        "MISSION_ITEM": _on_item,
        "MISSION_REQUEST_LIST": _on_request_list,
        "MISSION_REQUEST_INT": _on_request,
        "MISSION_REQUEST": _on_request,
        "MISSION_ACK": _on_ack,
        "MISSION_CLEAR_ALL": _on_clear_all,
        "MISSION_SET_CURRENT": _on_set_current,
    }

    # ----------------------------------------------------------------- helpers

    def _addressed_to_me(self, msg: Message) -> bool:
        """Broadcast (0) or our ids; messages for other systems are not ours to answer."""
        return addressed_to(msg, self.system_id, self.component_id)

    def _accept(self, items: tuple[MissionItem, ...]) -> int:
        """Whole-mission check, then replace the stored mission only if accepted."""
        result = ACCEPTED
        if self.check_mission is not None:
            try:
                result = int(self.check_mission(items))
            except ValueError:
                result = INVALID
        if result == ACCEPTED:
            self._replace(items)
        return result

    def _replace(self, items: tuple[MissionItem, ...]) -> None:
        self._mission = items
        flagged = [it.seq for it in items if it.current]
        self.current_seq = flagged[0] if flagged else 0
        self.generation += 1
        if self.on_mission_changed is not None:
            self.on_mission_changed(items)

    def _abort(self, up: _Upload, result: int) -> list[Message]:
        """An error ends the upload (spec: errors are unrecoverable); the old mission stays."""
        self._upload = None
        self._last_done = None
        return [self._ack(up.partner, result, TYPE_MISSION)]

    def _request(self, up: _Upload, now_s: float) -> Message:
        up.last_request_s = now_s
        seq = len(up.items)
        cls = (
            mavlink.MAVLink_mission_request_message
            if up.legacy
            else mavlink.MAVLink_mission_request_int_message
        )
        return cls(up.partner[0], up.partner[1], seq, TYPE_MISSION)

    def _ack(self, partner: Partner, result: int, mission_type: int) -> Message:
        return mavlink.MAVLink_mission_ack_message(partner[0], partner[1], result, mission_type)

    @staticmethod
    def _text(severity: int, text: str) -> Message:
        return mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:50])


def _partner(msg: Message) -> Partner:
    return (int(msg.get_srcSystem()), int(msg.get_srcComponent()))
