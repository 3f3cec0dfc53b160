"""A small ground-station client: one UDP socket (heli_common.wire.mavlink.udp.MavlinkUdp), no
pymavlink ``mavutil`` global state, every wait bounded.

The client binds the port the vehicle sends to (``--gcs-port``, 14550 by default: the
vehicle's ground-station link; 14540 reaches its API link) and learns the vehicle's address
from the first message of ``target_system``. It speaks as system 255, component 190
(MAV_COMP_ID_MISSIONPLANNER), as QGroundControl and MAVProxy do, and sends a GCS HEARTBEAT
every second while it waits, as ground stations do.

Every message received (from anyone) goes to the optional ``.tlog`` writer and updates
:attr:`GroundClient.latest`; waits look at what arrives *after* their request (pending
input is consumed first), so an old COMMAND_ACK cannot answer a new command.

Retries follow the MAVLink services: commands are re-sent with an increasing
``confirmation`` until a COMMAND_ACK; a mission upload re-sends MISSION_COUNT until the
first request (afterwards the vehicle drives the retries, as the mission protocol says)
and is cancelled with MISSION_ACK OPERATION_CANCELLED when the vehicle falls silent;
downloads re-request each missing item; the parameter list re-requests each missing
index with PARAM_REQUEST_READ until the list is complete (QGroundControl needs it whole).
"""

from __future__ import annotations

import functools
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from heli_common.closing import Closing
from heli_common.defaults import ports
from heli_common.geo import GeoPoint
from heli_common.wire.mavlink import modes as wm
from heli_common.wire.mavlink.mission_items import MissionItem
from heli_common.wire.mavlink.udp import LOOPBACK, Address, MavlinkUdp, Message, TlogWriter, mavlink2
from heli_common.wire.mavlink.wire import decode_param, encode_param, f32

m2 = mavlink2
PORTS = ports()

GCS_SYSTEM_ID = 255
GCS_COMPONENT_ID = m2.MAV_COMP_ID_MISSIONPLANNER  # 190
# the vehicle's mode numbers (heli_common.wire.mavlink.modes): main/sub as DO_SET_MODE takes them
PX4_MAIN_AUTO, PX4_SUB_MISSION = wm.main_sub(wm.MISSION.custom_mode)
PX4_SUB_LOITER = wm.main_sub(wm.HOLD.custom_mode)[1]
PX4_MAIN_OFFBOARD = wm.main_sub(wm.OFFBOARD.custom_mode)[0]
FORCE_DISARM_MAGIC = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: disarm even in flight


class GroundError(RuntimeError):
    """Something the vehicle did not do; the message is a one-line reason."""


class LinkTimeoutError(GroundError):
    """No (or no expected) answer from the vehicle in time."""


class CommandRefusedError(GroundError):
    def __init__(self, text: str, command: int, result: int) -> None:
        super().__init__(text)
        self.command = command
        self.result = result


class MissionRefusedError(GroundError):
    def __init__(self, text: str, result: int) -> None:
        super().__init__(text)
        self.result = result


class ParamError(GroundError):
    """Unknown parameter (the vehicle answered with a STATUSTEXT, or not at all)."""


def enum_name(enum: str, value: int) -> str:
    """MAVLink enum value -> its name (``MAV_RESULT_DENIED``), or the number if unknown."""
    entry = m2.enums.get(enum, {}).get(int(value))
    return str(entry.name) if entry is not None else f"{enum}({value})"


px4_mode = wm.main_sub  # HEARTBEAT custom_mode -> (main, sub), as this vehicle reports them


@dataclass(frozen=True)
class ParamValue:
    name: str
    value: float  # decoded (C cast, as the vehicle advertises)
    param_type: int
    index: int
    count: int


@dataclass(frozen=True)
class ParamSetResult:
    accepted: bool
    value: ParamValue  # what the vehicle holds now (the old value when refused)
    reason: str = ""  # the vehicle's STATUSTEXT when it refused


