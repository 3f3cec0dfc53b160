"""DroneCAN (UAVCAN v0) for the servo link: encoding to CAN frames and checked reassembly.

Message types come from the ``dronecan`` package's own DSDL definitions and are
serialised by its transfer code (``dronecan.transport.Transfer``), so the bits on the
bus are what any DroneCAN node (ArduPilot, PX4, the DroneCAN GUI tool) expects:

* ``uavcan.equipment.actuator.ArrayCommand`` (data type id 1010): one
  ``Command(actuator_id, COMMAND_TYPE_POSITION, command_value)`` per servo, the value a
  float16 in radians. Four commands are 16 payload bytes; with the 2-byte transfer CRC
  that is a 3-frame transfer (7 + 7 + 4 bytes plus one tail byte per frame).
* ``uavcan.protocol.NodeStatus`` (341): single frame, sent at 1 Hz by every node.

Actuator ids, by default (override in the link configuration)::

    1 = theta_m (main rotor collective)   2 = theta_t (tail rotor collective)
    3 = eps (longitudinal cyclic)          4 = eta (lateral cyclic)

dronecan 1.0.27's python-can *driver* is not used for sending or receiving: with
python-can >= 4.4 it calls ``bus.flush_tx_buffer()`` after every frame, which raises
NotImplementedError on the ``virtual`` and ``udp_multicast`` buses (its writer thread
dies on the first frame), and it passes the receive timeout in milliseconds to
``bus.recv``, which takes seconds. The links here drive python-can themselves
(:mod:`heli_common.wire.can.bus`) and use only dronecan's DSDL and framing;
:class:`DronecanDriver` is a corrected driver for running dronecan's own ``Node`` on
such a bus (the interoperability test decodes the autopilot's commands that way).

The two per-tick types (ArrayCommand, ArmingStatus) are packed and unpacked here with
precompiled ``struct`` layouts, float16 conversion that reproduces libuavcan's rounding bit
for bit, and the transfer CRC from ``binascii.crc_hqx`` (CRC-16-CCITT, seeded with the data
type's signature CRC): no DSDL object is built per tick. The tests check every byte
against dronecan's own serialisation, both ways. NodeStatus (1 Hz) goes through dronecan.

The receiving side does its own reassembly (:class:`Reassembler`) rather than
dronecan's ``TransferManager``: that one reads the wall clock, keys sessions by transfer
id so a lost end frame leaves a session behind, and cannot say *why* a transfer was
lost. This one checks the tail byte (start, end, toggle, transfer id), the transfer CRC
and the payload size, counts every drop by reason, and hands the checked frames to
dronecan's ``Transfer.from_frames`` for decoding.
"""

from __future__ import annotations

import binascii
import enum
import math
import struct
import time
from collections import Counter
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import can
import dronecan
from dronecan import transport
from dronecan.driver.common import AbstractDriver, CANFrame

from heli_common.wire.can.bus import CanBus

ARRAY_COMMAND: Any = dronecan.uavcan.equipment.actuator.ArrayCommand
ACTUATOR_COMMAND: Any = dronecan.uavcan.equipment.actuator.Command
NODE_STATUS: Any = dronecan.uavcan.protocol.NodeStatus
ARMING_STATUS: Any = dronecan.uavcan.equipment.safety.ArmingStatus

ARRAY_COMMAND_DTID = 1010
NODE_STATUS_DTID = 341
ARMING_STATUS_DTID = 1100
ARMING_STATUS_DISARMED, ARMING_STATUS_FULL = 0, 255  # ArmingStatus.STATUS_*
COMMAND_TYPE_POSITION = 1  # Command.COMMAND_TYPE_POSITION: metre or radian
MAX_COMMANDS_PER_ARRAY = 15  # Command[<=15]

HEALTH_OK, HEALTH_WARNING, HEALTH_ERROR, HEALTH_CRITICAL = 0, 1, 2, 3
MODE_OPERATIONAL, MODE_INITIALIZATION = 0, 1

#: theta_m, theta_t, eps, eta (heli_common.state.PITCH_NAMES order)
DEFAULT_ACTUATOR_IDS: tuple[int, int, int, int] = (1, 2, 3, 4)
#: 0 is the highest priority, 31 the lowest. Servo commands are time-critical; NodeStatus
#: is housekeeping and must not delay them.
PRIORITY_ARRAY_COMMAND = 8
PRIORITY_NODE_STATUS = 24
PRIORITY_ARMING_STATUS = 16  # before the commands it qualifies, after time-critical ones

