"""What makes a bench process a DroneCAN node the field's tools recognise.

Every node of the bench (the autopilot's servo output, node 10; the plant's servos,
node 20) sends ``uavcan.protocol.NodeStatus`` (341) at 1 Hz and answers
``uavcan.protocol.GetNodeInfo`` (service 1) with its name, software version (the
project's), hardware version 0.0 and a 16-byte unique id; the plant's servos also
publish ``uavcan.equipment.actuator.Status`` (1011), one per servo. That is what the
DroneCAN GUI tool's node list, ``dronecan``'s ``NodeMonitor`` and ArduPilot's node
discovery ask of a node.

Nothing here reads a clock or a bus: the owner passes the time and sends the frames.
The per-tick work is one integer test (:func:`get_node_info_request` on a frame id); an
answer (ten frames) is the response dronecan serialised once with the current status in
front (~30 us; dronecan's whole serialisation costs ~4 ms, more than a tick at 400 Hz), the
actuator status (8 bytes per servo) is packed with ``struct``: both byte-identical to
dronecan's (tested).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import dronecan
from dronecan import transport

from heli_common.wire.can.dronecan_codec import (
    HEALTH_OK,
    MODE_OPERATIONAL,
    CanFrame,
    _Broadcaster,
    check_node_id,
    float16_bits,
    frames_of_transfer,
)

GET_NODE_INFO: Any = dronecan.uavcan.protocol.GetNodeInfo
ACTUATOR_STATUS: Any = dronecan.uavcan.equipment.actuator.Status
GET_NODE_INFO_DTID = 1
ACTUATOR_STATUS_DTID = 1011
POWER_RATING_PCT_UNKNOWN = 127
#: feedback is housekeeping: below the commands (8) and the arming status (16)
PRIORITY_ACTUATOR_STATUS = 20
NAME_MAX = 80
_NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyz0123456789.-_")

assert GET_NODE_INFO.default_dtid == GET_NODE_INFO_DTID
assert ACTUATOR_STATUS.default_dtid == ACTUATOR_STATUS_DTID


def project_version() -> tuple[int, int]:
    """The installed project's major.minor (0.0, "unknown" in DroneCAN, if not installed)."""
    try:
        parts = importlib.metadata.version("heli-tlc-sitl").split(".")
        return int(parts[0]) & 0xFF, int(parts[1]) & 0xFF
    except (importlib.metadata.PackageNotFoundError, ValueError, IndexError):
        return 0, 0


@dataclass(frozen=True)
class NodeIdentity:
    """What GetNodeInfo answers. ``unique_id``: 16 bytes; empty derives one from the name
    and node id (stable across runs, distinct per node: the tools key nodes by it)."""

    name: str
    software_version: tuple[int, int] = (0, 0)
    hardware_version: tuple[int, int] = (0, 0)
    unique_id: bytes = b""

    def __post_init__(self) -> None:
        if not 1 <= len(self.name) <= NAME_MAX or not set(self.name) <= _NAME_CHARS:
            raise ValueError(f"DroneCAN node name must be 1..{NAME_MAX} of a-z 0-9 . - _ "
                             f"(a reversed domain name), got {self.name!r}")  # fmt: skip
        if self.unique_id and len(self.unique_id) != 16:
            raise ValueError(f"unique id must be 16 bytes, got {len(self.unique_id)}")

    def unique_id_for(self, node_id: int) -> bytes:
        if self.unique_id:
            return self.unique_id
        return hashlib.md5(f"heli-tlc-sitl/{self.name}/{node_id}".encode()).digest()


class ServiceRequest(NamedTuple):
    source_node_id: int
    transfer_id: int
    priority: int


def get_node_info_request(can_id: int, data: bytes, node_id: int) -> ServiceRequest | None:
    """The GetNodeInfo request a frame is, if it is one for ``node_id`` (its request is
    empty: a single frame holding only the tail byte), else None."""
    # service, request, destination node_id, service type 1: one mask and compare
    if (can_id & 0x00FFFF80) != ((GET_NODE_INFO_DTID << 16) | 0x8000 | (node_id << 8) | 0x80):
        return None
    if len(data) < 1 or (data[-1] & 0xC0) != 0xC0:  # single frame: start and end set
        return None
    source = can_id & 0x7F
    if source == 0:  # anonymous nodes send no service requests
        return None
    return ServiceRequest(source, data[-1] & 0x1F, (can_id >> 24) & 0x1F)


