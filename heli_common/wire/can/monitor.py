"""A candump-like live listing of a CAN bus, decoded as DroneCAN (``heli-sitl can monitor``).

Every frame is reassembled into its transfer (messages and services, any data type
``dronecan``'s DSDL knows), checked (tail bytes, the transfer CRC through dronecan's
``Transfer.from_frames``) and printed as one line: the time, the source and destination
node, the type's full name, priority and transfer id, and the fields::

    0.123456  10 -> *    uavcan.equipment.actuator.ArrayCommand  p8 t5  commands=[{actuator_id=1, ...}]

A transfer that cannot be decoded is printed too, with the reason (``!``), and with
``frames=True`` every frame is listed as candump lists it (id in hex, length, bytes).
Sessions are keyed by the frame's id without priority (source, destination, type): one
transfer at a time per key, as DroneCAN sends them. Nothing here blocks or reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import can
import dronecan
from dronecan import transport

from heli_common.wire.can.dronecan_codec import parse_can_id

#: frames of one transfer kept at most (a 256-byte transfer is 37 classic frames)
MAX_FRAMES_PER_TRANSFER = 64
_SESSION_KEY_MASK = 0x00FFFFFF  # the id without its priority


@dataclass(frozen=True)
class MonitoredTransfer:
    """One transfer seen on the bus (``payload`` None and ``error`` set if undecodable)."""

    timestamp: float
    source_node_id: int
    dest_node_id: int | None  # None: a broadcast message
    service: bool
    request: bool
    data_type_id: int
    type_name: str
    priority: int
    transfer_id: int
    payload: Any
    error: str = ""


@dataclass
class _Session:
    frames: list[transport.Frame] = field(default_factory=list)
    toggle: int = 0
    transfer_id: int = 0


class TransferMonitor:
    """Frames in, :class:`MonitoredTransfer` out; counts what it could not read."""

    def __init__(self) -> None:
        self._sessions: dict[int, _Session] = {}
        self.frames = 0
        self.transfers = 0
        self.errors = 0
        self.skipped = 0  # not a DroneCAN frame (standard id, remote, error frame, empty)

    def feed(self, msg: can.Message) -> MonitoredTransfer | None:
        self.frames += 1
        if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or len(msg.data) == 0:
            self.skipped += 1
            return None
        can_id = msg.arbitration_id
        data = bytes(msg.data)
        tail = data[-1]
        sot, eot, toggle, tid = bool(tail & 0x80), bool(tail & 0x40), (tail >> 5) & 1, tail & 0x1F
        key = can_id & _SESSION_KEY_MASK
        ts = msg.timestamp if math.isfinite(msg.timestamp) else 0.0
        frame = transport.Frame(can_id, bytearray(data), ts_monotonic=ts, ts_real=ts, canfd=msg.is_fd)
        if sot:
            if toggle != 0:
                return self._error(can_id, tid, ts, "start frame with toggle set")
            if eot:
                self._sessions.pop(key, None)
                return self._decode(can_id, tid, ts, [frame])
            self._sessions[key] = _Session([frame], 1, tid)
            return None
        session = self._sessions.get(key)
        if session is None or session.transfer_id != tid:
            return None  # the middle of a transfer whose start this monitor did not see
        if toggle != session.toggle or len(session.frames) >= MAX_FRAMES_PER_TRANSFER:
            del self._sessions[key]
            return self._error(can_id, tid, ts, "toggle out of sequence: a frame was lost")
        session.frames.append(frame)
        session.toggle ^= 1
        if not eot:
            return None
        del self._sessions[key]
        return self._decode(can_id, tid, ts, session.frames)

    def _decode(self, can_id: int, tid: int, ts: float, frames: list[transport.Frame]) -> MonitoredTransfer:
        tr = transport.Transfer()
        try:
            tr.from_frames(frames)
        except Exception as exc:
            # dronecan raises TransferError (CRC, unknown type), ValueError, IndexError
            return self._error(can_id, tid, ts, f"{type(exc).__name__}: {exc}")
        self.transfers += 1
        name = dronecan.get_dronecan_data_type(tr.payload).full_name
        f = parse_can_id(can_id)
        return MonitoredTransfer(
            ts, f.source_node_id, int(tr.dest_node_id) if f.service else None, f.service,
            bool(tr.request_not_response) if f.service else False, f.data_type_id, name,
            f.priority, tid, tr.payload,
        )  # fmt: skip

    def _error(self, can_id: int, tid: int, ts: float, why: str) -> MonitoredTransfer:
        self.errors += 1
        f = parse_can_id(can_id)
        dest = (can_id >> 8) & 0x7F if f.service else None
        request = bool(can_id & 0x8000) if f.service else False
        kind = dronecan.DATATYPES.get(
            (f.data_type_id, dronecan.dsdl.CompoundType.KIND_SERVICE if f.service
             else dronecan.dsdl.CompoundType.KIND_MESSAGE)
        )  # fmt: skip
        name = kind.full_name if kind is not None else f"type {f.data_type_id}"
        return MonitoredTransfer(ts, f.source_node_id, dest, f.service, request, f.data_type_id, name,
                                 f.priority, tid, None, why)  # fmt: skip


def value_text(v: Any, *, float_digits: int = 6) -> str:
    """A dronecan value on one line: ``{a=1, b=[...]}``; uint8 strings as text, fixed uint8
    arrays (unique ids) as hex."""
    if isinstance(v, transport.CompoundValue):
        names = [k for k in v._fields if not k.startswith("_void_")]
        if v._is_union:
            names = [v._union_field or names[0]]
        return "{" + ", ".join(f"{k}={value_text(getattr(v, k), float_digits=float_digits)}"
                               for k in names) + "}"  # fmt: skip
    if isinstance(v, transport.ArrayValue):
        if v._type.is_string_like:
            try:
                text = v.decode()
                if text.isprintable():
                    return repr(text)
            except UnicodeDecodeError:
                pass
            return "0x" + bytes(v.to_bytes()).hex()
        vt = v._type.value_type
        static = v._type.mode == dronecan.dsdl.ArrayType.MODE_STATIC
        if static and isinstance(vt, dronecan.dsdl.PrimitiveType) and vt.kind == vt.KIND_UNSIGNED_INT \
                and vt.bitlen == 8:  # fmt: skip
            return "0x" + bytes(v.to_bytes()).hex()  # an id (unique_id): as hex
        return "[" + ", ".join(value_text(x, float_digits=float_digits) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.{float_digits}g}"
    return str(v)


def transfer_line(t: MonitoredTransfer, t0: float = 0.0) -> str:
    """One line for a transfer (times relative to ``t0``)."""
    dest = "*" if t.dest_node_id is None else str(t.dest_node_id)
    kind = " request" if t.service and t.request else (" response" if t.service else "")
    head = f"{t.timestamp - t0:10.6f}  {t.source_node_id:3d} -> {dest:<3}  {t.type_name}{kind}  " \
           f"p{t.priority} t{t.transfer_id}"  # fmt: skip
    if t.error:
        return f"{head}  ! {t.error}"
    if t.payload is None:
        return head
    fields = value_text(t.payload)
    return f"{head}  {fields[1:-1] if fields.startswith('{') else fields}"


def frame_line(msg: can.Message, bus_name: str, t0: float = 0.0) -> str:
    """candump's form: ``(time) bus  ID#  [len]  bytes``."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    data = " ".join(f"{b:02X}" for b in msg.data)
    return f"({msg.timestamp - t0:10.6f})  {bus_name}  {ident}  [{len(msg.data)}]  {data}"


def iter_lines(
    messages: Iterator[can.Message], bus_name: str, *, frames: bool = False, t0: float = 0.0
) -> Iterator[tuple[str, bool]]:
    """(line, is_transfer) for each frame read: a transfer's line when one completes, and
    with ``frames`` a line per frame first."""
    mon = TransferMonitor()
    for msg in messages:
        if frames:
            yield frame_line(msg, bus_name, t0), False
        tr = mon.feed(msg)
        if tr is not None:
            yield transfer_line(tr, t0), True