#: float16 keeps 11 significant bits: rounding moves a value by at most half a unit in the
#: last place, 2**-11 relative (~1.2e-4 rad at 0.25..0.5 rad), 2**-25 absolute near zero.
FLOAT16_REL_ERR = 2.0**-11
FLOAT16_ABS_ERR = 2.0**-25
FLOAT16_MAX = 65504.0

assert ARRAY_COMMAND.default_dtid == ARRAY_COMMAND_DTID
assert NODE_STATUS.default_dtid == NODE_STATUS_DTID
assert ARMING_STATUS.default_dtid == ARMING_STATUS_DTID


@dataclass(frozen=True)
class CanFrame:
    """One CAN 2.0 frame with a 29-bit identifier, as DroneCAN uses."""

    can_id: int
    data: bytes


def check_node_id(node_id: int) -> int:
    if not 1 <= node_id <= 127:
        raise ValueError(f"DroneCAN node id must be in 1..127, got {node_id}")
    return node_id


def check_actuator_ids(ids: Sequence[int], n: int = 4) -> tuple[int, ...]:
    out = tuple(int(i) for i in ids)
    if len(out) != n:
        raise ValueError(f"need {n} actuator ids (theta_m, theta_t, eps, eta), got {len(out)}")
    if len(set(out)) != n:
        raise ValueError(f"actuator ids must be distinct, got {out}")
    if not all(0 <= i <= 255 for i in out):
        raise ValueError(f"actuator ids must be in 0..255, got {out}")
    return out


_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")
_F16 = struct.Struct("<e")
_F32_INF_BITS = 0x7F800000
_F16_INF_AS_F32_BITS = 31 << 23


def float16_bits(value: float) -> int:
    """The float16 bit pattern dronecan puts on the wire for ``value``: saturated to
    +-65504 (the DSDL ``saturated float16`` cast; NaN passes), then libuavcan's float32 ->
    float16 conversion (round to nearest, ties away from zero; NaN -> 0x7FFF with sign)."""
    if value > FLOAT16_MAX:
        value = FLOAT16_MAX
    elif value < -FLOAT16_MAX:
        value = -FLOAT16_MAX
    u = _U32.unpack(_F32.pack(value))[0]
    sign = u & 0x80000000
    u ^= sign
    if u >= _F32_INF_BITS:
        out = 0x7FFF if u > _F32_INF_BITS else 0x7C00
    else:
        # keep the rounding bit, scale the exponent by 2**-112 in float32, add the rounding bit
        f = _F32.unpack(_U32.pack(u & 0xFFFFF000))[0] * 2.0**-112
        u = _U32.unpack(_F32.pack(f))[0] + 0x1000
        out = (min(u, _F16_INF_AS_F32_BITS) >> 13) & 0xFFFF
    return int(out | (sign >> 16))


def float16_value(bits: int) -> float:
    """The value of a float16 bit pattern (exact; inf and NaN survive)."""
    return float(_F16.unpack(bits.to_bytes(2, "little"))[0])


def float16_round(value: float) -> float:
    """``value`` as it arrives after a trip through a DroneCAN float16 (dronecan's rounding)."""
    return float16_value(float16_bits(float(value)))


def float16_tolerance(value: float) -> float:
    """Bound on ``|float16_round(value) - value|`` for a finite value within float16 range
    (float16 rounding plus the float32 rounding dronecan does first)."""
    return abs(value) * (FLOAT16_REL_ERR + 2.0**-24) + FLOAT16_ABS_ERR


def _to_frames(transfer: Any) -> list[CanFrame]:
    return [CanFrame(int(f.message_id), bytes(f.bytes)) for f in transfer.to_frames()]


def message_can_id(priority: int, data_type_id: int, source_node_id: int) -> int:
    """The 29-bit identifier of a DroneCAN message frame."""
    return (priority << 24) | (data_type_id << 8) | source_node_id


def transfer_crc(payload: bytes, base_crc: int) -> int:
    """DroneCAN's multi-frame transfer CRC: CRC-16-CCITT of the payload, seeded with the
    data type's signature CRC (what dronecan's ``crc16_from_bytes`` computes, in C)."""
    return binascii.crc_hqx(payload, base_crc)


