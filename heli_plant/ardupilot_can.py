"""ArduPilot's servo outputs taken from DroneCAN (``heli-sitl up --firmware ardupilot --servo-link can``).

ArduPilot's CAN-enabled SITL firmware, with ``configs/ardupilot/can-servos.parm``, sends its
servo outputs as ``uavcan.equipment.actuator.ArrayCommand`` (1010) on its CAN bus 1, which
SITL carries on DroneCAN's UDP multicast (``mcast:0``, 239.65.82.0:57732): one transfer
with a command for each channel of ``CAN_D1_UC_SRV_BM`` (actuator id = the servo channel
number: 1-3 the swashplate, 4 the tail, 8 HeliRSC), ``command_type`` 0 (unitless), the value
in [-1, 1] the channel's PWM mapped 1000 -> -1, 2000 -> +1 (``(pulse - 1000) / 500 - 1``,
clipped: the PWM already holds the channel's SERVOn_MIN/TRIM/MAX; the bench sets those to
1000/1500/2000 us, so -1, 0, +1 are also MIN, TRIM, MAX). :class:`ArduPilotCanServos`
is the servos' end of that bus:

* ``poll(now_s)`` drains the bus, reassembles and checks each transfer
  (:class:`~heli_common.wire.can.dronecan_codec.Reassembler`), and for each ArrayCommand from
  the firmware's node turns every command for one of :data:`CHANNELS` back into the PWM the
  firmware meant (:func:`pwm_from_unitless`, rounded to the microsecond: the firmware's
  pulse is an integer, and the float16 value resolves 0.25 us); the PWMs of the newest
  command are held until the next (a servo holds its last command). A command of another
  type, or out of [-1, 1], or non-finite, refuses the whole transfer (counted, the previous
  PWMs stay held); other actuator ids are ignored (counted).
* :meth:`pwm_us` gives those PWMs, None before the first command; ``silent(now_s)`` is True
  after ``timeout_s`` of physics time without one (each entry counted).
* The servos are a DroneCAN node (``node_id`` 20 by default): NodeStatus at 1 Hz of physics
  time, always HEALTH_OK / MODE_OPERATIONAL (the firmware refuses to arm while any node on its
  bus is not), and answers GetNodeInfo (name ``org.heli-tlc-sitl.servos``). ``node_id`` None:
  a silent listener.
* Every transfer type seen is counted by data type id in ``stats.types`` (what the firmware
  sends, measured: docs/can.md, "ArduPilot on the bus").

Times come in as ``now_s`` (the plant's physics time); only :meth:`ArduPilotCanServos.wait_for_command`
reads the monotonic clock, to bound how long it blocks (the backend's pacing,
:mod:`heli_plant.ardupilot_backend`).
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from heli_common.closing import Closing
from heli_common.vehicle.swashplate import read_parm
from heli_common.wire.can.bus import CanBus, CanBusConfig, CanBusError, CanSendError, open_bus
from heli_common.wire.can.dronecan_codec import (
    ARMING_STATUS_DTID,
    ARRAY_COMMAND_DTID,
    HEALTH_OK,
    MODE_OPERATIONAL,
    NODE_STATUS_DTID,
    CanFrame,
    DropReason,
    NodeStatusEncoder,
    Reassembler,
    array_command_entries,
    check_node_id,
    parse_can_id,
)
from heli_common.wire.can.node import (
    NodeIdentity,
    NodeInfoResponder,
    frame_source,
    get_node_info_request,
    project_version,
)

log = logging.getLogger(__name__)

CHANNELS = (1, 2, 3, 4, 8)  # SERVO1-3 the swashplate, SERVO4 the tail, SERVO8 HeliRSC
COMMAND_TYPE_UNITLESS = 0
ARDUPILOT_NODE_ID = 10  # CAN_D1_UC_NODE's default
DEFAULT_NODE_ID = 20
SERVOS_NODE_NAME = "org.heli-tlc-sitl.servos"
NODE_STATUS_PERIOD_S = 1.0
GAP_LOG_S = 0.05  # gaps between commands longer than this [s of physics] are listed in the stats
MAX_GAPS_LOGGED = 200
DEFAULT_TIMEOUT_S = 0.5  # physics time without a command before the bus counts as silent
# ArduPilot's SERVOn_MIN / TRIM / MAX defaults (SRV_Channel.cpp)
DEFAULT_MIN_US, DEFAULT_TRIM_US, DEFAULT_MAX_US = 1100.0, 1500.0, 1900.0


def pwm_from_unitless(value: float) -> float:
    """The PWM [us] a unitless command stands for, inverting the firmware's own
    ``command_value = constrain((pulse - 1000) / 500 - 1, -1, 1)`` (``AP_DroneCAN::SRV_send_actuator``):
    1000 us at -1, 2000 us at +1, whatever the channel's SERVOn_MIN/TRIM/MAX."""
    return 1500.0 + 500.0 * value


