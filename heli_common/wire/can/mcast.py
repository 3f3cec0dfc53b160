"""DroneCAN's UDP multicast CAN bus as a python-can interface (``mcast:N``).

The format every DroneCAN tool of the field speaks for a CAN bus between processes on one
host: ArduPilot's SITL CAN driver and AP_Periph SITL nodes, libcanard's multicast driver,
pydronecan's ``mcast:N`` driver (so the DroneCAN GUI tool). Verified against:

* ArduPilot ``libraries/AP_HAL_SITL/CAN_Multicast.cpp`` (the packet, ``send``, ``receive``),
  ``libraries/AP_HAL/utility/Socket.cpp`` (``connect`` to a multicast address: the receive
  socket and the self filter), ``libraries/AP_HAL/CANIface.h`` (``CANFrame::id`` flags);
* libcanard ``drivers/mcast/mcast.c`` (the same packet and sockets; ``canard.h``'s
  ``CANARD_CAN_FRAME_EFF``);
* pydronecan ``dronecan/driver/mcast.py`` (``mcast:N``; installed as ``dronecan`` 1.0.27,
  identical to the repository's head), ``dronecan/dsdl/common.py`` ``crc16_from_bytes``.

The bus: UDP to the IPv4 group 239.65.82.N, N the bus number (0..9: ArduPilot and
libcanard write N as one digit), port 57732; one CAN frame per datagram::

    offset  size  field (little-endian)
    0       2     magic = 0x2934
    2       2     crc   = CRC-16-CCITT (poly 0x1021, init 0xFFFF, no reflection, no final
                          xor; "123456789" -> 0x29B1) over bytes 4.. (flags, id, data)
    4       2     flags: bit 0 = CAN FD frame
    6       4     id: the CAN id with the flags of ArduPilot's CANFrame::id: bit 31 extended
                  (every DroneCAN frame), bit 30 remote, bit 29 error; bits 0-28 the id
    10      n     data, n = datagram length - 10 (0..8; a CAN FD frame 0..64)

At most 74 bytes. A datagram that is shorter than 10 bytes, has another magic or a wrong
CRC, is longer than 74 bytes, or whose length or id does not make a CAN frame (more than
8 bytes without the FD flag, an FD length that is no DLC length, a standard id over
0x7FF) is counted in :attr:`DroneCanMcastBus.stats` and dropped, never raised.

Sockets, as the three implementations make them: a receive socket with SO_REUSEADDR,
bound to (group, 57732) and joined to the group on INADDR_ANY (the interface the route to
224.0.0.0/4 names: ``lo`` in the tests' namespaces), so every process on the host binds
the same port and each gets a copy of every datagram; and a send socket connected to
(group, 57732), multicast loopback on (the other processes of the host must hear it).
The field's tools leave the multicast TTL at its default of 1 (the local link); this bus
sends with TTL 0 by default (``ttl=1`` to reach the link): a TTL 0 datagram is still
looped back to every socket of the host but never leaves it.

Own frames: a process does not see its own frames, as ArduPilot (a datagram whose source
address and port are those of its own send socket is dropped) and pydronecan (same source
port) do; libcanard's driver does hear its own. ``receive_own_messages=True`` keeps them.
Two buses opened in one process are two nodes: each sees the other's frames.

Opened by ``can.Bus(interface="dronecan_mcast", channel=N)`` in any python-can program
(the ``can.interface`` entry point in pyproject.toml), or ``--can-bus mcast:N`` here.
Multicast leaves the loopback interface unless routed otherwise: the tests open it only
inside a private network namespace (``unshare --net``, ``ip link set lo up``,
``ip route add 224.0.0.0/4 dev lo``).
"""

from __future__ import annotations

import binascii
import errno
import select
import socket
import struct
import time
from typing import Any, NamedTuple

import can

MCAST_GROUP_BASE = "239.65.82"
MCAST_PORT = 57732
MCAST_MAGIC = 0x2934
MCAST_FLAG_CANFD = 0x0001
HEADER = struct.Struct("<HHHI")  # magic, crc, flags, id
HEADER_LEN = HEADER.size  # 10
MAX_DATA_LEN = 64
MAX_DATAGRAM_LEN = HEADER_LEN + MAX_DATA_LEN  # 74
MAX_BUS = 9

#: AP_HAL::CANFrame::id (and libcanard's CanardCANFrame::id) flags
FLAG_EFF = 1 << 31
FLAG_RTR = 1 << 30
FLAG_ERR = 1 << 29
EXT_ID_MASK = 0x1FFFFFFF
STD_ID_MASK = 0x7FF
CANFD_LENGTHS = frozenset((*range(9), 12, 16, 20, 24, 32, 48, 64))