def frame_source(can_id: int) -> int:
    """The source node id of a DroneCAN frame (0: anonymous)."""
    return can_id & 0x7F


_NODE_STATUS = struct.Struct("<IBH")  # uptime_sec; health:2 mode:3 sub_mode:3; vendor code


def node_status_bytes(
    uptime_s: int, health: int, mode: int, sub_mode: int = 0, vendor_status: int = 0
) -> bytes:
    """``uavcan.protocol.NodeStatus`` serialised (7 bytes, as dronecan packs it: tested)."""
    uptime = max(0, min(int(uptime_s), 2**32 - 1))
    return _NODE_STATUS.pack(uptime, ((health & 3) << 6) | ((mode & 7) << 3) | (sub_mode & 7),
                             vendor_status & 0xFFFF)  # fmt: skip


class NodeInfoResponder:
    """Builds the frames answering a GetNodeInfo request (one node). The response is
    serialised by dronecan once, at construction; an answer only puts the current status
    (its first 7 bytes) in front of the rest and frames it (dronecan's serialisation of
    the whole response costs ~4 ms, too much for a control tick; this ~40 us)."""

    def __init__(self, node_id: int, identity: NodeIdentity) -> None:
        self.node_id = check_node_id(node_id)
        self.identity = identity
        self.unique_id = identity.unique_id_for(node_id)
        self.answered = 0
        r = GET_NODE_INFO.Response()
        r.software_version.major, r.software_version.minor = identity.software_version
        r.software_version.optional_field_flags = 0
        r.hardware_version.major, r.hardware_version.minor = identity.hardware_version
        r.hardware_version.unique_id = list(self.unique_id)
        r.name = identity.name
        template = transport.Transfer(
            transfer_id=0, source_node_id=self.node_id, dest_node_id=1, payload=r,
            service_not_message=True, request_not_response=False,
        )  # fmt: skip
        self._after_status = bytes(template.payload)[7:]
        self._base_crc = int(r._type.base_crc)

    def payload(self, uptime_s: int, health: int = HEALTH_OK, mode: int = MODE_OPERATIONAL,
                vendor_status: int = 0) -> bytes:  # fmt: skip
        return node_status_bytes(uptime_s, health, mode, 0, vendor_status) + self._after_status

    def respond(
        self,
        request: ServiceRequest,
        uptime_s: int,
        *,
        health: int = HEALTH_OK,
        mode: int = MODE_OPERATIONAL,
        vendor_status: int = 0,
    ) -> list[CanFrame]:
        can_id = ((request.priority & 0x1F) << 24) | (GET_NODE_INFO_DTID << 16) \
            | (request.source_node_id << 8) | 0x80 | self.node_id  # a response: bit 15 clear
        self.answered += 1
        return frames_of_transfer(can_id, self.payload(uptime_s, health, mode, vendor_status),
                                  request.transfer_id, self._base_crc)  # fmt: skip


_STATUS = struct.Struct("<BHHHB")  # actuator_id, position, force, speed, void1 + uint7 power


class ActuatorStatusEncoder(_Broadcaster):
    """``uavcan.equipment.actuator.Status`` (1011) from one node, packed with ``struct``:
    actuator id, position [rad], force and speed (NaN: unknown), power rating (127:
    unknown). One transfer per actuator, 8 payload bytes, two frames."""

    def __init__(self, node_id: int, *, priority: int = PRIORITY_ACTUATOR_STATUS) -> None:
        super().__init__(node_id, ACTUATOR_STATUS(), priority)

    def encode(
        self,
        actuator_id: int,
        position: float,
        *,
        force: float = math.nan,
        speed: float = math.nan,
        power_rating_pct: int = POWER_RATING_PCT_UNKNOWN,
    ) -> list[CanFrame]:
        payload = _STATUS.pack(
            actuator_id & 0xFF, float16_bits(float(position)), float16_bits(float(force)),
            float16_bits(float(speed)), power_rating_pct & 0x7F,
        )  # fmt: skip
        return self._frames_of(payload)

    def encode_all(self, actuator_ids: Sequence[int], positions: Sequence[float]) -> list[CanFrame]:
        out: list[CanFrame] = []
        for aid, pos in zip(actuator_ids, positions, strict=True):
            out += self.encode(aid, pos)
        return out