@dataclass(frozen=True)
class ServoRange:
    """One channel's SERVOn_MIN / TRIM / MAX [us], as the firmware is configured."""

    min_us: float = DEFAULT_MIN_US
    trim_us: float = DEFAULT_TRIM_US
    max_us: float = DEFAULT_MAX_US

    def __post_init__(self) -> None:
        if not self.min_us <= self.trim_us <= self.max_us or self.min_us == self.max_us:
            raise ValueError(f"SERVO range {self} is not MIN <= TRIM <= MAX")

    def pwm_from_norm(self, value: float) -> float:
        """The PWM the firmware meant by ``value``: :func:`pwm_from_unitless`, which is
        this channel's MIN / TRIM / MAX mapping (-1, 0, +1) when those are 1000 / 1500 /
        2000 us, as the bench configures SERVO1-4 and 8 (:meth:`matches_unitless`)."""
        return pwm_from_unitless(value)

    def matches_unitless(self) -> bool:
        """MIN / TRIM / MAX are 1000 / 1500 / 2000 us: [-1, 1] covers the travel exactly."""
        return (self.min_us, self.trim_us, self.max_us) == (1000.0, 1500.0, 2000.0)


def servo_ranges(
    parm_files: Iterable[str | Path], channels: Sequence[int] = CHANNELS
) -> dict[int, ServoRange]:
    """SERVOn_MIN / TRIM / MAX of ``channels`` from ArduPilot parameter files loaded in this
    order (a later file wins), ArduPilot's defaults where none sets them."""
    params: dict[str, float] = {}
    for f in parm_files:
        params.update(read_parm(f))
    out = {}
    for ch in channels:
        out[ch] = ServoRange(params.get(f"SERVO{ch}_MIN", DEFAULT_MIN_US),
                             params.get(f"SERVO{ch}_TRIM", DEFAULT_TRIM_US),
                             params.get(f"SERVO{ch}_MAX", DEFAULT_MAX_US))  # fmt: skip
        if not out[ch].matches_unitless():  # the firmware clips its pulse to 1000-2000 on the bus
            log.warning("SERVO%d MIN/TRIM/MAX %s are not 1000/1500/2000 us: the firmware's unitless "
                        "command covers 1000-2000 us only", ch, out[ch])  # fmt: skip
    return out


STAT_KEYS = (
    "frames_rx",
    "transfers_rx",  # checked ArrayCommand / NodeStatus / ArmingStatus transfers
    "commands_applied",  # ArrayCommands whose PWMs are now held
    "foreign_source",  # ArrayCommand from another node than the firmware's
    "wrong_command_type",
    "out_of_range",  # a value outside [-1, 1] or not finite
    "missing_channel",  # a transfer without a command for one of CHANNELS
    "unknown_actuator",  # commands for other actuator ids (ignored)
    "timeouts",  # entries into silence
    "bus_errors",
    *(r.value for r in DropReason),
)


@dataclass
class CanServoStats:
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STAT_KEYS, 0))
    types: Counter[int] = field(default_factory=Counter)  # transfers by data type id (any node)
    actuator_ids: set[int] = field(default_factory=set)
    command_types: set[int] = field(default_factory=set)
    first_command_s: float | None = None
    last_command_s: float | None = None
    max_gap_s: float = 0.0  # the longest physics time between two applied commands
    node_status_sent: int = 0
    node_info_answered: int = 0
    send_errors: int = 0
    waits: int = 0  # wait_for_command calls (the plant waiting for a fresh command)
    wait_s: float = 0.0  # wall time spent in them
    wait_timeouts: int = 0
    gaps: list[tuple[float, float]] = field(default_factory=list)  # (physics time, gap) over GAP_LOG_S

    def as_dict(self) -> dict[str, object]:
        span = (None if self.first_command_s is None or self.last_command_s is None
                else self.last_command_s - self.first_command_s)  # fmt: skip
        rate = None if not span else (self.counts["commands_applied"] - 1) / span
        return {**self.counts, "types": {str(k): v for k, v in sorted(self.types.items())},
                "actuator_ids": sorted(self.actuator_ids), "command_types": sorted(self.command_types),
                "first_command_s": self.first_command_s, "last_command_s": self.last_command_s,
                "command_rate_hz": rate, "max_gap_s": self.max_gap_s,
                "node_status_sent": self.node_status_sent, "node_info_answered": self.node_info_answered,
                "send_errors": self.send_errors, "waits": self.waits, "wait_s": self.wait_s,
                "wait_timeouts": self.wait_timeouts, "gaps": self.gaps}  # fmt: skip