#: receive buffer: larger than any valid datagram, so an oversized one is seen as such
_RECV_BUF = 256

STAT_KEYS = (
    "tx_frames",
    "tx_errors",
    "rx_frames",  # delivered
    "rx_own",  # this bus's own frames, dropped (receive_own_messages=False)
    "bad_short",  # under 10 bytes
    "bad_magic",
    "bad_crc",
    "bad_oversized",  # over 74 bytes
    "bad_frame",  # length or id that makes no CAN frame
    "rx_errors",  # the socket raised on receive
)


def group_of(bus: int) -> str:
    """The IPv4 group of bus ``bus``: 239.65.82.N."""
    return f"{MCAST_GROUP_BASE}.{check_bus_number(bus)}"


def check_bus_number(bus: int) -> int:
    if not 0 <= bus <= MAX_BUS:
        raise ValueError(f"DroneCAN mcast bus must be 0..{MAX_BUS} (239.65.82.N), got {bus}")
    return bus


def parse_channel(channel: object) -> int:
    """A python-can channel as a bus number: 0, "0", "mcast:0" or "mcast" (bus 0)."""
    if isinstance(channel, bool):
        raise ValueError(f"not a DroneCAN mcast bus: {channel!r}")
    if channel is None:
        return 0
    if isinstance(channel, int):
        return check_bus_number(channel)
    text = str(channel).strip()
    if text.startswith("mcast"):
        text = text[len("mcast") :].removeprefix(":")
    if text == "":
        return 0
    try:
        return check_bus_number(int(text))
    except ValueError:
        raise ValueError(
            f"not a DroneCAN mcast bus: {channel!r} (expected 0..{MAX_BUS} or mcast:N)"
        ) from None