def frames_of_transfer(can_id: int, payload: bytes, transfer_id: int, base_crc: int) -> list[CanFrame]:
    """Split one message transfer into CAN frames: a single frame up to 7 bytes, else the
    transfer CRC first and 7 bytes per frame, each with its tail byte (start, end, toggle,
    transfer id)."""
    if len(payload) <= 7:
        return [CanFrame(can_id, payload + bytes((0xC0 | transfer_id,)))]
    crc = transfer_crc(payload, base_crc)
    buf = bytes((crc & 0xFF, crc >> 8)) + payload
    n = (len(buf) + 6) // 7
    frames = []
    for i in range(n):
        tail = ((i & 1) << 5) | transfer_id
        if i == 0:
            tail |= 0x80
        if i == n - 1:
            tail |= 0x40
        frames.append(CanFrame(can_id, buf[7 * i : 7 * i + 7] + bytes((tail,))))
    return frames


class _Broadcaster:
    """One message type broadcast by one node: its identifier, and the transfer id counting
    0..31, as DroneCAN requires per data type."""

    def __init__(self, node_id: int, message: Any, priority: int) -> None:
        self.node_id = check_node_id(node_id)
        self.priority = priority
        self.transfer_id = 0
        self._msg: Any = message
        self._can_id = message_can_id(priority, int(message._type.default_dtid), self.node_id)
        self._base_crc = int(message._type.base_crc)

    def _next_tid(self) -> int:
        tid = self.transfer_id
        self.transfer_id = (tid + 1) & 0x1F
        return tid

    def _frames(self) -> list[CanFrame]:
        """The frames of the DSDL object, serialised by dronecan (for the rare messages)."""
        tr = transport.Transfer(
            transfer_id=self._next_tid(),
            source_node_id=self.node_id,
            payload=self._msg,
            transfer_priority=self.priority,
        )
        return _to_frames(tr)

    def _frames_of(self, payload: bytes) -> list[CanFrame]:
        """The frames of an already packed payload (the per-tick messages)."""
        return frames_of_transfer(self._can_id, payload, self._next_tid(), self._base_crc)


class ArrayCommandEncoder(_Broadcaster):
    """Encodes pitch vectors as ArrayCommand transfers from one node, packed with one
    precompiled struct (no DSDL object per tick). The transfer id counts 0..31."""

    def __init__(
        self,
        node_id: int,
        actuator_ids: Sequence[int] = DEFAULT_ACTUATOR_IDS,
        *,
        priority: int = PRIORITY_ARRAY_COMMAND,
    ) -> None:
        self.actuator_ids = check_actuator_ids(actuator_ids, len(actuator_ids))
        if not 1 <= len(self.actuator_ids) <= MAX_COMMANDS_PER_ARRAY:
            raise ValueError(f"an ArrayCommand carries 1..{MAX_COMMANDS_PER_ARRAY} commands")
        if not 0 <= priority <= 31:
            raise ValueError("DroneCAN priority must be in 0..31")
        super().__init__(node_id, ARRAY_COMMAND(), priority)
        # per command: uint8 actuator id, uint8 command type, float16 value (little endian);
        # the array is the message's last field, so its length is implied (tail array
        # optimisation) and the payload is exactly 4 bytes per command
        self._layout = struct.Struct("<" + "BBH" * len(self.actuator_ids))
        self._n = len(self.actuator_ids)

    def encode(self, values_rad: Sequence[float]) -> list[CanFrame]:
        """Frames of one transfer carrying ``values_rad`` (same order as the actuator ids).

        Values are sent as given (float16, saturating beyond +-65504; NaN stays NaN): the
        receiving servo is the gate that refuses bad values, as on a real bus.
        """
        if len(values_rad) != self._n:
            raise ValueError(f"need {self._n} values, got {len(values_rad)}")
        fields: list[int] = []
        for aid, v in zip(self.actuator_ids, values_rad, strict=True):
            fields += (aid, COMMAND_TYPE_POSITION, float16_bits(float(v)))
        return self._frames_of(self._layout.pack(*fields))