@dataclass
class MissionProgress:
    """What :meth:`GroundClient.follow_mission` saw; times are the vehicle's [s]."""

    n_items: int
    duration_s: float | None = None  # timed trajectory: its length
    start_s: float | None = None  # vehicle time when following began
    elapsed_s: float = 0.0
    current_seq: int = 0
    reached: dict[int, float] = field(default_factory=dict)  # seq -> vehicle time
    finished: bool = False
    reason: str = ""  # why following ended: "all items reached", "mode ...", "disarmed"


class GroundClient(Closing):
    """Context manager: ``with GroundClient(14550) as gc: gc.connect(); gc.upload_mission(items)``."""

    def __init__(
        self,
        port: int = PORTS.gcs,
        *,
        host: str = LOOPBACK,
        signing_key: bytes | None = None,
        target_system: int = 1,
        target_component: int = 1,
        system_id: int = GCS_SYSTEM_ID,
        component_id: int = GCS_COMPONENT_ID,
        tlog: TlogWriter | None = None,
        heartbeat_period_s: float = 1.0,
    ) -> None:
        # NaN is a legitimate value on this link (mission yaw, "unset" params): keep them.
        self.link = MavlinkUdp((host, port), None, system_id=system_id, component_id=component_id,
                               drop_nonfinite=False)  # fmt: skip
        if signing_key is not None:
            # A keyed ground station trusts only messages signed with its key.
            self.link.setup_signing(signing_key, lambda _msg_id: False)
        self.system_id = system_id
        self.component_id = component_id
        self.target_system = target_system
        self.target_component = target_component
        self.tlog = tlog
        self.heartbeat_period_s = heartbeat_period_s
        # where each system was heard from: several vehicles may send to one port
        self.vehicles: dict[int, Address] = {}
        self.latest: dict[str, Message] = {}  # the vehicle's latest message of each type
        self.texts: deque[tuple[float, int, str]] = deque(maxlen=200)  # (monotonic, severity, text)
        self.listeners: list[Callable[[Message], None]] = []  # called with each message received
        self.after_poll: list[Callable[[], None]] = []  # called once a batch has been received
        self._queue: deque[Message] = deque()
        self._next_heartbeat = 0.0
        self._param_types: dict[str, int] = {}

    # ----------------------------------------------------------------- lifecycle

    def close(self) -> None:
        self.link.close()

    @property
    def port(self) -> int:
        return int(self.link.local[1])

    # ----------------------------------------------------------------- receiving

    def from_vehicle(self, m: Message) -> bool:
        """Sent by the vehicle (its system id; any of its components)."""
        return bool(m.get_srcSystem() == self.target_system)

    def _for_me(self, m: Message) -> bool:
        ts = getattr(m, "target_system", 0)
        return ts in (0, self.system_id)

    def poll(self, timeout_s: float = 0.0) -> list[Message]:
        """Receive what is queued (waiting up to ``timeout_s`` for the first datagram)."""
        self._maybe_heartbeat()
        got = self.link.recv(max(0.0, timeout_s))
        if not got:
            return []
        msgs = [m for m, _ in got]
        if self.tlog is not None:
            self.tlog.write(int(time.time() * 1e6), msgs)
        now = time.monotonic()
        for m, addr in got:
            kind = m.get_type()
            self.vehicles.setdefault(m.get_srcSystem(), addr)
            if self.from_vehicle(m):
                self.latest[kind] = m
                if kind == "STATUSTEXT":
                    self.texts.append((now, int(m.severity), str(m.text)))
            for fn in self.listeners:
                fn(m)
        for after in self.after_poll:
            after()
        return msgs

    def recv_match(self, pred: Callable[[Message], bool], timeout_s: float) -> Message | None:
        """The first message (queued or new) satisfying ``pred`` within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            while self._queue:
                m = self._queue.popleft()
                if pred(m):
                    return m
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                return None
            self._queue.extend(self.poll(min(remaining, 0.25)))

    def flush(self) -> None:
        """Consume everything pending (it is logged and kept in ``latest``, then dropped)."""
        self._queue.clear()
        while self.poll(0.0):
            pass

    def spin(self, duration_s: float) -> None:
        """Keep receiving (and logging) for ``duration_s``."""
        end = time.monotonic() + duration_s
        while (left := end - time.monotonic()) > 0:
            self.poll(min(left, 0.25))
        self._queue.clear()

    def _texts_since(self, t0: float) -> str:
        return "; ".join(text for t, _, text in self.texts if t >= t0)

    # ----------------------------------------------------------------- sending

    @property
    def vehicle(self) -> Address | None:
        """The address of the target system (None until it was heard)."""
        return self.vehicles.get(self.target_system)

    def send(self, *msgs: Message) -> None:
        to = self.vehicle
        if to is None:
            raise GroundError(f"no vehicle {self.target_system} yet: call connect() first")
        self.link.send(*msgs, to=to)

    def _maybe_heartbeat(self) -> None:
        now = time.monotonic()
        if not self.vehicles or now < self._next_heartbeat:
            return
        self._next_heartbeat = now + self.heartbeat_period_s
        hb = m2.MAVLink_heartbeat_message(
            m2.MAV_TYPE_GCS, m2.MAV_AUTOPILOT_INVALID, 0, 0, m2.MAV_STATE_ACTIVE, 3
        )
        for addr in set(self.vehicles.values()):  # every vehicle heard sees a ground station
            self.link.send(hb, to=addr)

    # ----------------------------------------------------------------- connection

    def connect(self, timeout_s: float = 30.0) -> Message:
        """Wait for the vehicle's HEARTBEAT (the vehicle's address is learnt from it)."""
        hb = self.recv_match(
            lambda m: m.get_type() == "HEARTBEAT" and self.from_vehicle(m)
            and m.type != m2.MAV_TYPE_GCS, timeout_s,
        )  # fmt: skip
        if hb is None:
            why = f"no HEARTBEAT from system {self.target_system} on UDP port {self.port} in {timeout_s:g} s"
            if self.link.stats.rx_unsigned:
                why += (f" ({self.link.stats.rx_unsigned} messages refused: not signed with our key; "
                        "is the vehicle using the same signing key?)")  # fmt: skip
            raise LinkTimeoutError(why)
        return hb

    wait_heartbeat = connect

    def vehicle_time_s(self) -> float | None:
        """The vehicle's clock [s] (time_boot_ms of its latest ATTITUDE / LOCAL_POSITION_NED)."""
        ts = [self.latest[k].time_boot_ms for k in ("ATTITUDE", "LOCAL_POSITION_NED") if k in self.latest]
        return max(ts) / 1e3 if ts else None

    # ----------------------------------------------------------------- commands

    def command(
        self,
        command: int,
        params: Sequence[float] = (),
        *,
        timeout_s: float = 1.0,
        retries: int = 3,
    ) -> int:
        """COMMAND_LONG -> the MAV_RESULT of its COMMAND_ACK (LinkTimeoutError if none comes)."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.flush()
        for attempt in range(retries + 1):
            self.send(m2.MAVLink_command_long_message(
                self.target_system, self.target_component, command, min(attempt, 255), *p))  # fmt: skip
            deadline = time.monotonic() + timeout_s
            while (left := deadline - time.monotonic()) > 0:
                ack = self.recv_match(
                    lambda m: m.get_type() == "COMMAND_ACK" and self.from_vehicle(m)
                    and m.command == command and self._for_me(m), left,
                )  # fmt: skip
                if ack is None:
                    break
                if ack.result == m2.MAV_RESULT_IN_PROGRESS:
                    deadline = time.monotonic() + timeout_s  # still working on it: keep waiting
                    continue
                return int(ack.result)
        raise LinkTimeoutError(f"{enum_name('MAV_CMD', command)}: no COMMAND_ACK after {retries + 1} tries")

    def command_ok(
        self, command: int, params: Sequence[float] = (), *, timeout_s: float = 1.0, retries: int = 3
    ) -> None:
        """:meth:`command`, raising CommandRefusedError (with the vehicle's STATUSTEXT) unless accepted."""
        t0 = time.monotonic()
        result = self.command(command, params, timeout_s=timeout_s, retries=retries)
        if result != m2.MAV_RESULT_ACCEPTED:
            self.poll(0.05)  # the STATUSTEXT saying why is sent with the ACK
            why = self._texts_since(t0)
            text = f"{enum_name('MAV_CMD', command)}: {enum_name('MAV_RESULT', result)}"
            raise CommandRefusedError(text + (f" ({why})" if why else ""), command, result)

    def arm(self) -> None:
        self.command_ok(m2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0])

    def disarm(self, force: bool = False) -> None:
        self.command_ok(m2.MAV_CMD_COMPONENT_ARM_DISARM, [0.0, FORCE_DISARM_MAGIC if force else 0.0])

    def start_mission(self, first_seq: int = 0) -> None:
        self.command_ok(m2.MAV_CMD_MISSION_START, [float(first_seq), 0.0])

    def land(self) -> None:
        # NaN lat/lon/alt: land where the vehicle is (MAV_CMD_NAV_LAND's "use current position")
        self.command_ok(m2.MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, math.nan, math.nan, math.nan, math.nan])

    def hold(self) -> None:
        self.set_mode(PX4_MAIN_AUTO, PX4_SUB_LOITER)

    def set_mode(self, main: int, sub: int = 0) -> None:
        """DO_SET_MODE with PX4's custom-mode numbers (what this vehicle takes)."""
        self.command_ok(m2.MAV_CMD_DO_SET_MODE,
                        [float(m2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)])  # fmt: skip

    def home(self, timeout_s: float = 3.0) -> GeoPoint:
        """The vehicle's HOME_POSITION (asked for with MAV_CMD_REQUEST_MESSAGE)."""
        self.flush()
        m = self.latest.get("HOME_POSITION")
        if m is None:
            self.command_ok(m2.MAV_CMD_REQUEST_MESSAGE, [float(m2.MAVLINK_MSG_ID_HOME_POSITION)])
            m = self.recv_match(lambda x: x.get_type() == "HOME_POSITION" and self.from_vehicle(x),
                                timeout_s)  # fmt: skip
            if m is None:
                raise LinkTimeoutError("no HOME_POSITION")
        return GeoPoint(m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1e3)

    # ----------------------------------------------------------------- missions

    def _mission_msg(self, m: Message, kinds: tuple[str, ...], mission_type: int) -> bool:
        return bool(
            m.get_type() in kinds and self.from_vehicle(m) and self._for_me(m)
            and getattr(m, "mission_type", 0) == mission_type
        )  # fmt: skip

    def _item_or_ack(self, seq: int, mission_type: int, m: Message) -> bool:
        if self._mission_msg(m, ("MISSION_ITEM_INT",), mission_type):
            return bool(m.seq == seq)
        return self._mission_msg(m, ("MISSION_ACK",), mission_type)

    def upload_mission(
        self,
        items: Sequence[MissionItem],
        *,
        timeout_s: float = 1.5,
        retries: int = 5,
        mission_type: int = m2.MAV_MISSION_TYPE_MISSION,
        on_item: Callable[[int, int], None] | None = None,
    ) -> None:
        """Upload ``items`` (renumbered 0..n-1); raises MissionRefusedError with the vehicle's code.

        ``timeout_s`` is how long the vehicle may stay silent before a retry: the vehicle
        itself re-requests a missing item after 250 ms, so 1.5 s leaves it room for its own
        retries; ``on_item(seq, count)`` reports progress.
        """
        todo = [replace(it, seq=i, mission_type=mission_type) for i, it in enumerate(items)]
        n = len(todo)
        count = m2.MAVLink_mission_count_message(self.target_system, self.target_component, n, mission_type)
        self.flush()
        t0 = time.monotonic()
        self.send(count)
        requested = False
        silent = 0
        sent_up_to = -1
        kinds = ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")
        while True:
            m = self.recv_match(lambda x: self._mission_msg(x, kinds, mission_type), timeout_s)
            if m is None:
                silent += 1
                if silent > retries:
                    self.send(m2.MAVLink_mission_ack_message(
                        self.target_system, self.target_component,
                        m2.MAV_MISSION_OPERATION_CANCELLED, mission_type))  # fmt: skip
                    raise LinkTimeoutError(f"mission upload: the vehicle stopped asking for items "
                                      f"({sent_up_to + 1} of {n} sent)")  # fmt: skip
                if not requested:
                    self.send(count)  # our MISSION_COUNT (or its first request) was lost
                continue
            silent = 0
            if m.get_type() == "MISSION_ACK":
                if m.type == m2.MAV_MISSION_ACCEPTED and (requested or n == 0):
                    return
                if m.type == m2.MAV_MISSION_ACCEPTED:
                    continue  # a stale ACK of an earlier upload
                self.poll(0.05)
                why = self._texts_since(t0)
                at = f" at item {sent_up_to}" if sent_up_to >= 0 else ""
                raise _mission_error(f"mission upload refused{at}", int(m.type), why)
            seq = int(m.seq)
            if not 0 <= seq < n:
                raise MissionRefusedError(f"mission upload: the vehicle asked for item {seq} of {n}",
                                    m2.MAV_MISSION_INVALID_SEQUENCE)  # fmt: skip
            requested = True
            self.send(todo[seq].to_message(self.target_system, self.target_component))
            sent_up_to = max(sent_up_to, seq)
            if on_item is not None:
                on_item(seq, n)

    def download_mission(
        self, *, timeout_s: float = 1.0, retries: int = 5, mission_type: int = m2.MAV_MISSION_TYPE_MISSION
    ) -> list[MissionItem]:
        """The vehicle's stored mission (MISSION_REQUEST_LIST, then each item)."""
        self.flush()
        req_list = m2.MAVLink_mission_request_list_message(self.target_system, self.target_component,
                                                           mission_type)  # fmt: skip
        count_msg = None
        for _ in range(retries + 1):
            self.send(req_list)
            count_msg = self.recv_match(
                lambda x: self._mission_msg(x, ("MISSION_COUNT", "MISSION_ACK"), mission_type), timeout_s)
            if count_msg is not None:
                break
        if count_msg is None:
            raise LinkTimeoutError("mission download: no MISSION_COUNT")
        if count_msg.get_type() == "MISSION_ACK":
            code = int(count_msg.type)
            raise _mission_error("mission download refused", code)
        items: list[MissionItem] = []
        for seq in range(int(count_msg.count)):
            req = m2.MAVLink_mission_request_int_message(self.target_system, self.target_component, seq,
                                                         mission_type)  # fmt: skip
            got = None
            for _ in range(retries + 1):
                self.send(req)
                got = self.recv_match(functools.partial(self._item_or_ack, seq, mission_type), timeout_s)
                if got is not None:
                    break
            if got is None:
                raise LinkTimeoutError(f"mission download: item {seq} never came")
            if got.get_type() == "MISSION_ACK":
                code = int(got.type)
                raise _mission_error(f"mission download: item {seq}", code)
            items.append(MissionItem.from_message(got))
        self.send(m2.MAVLink_mission_ack_message(self.target_system, self.target_component,
                                                 m2.MAV_MISSION_ACCEPTED, mission_type))  # fmt: skip
        return items

    def clear_mission(
        self, *, timeout_s: float = 1.0, retries: int = 3, mission_type: int = m2.MAV_MISSION_TYPE_MISSION
    ) -> None:
        self.flush()
        msg = m2.MAVLink_mission_clear_all_message(self.target_system, self.target_component, mission_type)
        for _ in range(retries + 1):
            self.send(msg)
            ack = self.recv_match(lambda x: self._mission_msg(x, ("MISSION_ACK",), mission_type), timeout_s)
            if ack is None:
                continue
            if ack.type != m2.MAV_MISSION_ACCEPTED:
                raise _mission_error("mission clear refused", int(ack.type))
            return
        raise LinkTimeoutError("mission clear: no MISSION_ACK")

    # ----------------------------------------------------------------- mission progress

    def follow_mission(
        self,
        n_items: int,
        *,
        duration_s: float | None = None,
        timeout_s: float = 600.0,
        on_update: Callable[[MissionProgress], None] | None = None,
    ) -> MissionProgress:
        """Follow a started mission until it ends; returns what was seen.

        It ends when every item was reached (MISSION_ITEM_REACHED of the last seq), when the
        heartbeat shows the vehicle left mission mode after being in it (the end of a timed
        trajectory, a waypoint mission whose last report was lost, a mode change by another
        GCS), or when the vehicle disarms. Raises LinkTimeoutError after ``timeout_s``.
        """
        prog = MissionProgress(n_items, duration_s)
        seen_mission_mode = False
        deadline = time.monotonic() + timeout_s
        self._queue.clear()
        while not prog.finished:
            if time.monotonic() > deadline:
                raise LinkTimeoutError(f"mission not finished after {timeout_s:g} s "
                                  f"({len(prog.reached)} of {n_items} items reached)")  # fmt: skip
            for m in self.poll(0.2):
                if not self.from_vehicle(m):
                    continue
                kind = m.get_type()
                if kind in ("ATTITUDE", "LOCAL_POSITION_NED"):
                    t = m.time_boot_ms / 1e3
                    if prog.start_s is None:
                        prog.start_s = t
                    prog.elapsed_s = max(prog.elapsed_s, t - prog.start_s)
                elif kind == "MISSION_ITEM_REACHED":
                    prog.reached.setdefault(int(m.seq), self.vehicle_time_s() or 0.0)
                    if int(m.seq) >= n_items - 1:
                        prog.finished, prog.reason = True, "all items reached"
                elif kind == "MISSION_CURRENT":
                    prog.current_seq = int(m.seq)
                elif kind == "HEARTBEAT" and m.type != m2.MAV_TYPE_GCS:
                    main, sub = px4_mode(int(m.custom_mode))
                    in_mission = (main, sub) == (PX4_MAIN_AUTO, PX4_SUB_MISSION)
                    seen_mission_mode |= in_mission
                    if not m.base_mode & m2.MAV_MODE_FLAG_SAFETY_ARMED:
                        prog.finished, prog.reason = True, "disarmed"
                    elif not in_mission and (seen_mission_mode or prog.elapsed_s > 2.5):
                        now = wm.BY_CUSTOM.get(wm.custom_mode(main, sub))
                        prog.finished = True
                        left_for = now.name if now else "another mode"
                        prog.reason = f"the vehicle left MISSION mode for {left_for}: the mission is over"
            if on_update is not None:
                on_update(prog)
        return prog

    def landed_state(self) -> int | None:
        m = self.latest.get("EXTENDED_SYS_STATE")
        return int(m.landed_state) if m is not None else None

    def armed(self) -> bool | None:
        hb = self.latest.get("HEARTBEAT")
        if hb is None or not self.from_vehicle(hb):
            return None
        return bool(hb.base_mode & m2.MAV_MODE_FLAG_SAFETY_ARMED)

    def wait_landed(self, timeout_s: float = 120.0) -> None:
        """Until EXTENDED_SYS_STATE says on the ground (or the vehicle disarmed itself)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for m in self.poll(0.2):
                if not self.from_vehicle(m):
                    continue
                if m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == m2.MAV_LANDED_STATE_ON_GROUND:
                    return
                if m.get_type() == "HEARTBEAT" and not m.base_mode & m2.MAV_MODE_FLAG_SAFETY_ARMED:
                    return
        raise LinkTimeoutError(f"not on the ground after {timeout_s:g} s")

    # ----------------------------------------------------------------- parameters

    def _decode_param(self, m: Message) -> ParamValue:
        # C cast: what this vehicle advertises (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
        value = decode_param(float(m.param_value), int(m.param_type), bytewise=False)
        name = _param_name(m.param_id)
        self._param_types[name] = int(m.param_type)
        return ParamValue(name, value, int(m.param_type), int(m.param_index), int(m.param_count))

    def _encode_param(self, value: float, param_type: int) -> float:
        try:
            return encode_param(value, param_type, bytewise=False)
        except ValueError as exc:
            raise ParamError(str(exc)) from exc

    def _param_answer(self, name: str, timeout_s: float, t0: float) -> Message | None:
        """PARAM_VALUE for ``name``; None on timeout; ParamError if the vehicle says unknown."""
        def pred(m: Message) -> bool:
            if not self.from_vehicle(m):
                return False
            if m.get_type() == "PARAM_VALUE":
                return _param_name(m.param_id) == name
            return m.get_type() == "STATUSTEXT" and name in str(m.text) and "nknown" in str(m.text)

        got = self.recv_match(pred, timeout_s)
        if got is not None and got.get_type() == "STATUSTEXT":
            raise ParamError(f"{name}: {got.text}")
        return got

    def param_get(self, name: str, *, timeout_s: float = 1.0, retries: int = 3) -> ParamValue:
        self.flush()
        t0 = time.monotonic()
        for _ in range(retries + 1):
            self.send(m2.MAVLink_param_request_read_message(self.target_system, self.target_component,
                                                            name.encode("ascii"), -1))  # fmt: skip
            got = self._param_answer(name, timeout_s, t0)
            if got is not None:
                return self._decode_param(got)
        raise ParamError(f"{name}: no PARAM_VALUE after {retries + 1} tries (unknown parameter?)")

    def param_set(
        self, name: str, value: float, *, timeout_s: float = 1.0, retries: int = 3
    ) -> ParamSetResult:
        """PARAM_SET; the vehicle echoes the value it holds afterwards (unchanged if refused)."""
        ptype = self._param_types.get(name)
        if ptype is None:
            ptype = self.param_get(name, timeout_s=timeout_s, retries=retries).param_type
        wire = self._encode_param(value, ptype)
        self.flush()
        t0 = time.monotonic()
        for _ in range(retries + 1):
            self.send(m2.MAVLink_param_set_message(self.target_system, self.target_component,
                                                   name.encode("ascii"), wire, ptype))  # fmt: skip
            got = self._param_answer(name, timeout_s, t0)
            if got is None:
                continue
            pv = self._decode_param(got)
            # both sides see float32 on the wire (an INT32 arrives exactly)
            accepted = pv.value == value if ptype == m2.MAV_PARAM_TYPE_INT32 else f32(pv.value) == f32(value)
            self.poll(0.05)  # a refusal's STATUSTEXT follows the PARAM_VALUE
            reason = "" if accepted else self._texts_since(t0)
            return ParamSetResult(accepted, pv, reason)
        raise ParamError(f"{name}: no PARAM_VALUE after {retries + 1} tries")

    def param_list(
        self, *, timeout_s: float = 1.0, retries: int = 5, batch: int = 10
    ) -> dict[str, ParamValue]:
        """Every parameter, in index order; missing indices are re-requested one by one."""
        self.flush()
        by_index: dict[int, ParamValue] = {}
        count: int | None = None
        self.send(m2.MAVLink_param_request_list_message(self.target_system, self.target_component))
        quiet = 0  # consecutive quiet periods without a new parameter
        while count is None or len(by_index) < count:
            got = self.recv_match(lambda m: m.get_type() == "PARAM_VALUE" and self.from_vehicle(m),
                                  timeout_s)  # fmt: skip
            if got is not None:
                pv = self._decode_param(got)
                count = pv.count
                if 0 <= pv.index < pv.count and pv.index not in by_index:
                    by_index[pv.index] = pv
                    quiet = 0
                continue
            quiet += 1  # the stream went quiet with gaps: ask for the missing ones
            if quiet > retries:
                total = "?" if count is None else str(count)
                raise LinkTimeoutError(f"parameter list incomplete: {len(by_index)} of {total}")
            if count is None:
                self.send(m2.MAVLink_param_request_list_message(self.target_system, self.target_component))
                continue
            missing = [i for i in range(count) if i not in by_index][:batch]
            for i in missing:
                self.send(m2.MAVLink_param_request_read_message(self.target_system, self.target_component,
                                                                b"", i))  # fmt: skip
        return {pv.name: pv for _, pv in sorted(by_index.items())}


def _mission_error(what: str, code: int, why: str = "") -> MissionRefusedError:
    text = f"{what}: {enum_name('MAV_MISSION_RESULT', code)}" + (f" ({why})" if why else "")
    return MissionRefusedError(text, code)


def _param_name(param_id: str | bytes) -> str:
    raw = param_id.encode("latin-1") if isinstance(param_id, str) else bytes(param_id)
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")