def crc16_ccitt(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16-CCITT, polynomial 0x1021, MSB first, no final xor (ArduPilot's
    ``crc16_ccitt(buf, len, 0xFFFF)``, pydronecan's ``crc16_from_bytes``)."""
    return binascii.crc_hqx(data, crc)


class McastFrame(NamedTuple):
    """One CAN frame as a datagram carries it."""

    can_id: int  # without flags
    data: bytes
    extended: bool = True
    fd: bool = False
    remote: bool = False
    error: bool = False


def encode_datagram(frame: McastFrame) -> bytes:
    """The datagram for one frame; ValueError if it makes no CAN frame."""
    n = len(frame.data)
    if frame.fd:
        if n not in CANFD_LENGTHS:
            raise ValueError(f"a CAN FD frame carries 0..8, 12, 16, 20, 24, 32, 48 or 64 bytes, not {n}")
    elif n > 8:
        raise ValueError(f"a CAN 2.0 frame carries at most 8 bytes, not {n}")
    limit = EXT_ID_MASK if frame.extended else STD_ID_MASK
    if not 0 <= frame.can_id <= limit:
        raise ValueError(f"CAN id 0x{frame.can_id:x} out of range for a "
                         f"{'29' if frame.extended else '11'}-bit id")  # fmt: skip
    message_id = (
        frame.can_id
        | (FLAG_EFF if frame.extended else 0)
        | (FLAG_RTR if frame.remote else 0)
        | (FLAG_ERR if frame.error else 0)
    )
    body = struct.pack("<HI", MCAST_FLAG_CANFD if frame.fd else 0, message_id) + frame.data
    return struct.pack("<HH", MCAST_MAGIC, crc16_ccitt(body)) + body


def decode_datagram(datagram: bytes) -> McastFrame | str:
    """The frame a datagram carries, or the stat key of why it is bad."""
    n = len(datagram)
    if n < HEADER_LEN:
        return "bad_short"
    if n > MAX_DATAGRAM_LEN:
        return "bad_oversized"
    magic, crc, flags, message_id = HEADER.unpack_from(datagram)
    if magic != MCAST_MAGIC:
        return "bad_magic"
    if crc != crc16_ccitt(datagram[4:]):
        return "bad_crc"
    fd = bool(flags & MCAST_FLAG_CANFD)
    data = datagram[HEADER_LEN:]
    if (len(data) not in CANFD_LENGTHS) if fd else len(data) > 8:
        return "bad_frame"
    extended = bool(message_id & FLAG_EFF)
    can_id = message_id & EXT_ID_MASK
    if not extended and can_id > STD_ID_MASK:
        return "bad_frame"
    return McastFrame(can_id, data, extended, fd, bool(message_id & FLAG_RTR), bool(message_id & FLAG_ERR))


class DroneCanMcastBus(can.BusABC):
    """python-can bus on DroneCAN's UDP multicast CAN (see the module doc).

    ``channel``: the bus number 0..9 (or ``"mcast:N"``). ``ttl``: the multicast TTL of
    sent datagrams (0: the host only; the field's tools use 1). ``receive_own_messages``:
    also deliver this bus's own frames. ``port``: 57732 unless a test needs another.
    """

    def __init__(
        self,
        channel: Any = 0,
        can_filters: Any = None,
        *,
        ttl: int = 0,
        receive_own_messages: bool = False,
        port: int = MCAST_PORT,
        **kwargs: object,
    ) -> None:
        self.bus_number = parse_channel(channel)
        if not 0 <= ttl <= 255:
            raise ValueError(f"multicast TTL must be 0..255, got {ttl}")
        self.group = group_of(self.bus_number)
        self.port = int(port)
        self.receive_own_messages = receive_own_messages
        self.channel_info = f"DroneCAN mcast:{self.bus_number} ({self.group}:{self.port})"
        self.stats: dict[str, int] = dict.fromkeys(STAT_KEYS, 0)
        self._can_protocol = can.CanProtocol.CAN_FD
        self._rx: socket.socket | None = None
        self._tx: socket.socket | None = None
        try:
            self._rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
            self._rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._rx.bind((self.group, self.port))
            mreq = socket.inet_aton(self.group) + socket.inet_aton("0.0.0.0")  # INADDR_ANY
            self._rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
            self._rx.setblocking(False)
            self._tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
            self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
            self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            self._tx.connect((self.group, self.port))
            self._tx.setblocking(False)
            self._self_addr = self._tx.getsockname()
        except OSError as exc:
            self._close_sockets()
            raise can.CanInitializationError(f"cannot open {self.channel_info}: {exc}") from exc
        super().__init__(channel=self.bus_number, can_filters=can_filters, **kwargs)

    # ------------------------------------------------------------------ python-can API

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send one frame; CanOperationError if it was not (a full socket buffer after
        ``timeout`` seconds, None: wait; an invalid frame)."""
        if self._tx is None:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        try:
            frame = McastFrame(msg.arbitration_id, bytes(msg.data), msg.is_extended_id, msg.is_fd,
                               msg.is_remote_frame, msg.is_error_frame)  # fmt: skip
            pkt = encode_datagram(frame)
        except ValueError as exc:
            self.stats["tx_errors"] += 1
            raise can.CanOperationError(str(exc)) from exc
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                self._tx.send(pkt)
                self.stats["tx_frames"] += 1
                return
            except BlockingIOError:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0.0:
                    self.stats["tx_errors"] += 1
                    raise can.CanOperationError(f"{self.channel_info}: send buffer full") from None
                select.select([], [self._tx], [], left)
            except OSError as exc:
                self.stats["tx_errors"] += 1
                raise can.CanOperationError(f"{self.channel_info}: {exc}", exc.errno) from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        rx = self._rx
        if rx is None:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                datagram, source = rx.recvfrom(_RECV_BUF)
            except BlockingIOError:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0.0:
                    return None, False
                select.select([rx], [], [], left)
                continue
            except OSError as exc:
                if exc.errno == errno.EINTR:
                    continue
                self.stats["rx_errors"] += 1
                raise can.CanOperationError(f"{self.channel_info}: {exc}", exc.errno) from exc
            if source == self._self_addr and not self.receive_own_messages:
                self.stats["rx_own"] += 1
                continue
            frame = decode_datagram(datagram)
            if isinstance(frame, str):
                self.stats[frame] += 1
                continue
            self.stats["rx_frames"] += 1
            msg = can.Message(
                timestamp=time.time(),
                arbitration_id=frame.can_id,
                is_extended_id=frame.extended,
                is_remote_frame=frame.remote,
                is_error_frame=frame.error,
                is_fd=frame.fd,
                dlc=len(frame.data),
                data=frame.data,
                channel=self.bus_number,
                check=False,
            )
            return msg, False

    def fileno(self) -> int:
        if self._rx is None:
            raise can.CanOperationError(f"{self.channel_info} is shut down")
        return self._rx.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._close_sockets()

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        return [{"interface": "dronecan_mcast", "channel": n} for n in range(MAX_BUS + 1)]

    @property
    def bad_datagrams(self) -> int:
        """Datagrams dropped as not the format (short, magic, CRC, oversized, no frame)."""
        return sum(self.stats[k] for k in STAT_KEYS if k.startswith("bad_"))

    def _close_sockets(self) -> None:
        for s in (self._rx, self._tx):
            if s is not None:
                s.close()
        self._rx = self._tx = None