class ArmingStatusEncoder(_Broadcaster):
    """Encodes ``uavcan.equipment.safety.ArmingStatus`` (1100): what a servo node on a real
    bus learns of the vehicle's arming, and what the plant's servo input reads."""

    def __init__(self, node_id: int, *, priority: int = PRIORITY_ARMING_STATUS) -> None:
        super().__init__(node_id, ARMING_STATUS(), priority)

    def encode(self, armed: bool) -> list[CanFrame]:
        return self._frames_of(bytes((ARMING_STATUS_FULL if armed else ARMING_STATUS_DISARMED,)))


class NodeStatusEncoder(_Broadcaster):
    """Encodes ``uavcan.protocol.NodeStatus`` (single frame) from one node."""

    def __init__(self, node_id: int, *, priority: int = PRIORITY_NODE_STATUS) -> None:
        super().__init__(node_id, NODE_STATUS(), priority)

    def encode(
        self,
        uptime_s: int,
        *,
        health: int = HEALTH_OK,
        mode: int = MODE_OPERATIONAL,
        vendor_status: int = 0,
    ) -> list[CanFrame]:
        m = self._msg
        m.uptime_sec = max(0, min(int(uptime_s), 2**32 - 1))
        m.health = health
        m.mode = mode
        m.sub_mode = 0
        m.vendor_specific_status_code = vendor_status & 0xFFFF
        return self._frames()


# ----------------------------------------------------------------------------- receiving


class DropReason(enum.Enum):
    """Why a frame or transfer did not reach the application."""

    MALFORMED_FRAME = "malformed_frame"  # standard id, remote/error/FD frame, no tail byte
    FOREIGN_TYPE = "foreign_type"  # a data type (or service) this receiver does not handle
    MISSING_FRAME = "missing_frame"  # start, toggle or end out of sequence: a frame was lost
    CRC = "crc"  # multi-frame transfer CRC mismatch
    OVERSIZE = "oversize"  # more payload than the data type can hold
    DECODE = "decode"  # dronecan could not deserialise the payload


@dataclass(frozen=True)
class CanIdFields:
    priority: int
    data_type_id: int
    service: bool
    source_node_id: int


def parse_can_id(can_id: int) -> CanIdFields:
    """Fields of a DroneCAN 29-bit identifier (message frame layout where not a service)."""
    service = bool(can_id & 0x80)
    source = can_id & 0x7F
    if service:
        dtid = (can_id >> 16) & 0xFF
    elif source == 0:  # anonymous message: only 2 bits of the type id are on the wire
        dtid = (can_id >> 8) & 0x3
    else:
        dtid = (can_id >> 8) & 0xFFFF
    return CanIdFields((can_id >> 24) & 0x1F, dtid, service, source)


@dataclass(frozen=True)
class ReceivedTransfer:
    source_node_id: int
    data_type_id: int
    transfer_id: int
    priority: int
    payload: Any  # the dronecan CompoundValue (e.g. ArrayCommand)


class ArrayCommandPayload(NamedTuple):
    """A decoded ArrayCommand: (actuator id, command type, value) per command."""

    commands: tuple[tuple[int, int, float], ...]


class ArmingStatusPayload(NamedTuple):
    status: int


def decode_array_command(payload: bytes) -> ArrayCommandPayload:
    """Unpack an ArrayCommand payload (4 bytes per command, the length implied)."""
    if len(payload) % 4:
        raise ValueError(f"{len(payload)} bytes is not a whole number of 4-byte commands")
    return ArrayCommandPayload(
        tuple(
            (aid, ctype, float16_value(bits))
            for aid, ctype, bits in struct.iter_unpack("<BBH", payload)
        )
    )


def decode_arming_status(payload: bytes) -> ArmingStatusPayload:
    if not payload:
        raise ValueError("empty ArmingStatus")
    return ArmingStatusPayload(payload[0])


#: the per-tick types, unpacked without dronecan (the rest go through Transfer.from_frames)
FAST_DECODERS: dict[int, Callable[[bytes], Any]] = {
    ARRAY_COMMAND_DTID: decode_array_command,
    ARMING_STATUS_DTID: decode_arming_status,
}


@dataclass
class _Session:
    transfer_id: int
    next_toggle: int
    frames: list[tuple[int, bytes]] = field(default_factory=list)  # (can id, data)
    n_bytes: int = 0


DropHook = Callable[[DropReason, str], None]