class ArduPilotCanServos(Closing):
    """The plant's servos on ArduPilot's DroneCAN bus (see the module doc).

    ``bus``: a spec (``mcast:0``), a config or an open :class:`CanBus` (left to its owner);
    ``ranges``: SERVOn_MIN / TRIM / MAX by channel (:func:`servo_ranges`)."""

    def __init__(
        self,
        bus: CanBus | CanBusConfig | str,
        ranges: Mapping[int, ServoRange],
        *,
        source_node_id: int | None = ARDUPILOT_NODE_ID,
        node_id: int | None = DEFAULT_NODE_ID,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        max_frames_per_poll: int = 2000,
    ) -> None:
        missing = [ch for ch in CHANNELS if ch not in ranges]
        if missing:
            raise ValueError(f"no SERVO range for channels {missing}")
        if not (math.isfinite(timeout_s) and timeout_s > 0.0):
            raise ValueError(f"timeout_s must be a positive number, got {timeout_s}")
        self.ranges = dict(ranges)
        self.source_node_id = None if source_node_id is None else check_node_id(source_node_id)
        self.node_id = None if node_id is None else check_node_id(node_id)
        if self.node_id is not None and self.node_id == self.source_node_id:
            raise ValueError(f"the servos' node id {node_id} is the firmware's")
        self.timeout_s = float(timeout_s)
        self.max_frames_per_poll = max_frames_per_poll
        self.stats = CanServoStats()
        self._held: dict[int, int] | None = None
        self._silent = False
        self._first_poll_s: float | None = None
        self._next_status_s: float | None = None
        self._reassembler = Reassembler(
            (ARRAY_COMMAND_DTID, NODE_STATUS_DTID, ARMING_STATUS_DTID), self._on_drop
        )
        if self.node_id is not None:
            self._node_status = NodeStatusEncoder(self.node_id)
            self._node_info = NodeInfoResponder(
                self.node_id, NodeIdentity(SERVOS_NODE_NAME, project_version())
            )
        self._owns_bus = not isinstance(bus, CanBus)
        self.bus = bus if isinstance(bus, CanBus) else open_bus(bus)

    def close(self) -> None:
        if self._owns_bus:
            self.bus.close()

    # ------------------------------------------------------------------------------ API
    def pwm_us(self) -> dict[int, int] | None:
        """The PWM [us] of each of :data:`CHANNELS` the newest command meant (None before one)."""
        return None if self._held is None else dict(self._held)

    def silent(self, now_s: float) -> bool:
        ref = self.stats.last_command_s if self.stats.last_command_s is not None else self._first_poll_s
        return ref is not None and now_s - ref > self.timeout_s

    def poll(self, now_s: float) -> dict[int, int] | None:
        """Read every frame waiting (at most ``max_frames_per_poll``), apply the commands,
        send the node's status when due; return :meth:`pwm_us`."""
        if self._first_poll_s is None:
            self._first_poll_s = now_s
        for _ in range(self.max_frames_per_poll):
            if self._read_one(now_s, 0.0) is None:
                break
        silent = self.silent(now_s)
        if silent and not self._silent:
            self.stats.counts["timeouts"] += 1
            log.warning("ArduPilot CAN servos: no command for %.3f s of physics time; holding %s",
                        self.timeout_s, self._held)  # fmt: skip
        self._silent = silent
        if self.node_id is not None and (self._next_status_s is None or now_s >= self._next_status_s):
            frames = self._node_status.encode(self._uptime_s(now_s), health=HEALTH_OK, mode=MODE_OPERATIONAL)
            if self._send(frames, "NodeStatus"):
                self.stats.node_status_sent += 1
            nxt = (self._next_status_s if self._next_status_s is not None else now_s) + NODE_STATUS_PERIOD_S
            self._next_status_s = nxt if nxt > now_s else now_s + NODE_STATUS_PERIOD_S
        return self.pwm_us()

    def wait_for_command(self, now_s: float, wall_timeout_s: float) -> bool:
        """Block (at most ``wall_timeout_s`` of wall time, the only clock read here) until a
        new command is applied; True if one was. Counted in ``stats`` (``waits``,
        ``wait_s``, ``wait_timeouts``)."""
        applied = self.stats.counts["commands_applied"]
        start = time.monotonic()
        deadline = start + wall_timeout_s
        self.stats.waits += 1
        for _ in range(100_000):  # frames read while waiting: bounded as well as timed
            left = deadline - time.monotonic()
            if left <= 0.0 or self.stats.counts["commands_applied"] != applied:
                break
            self._read_one(now_s, left)
        self.stats.wait_s += time.monotonic() - start
        got = self.stats.counts["commands_applied"] != applied
        self.stats.wait_timeouts += not got
        return got

    def _read_one(self, now_s: float, timeout_s: float) -> bool | None:
        """Read and handle one frame (waiting up to ``timeout_s``); None when none came."""
        try:
            msg = self.bus.recv(timeout_s)
        except CanBusError as exc:
            self.stats.counts["bus_errors"] += 1
            log.warning("ArduPilot CAN servos: receive failed (%s)", exc)
            return None
        if msg is None:
            return None
        self.stats.counts["frames_rx"] += 1
        if msg.is_extended_id:
            can_id = msg.arbitration_id
            if self.node_id is not None:
                if frame_source(can_id) == self.node_id:
                    return True
                req = get_node_info_request(can_id, bytes(msg.data), self.node_id)
                if req is not None:
                    frames = self._node_info.respond(req, self._uptime_s(now_s))
                    if self._send(frames, "GetNodeInfo response"):
                        self.stats.node_info_answered += 1
                    return True
            self._count_type(can_id, bytes(msg.data))
        tr = self._reassembler.feed_message(msg)
        if tr is not None:
            self.stats.counts["transfers_rx"] += 1
            if tr.data_type_id == ARRAY_COMMAND_DTID:
                self._apply(tr.source_node_id, array_command_entries(tr.payload), now_s)
        return True

    # ------------------------------------------------------------------------ internals
    def _count_type(self, can_id: int, data: bytes) -> None:
        """Count each transfer (its start frame) by data type id; services as -id."""
        if not data or not data[-1] & 0x80:
            return
        f = parse_can_id(can_id)
        self.stats.types[-f.data_type_id if f.service else f.data_type_id] += 1

    def _uptime_s(self, now_s: float) -> int:
        return int(now_s - (self._first_poll_s if self._first_poll_s is not None else now_s))

    def _send(self, frames: list[CanFrame], what: str) -> bool:
        for fr in frames:
            try:
                self.bus.send(fr.can_id, fr.data)
            except CanSendError as exc:
                self.stats.send_errors += 1
                log.warning("ArduPilot CAN servos: %s not sent (%s)", what, exc)
                return False
        return True

    def _on_drop(self, reason: DropReason, detail: str) -> None:
        self.stats.counts[reason.value] += 1
        if reason is not DropReason.FOREIGN_TYPE:
            log.info("ArduPilot CAN servos: dropped (%s) %s", reason.value, detail)

    def _apply(self, source: int, entries: list[tuple[int, int, float]], now_s: float) -> None:
        c = self.stats.counts
        if self.source_node_id is not None and source != self.source_node_id:
            c["foreign_source"] += 1
            return
        pwm: dict[int, int] = {}
        for aid, ctype, value in entries:
            self.stats.actuator_ids.add(aid)
            self.stats.command_types.add(ctype)
            if aid not in self.ranges or aid not in CHANNELS:
                c["unknown_actuator"] += 1
                continue
            if ctype != COMMAND_TYPE_UNITLESS:
                c["wrong_command_type"] += 1
                return
            if not (math.isfinite(value) and -1.0 <= value <= 1.0):
                c["out_of_range"] += 1
                return
            pwm[aid] = round(self.ranges[aid].pwm_from_norm(value))
        if len(pwm) != len(CHANNELS):
            c["missing_channel"] += 1
            return
        if self.stats.last_command_s is not None:
            gap = now_s - self.stats.last_command_s
            self.stats.max_gap_s = max(self.stats.max_gap_s, gap)
            if gap > GAP_LOG_S and len(self.stats.gaps) < MAX_GAPS_LOGGED:
                self.stats.gaps.append((round(now_s, 4), round(gap, 4)))
        else:
            self.stats.first_command_s = now_s
            log.info("ArduPilot CAN servos: first command at %.3f s: %s", now_s, pwm)
        self.stats.last_command_s = now_s
        self._held = pwm
        c["commands_applied"] += 1