def _who(fields: CanIdFields, transfer_id: int) -> str:
    return f"type {fields.data_type_id} from node {fields.source_node_id}, transfer {transfer_id}"


class Reassembler:
    """Turns CAN frames into checked, decoded DroneCAN message transfers.

    ``feed`` takes frames in bus order and returns a :class:`ReceivedTransfer` when one
    completes, else None. Only message types in ``data_type_ids`` are reassembled; every
    rejected frame or transfer is counted in ``drops`` (once per lost transfer) and
    reported to ``on_drop``. Sessions are keyed by (source node, data type), as a
    DroneCAN receiver does; a new start frame abandons an unfinished transfer. No clock.
    """

    def __init__(self, data_type_ids: Collection[int], on_drop: DropHook | None = None) -> None:
        self.types: dict[int, Any] = {}
        self.max_bytes: dict[int, int] = {}
        for dtid in data_type_ids:
            dt = dronecan.DATATYPES.get((dtid, dronecan.dsdl.CompoundType.KIND_MESSAGE))
            if dt is None:
                raise ValueError(f"no DroneCAN message type with id {dtid}")
            self.types[dtid] = dt
            # payload bytes + 2 CRC bytes; beyond that a session is garbage
            self.max_bytes[dtid] = (int(dt.get_max_bitlen()) + 7) // 8 + 2
        self.on_drop = on_drop
        self.drops: Counter[DropReason] = Counter()
        self._sessions: dict[tuple[int, int], _Session] = {}
        self._orphans: dict[tuple[int, int], int] = {}  # last transfer id counted as orphan

    def _drop(self, reason: DropReason, detail: str) -> None:
        self.drops[reason] += 1
        if self.on_drop is not None:
            self.on_drop(reason, detail)

    def feed_message(self, msg: can.Message) -> ReceivedTransfer | None:
        """``feed`` for a python-can message, rejecting frames DroneCAN never uses."""
        if (
            not msg.is_extended_id
            or msg.is_remote_frame
            or msg.is_error_frame
            or msg.is_fd
            or len(msg.data) == 0
        ):
            self._drop(
                DropReason.MALFORMED_FRAME,
                f"id 0x{msg.arbitration_id:x} ext={msg.is_extended_id} "
                f"rtr={msg.is_remote_frame} err={msg.is_error_frame} fd={msg.is_fd} "
                f"len={len(msg.data)}",
            )
            return None
        return self.feed(msg.arbitration_id, bytes(msg.data))

    def feed(self, can_id: int, data: bytes) -> ReceivedTransfer | None:
        if not 1 <= len(data) <= 8:
            self._drop(DropReason.MALFORMED_FRAME, f"id 0x{can_id:x}: {len(data)} data bytes")
            return None
        fields = parse_can_id(can_id)
        if fields.service or fields.source_node_id == 0 or fields.data_type_id not in self.types:
            kind = "service" if fields.service else "message"
            self._drop(
                DropReason.FOREIGN_TYPE,
                f"{kind} type {fields.data_type_id} from node {fields.source_node_id}",
            )
            return None
        tail = data[-1]
        sot, eot, toggle, tid = bool(tail & 0x80), bool(tail & 0x40), (tail >> 5) & 1, tail & 0x1F
        key = (fields.source_node_id, fields.data_type_id)
        who = _who(fields, tid)
        frame = (can_id, data)
        if sot:
            self._orphans.pop(key, None)
            old = self._sessions.pop(key, None)
            if old is not None:
                self._drop(
                    DropReason.MISSING_FRAME,
                    f"{_who(fields, old.transfer_id)}: no end frame before the next start",
                )
            if toggle != 0:
                self._drop(DropReason.MISSING_FRAME, f"{who}: start frame with toggle set")
                return None
            if eot:
                return self._complete(fields, tid, [frame])
            self._sessions[key] = _Session(tid, 1, [frame], len(data) - 1)
            return None
        session = self._sessions.get(key)
        if session is None or session.transfer_id != tid:
            if session is not None:  # a different transfer is pending: it has lost its end
                del self._sessions[key]
                self._drop(
                    DropReason.MISSING_FRAME,
                    f"{_who(fields, session.transfer_id)}: interrupted by transfer {tid}",
                )
            if self._orphans.get(key) != tid:  # count each headless transfer once
                self._orphans[key] = tid
                self._drop(DropReason.MISSING_FRAME, f"{who}: continuation without a start")
            return None
        if toggle != session.next_toggle:
            del self._sessions[key]
            self._orphans[key] = tid  # its remaining frames are not counted again
            self._drop(DropReason.MISSING_FRAME, f"{who}: toggle out of sequence")
            return None
        session.frames.append(frame)
        session.n_bytes += len(data) - 1
        session.next_toggle ^= 1
        limit = self.max_bytes[fields.data_type_id]
        if session.n_bytes > limit:
            del self._sessions[key]
            self._orphans[key] = tid
            self._drop(DropReason.OVERSIZE, f"{who}: {session.n_bytes} bytes, at most {limit}")
            return None
        if not eot:
            return None
        del self._sessions[key]
        return self._complete(fields, tid, session.frames)

    def _complete(
        self, fields: CanIdFields, tid: int, frames: list[tuple[int, bytes]]
    ) -> ReceivedTransfer | None:
        dt = self.types[fields.data_type_id]
        who = _who(fields, tid)
        if len(frames) > 1:
            # checked here (not only inside dronecan's from_frames) to count it as a CRC fault
            raw = b"".join(data[:-1] for _, data in frames)
            if len(raw) < 2:
                self._drop(DropReason.DECODE, f"{who}: {len(raw)} bytes, shorter than its CRC")
                return None
            crc_rx = raw[0] | (raw[1] << 8)
            payload = raw[2:]
            crc = transfer_crc(payload, dt.base_crc)
            if crc != crc_rx:
                self._drop(DropReason.CRC, f"{who}: CRC 0x{crc_rx:04x}, computed 0x{crc:04x}")
                return None
        else:
            payload = frames[0][1][:-1]
        try:
            fast = FAST_DECODERS.get(fields.data_type_id)
            if fast is not None:
                value = fast(payload)
            else:
                tr = transport.Transfer()
                tr.from_frames([transport.Frame(can_id, data) for can_id, data in frames])
                value = tr.payload
        except Exception as exc:
            # dronecan raises TransferError, ValueError or IndexError on a short or
            # inconsistent payload; any of them means the transfer is unusable, not fatal
            self._drop(DropReason.DECODE, f"{who}: {type(exc).__name__}: {exc}")
            return None
        return ReceivedTransfer(fields.source_node_id, fields.data_type_id, tid, fields.priority, value)


def array_command_entries(payload: Any) -> list[tuple[int, int, float]]:
    """(actuator id, command type, value) for each command of a decoded ArrayCommand
    (ours, or a dronecan object)."""
    if isinstance(payload, ArrayCommandPayload):
        return list(payload.commands)
    return [
        (int(c.actuator_id), int(c.command_type), float(c.command_value))
        for c in payload.commands
    ]


# --------------------------------------------------------------- a driver for dronecan.Node


class DronecanDriver(AbstractDriver):  # type: ignore[misc]  # dronecan is untyped
    """A dronecan driver over a :class:`CanBus`, so dronecan's own ``Node`` (handlers,
    transfer manager, NodeStatus) can run on python-can >= 4.4 buses. Unlike dronecan's
    ``PythonCAN`` driver it sends synchronously without ``flush_tx_buffer`` and takes the
    receive timeout in seconds (see the module doc). Usage::

        node = dronecan.node.Node(DronecanDriver(CanBus(config)), node_id=None)
        node.add_handler(ARRAY_COMMAND, callback)
        node.spin(0)
    """

    def __init__(self, bus: CanBus) -> None:
        super().__init__()
        self.bus = bus

    def receive(self, timeout: float | None = None) -> Any:
        msg = self.bus.recv(timeout)  # seconds; None blocks, as dronecan's drivers do
        if msg is None or msg.is_error_frame or msg.is_remote_frame:
            return None
        frame = CANFrame(
            msg.arbitration_id,
            bytearray(msg.data),
            msg.is_extended_id,
            ts_monotonic=time.monotonic(),
            ts_real=msg.timestamp if math.isfinite(msg.timestamp) else time.time(),
        )
        self._rx_hook(frame)
        return frame

    def send_frame(self, frame: Any) -> None:
        self.bus.send(int(frame.id), bytes(frame.data))
        self._tx_hook(frame)

    def close(self) -> None:
        self.bus.close()
