"""A small MAVLink 2 endpoint over UDP on loopback, with pymavlink's codec and no global state.

pymavlink's ``mavutil`` keeps module-level state and hides the socket; this class keeps one
socket and one ``MAVLink`` codec object, parses each datagram on its own (a truncated or
corrupted datagram cannot poison the next one), counts what it drops, and closes cleanly.
"""

from __future__ import annotations

import errno
import math
import os
import select
import socket
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Protocol

os.environ.setdefault("MAVLINK20", "1")
# the development dialect: common.xml plus the standard modes microservice (AVAILABLE_MODES,
# CURRENT_MODE, DO_SET_STANDARD_MODE) that pymavlink 2.4.50 has only there
from pymavlink.dialects.v20 import development as mavlink2

from heli_common.closing import Closing
from heli_common.port_handoff import adopt

__all__ = [
    "LOOPBACK", "Address", "MavlinkUdp", "Message", "PortBusyError", "TlogWriter",
    "addressed_to", "mavlink2",
]  # fmt: skip

Address = tuple[str, int]
MAVLink = mavlink2.MAVLink
class Message(Protocol):
    """A pymavlink MAVLink_message as this project uses it. pymavlink ships no type
    information; this names the methods we call, so a typo in one is a mypy error. Fields
    are read by name (``msg.param1``) and typed Any: the handlers validate what they use."""

    def get_type(self) -> str: ...
    def get_srcSystem(self) -> int: ...
    def get_srcComponent(self) -> int: ...
    def get_msgId(self) -> int: ...
    def get_msgbuf(self) -> bytearray: ...
    def get_fieldnames(self) -> list[str]: ...
    def pack(self, mav: Any) -> bytes: ...
    def __getattr__(self, name: str) -> Any: ...
LOOPBACK = "127.0.0.1"


class PortBusyError(OSError):
    """The UDP port is already bound by another process."""


@dataclass
class LinkStats:
    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bad: int = 0  # undecodable bytes, wrong CRC, truncated
    rx_foreign: int = 0  # wrong system id
    rx_unsigned: int = 0  # refused by signing
    tx_messages: int = 0
    tx_errors: int = 0
    by_type: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "by_type"}


def is_loopback(host: str) -> bool:
    try:
        infos = socket.getaddrinfo(host, None)
    except socket.gaierror:
        return False
    import ipaddress

    return all(ipaddress.ip_address(i[4][0]).is_loopback for i in infos)


def bind_udp(local: Address, rcvbuf_bytes: int | None = None) -> socket.socket:
    """A non-blocking UDP socket bound to ``local``; :class:`PortBusyError` if the port is
    taken (the socket closed), any other OSError as it is. A socket the launcher bound for
    ``local`` and handed down (:mod:`heli_common.port_handoff`) is adopted instead."""
    sock = adopt(local)
    if sock is None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind(local)
        except OSError as exc:
            sock.close()
            if exc.errno == errno.EADDRINUSE:
                raise PortBusyError(exc.errno, f"UDP {local[0]}:{local[1]} is busy") from exc
            raise
    if rcvbuf_bytes is not None:  # takes effect after bind too (the queue's limit)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
    sock.setblocking(False)
    return sock


class MavlinkUdp(Closing):
    """One UDP socket speaking MAVLink 2.

    ``local`` is bound; datagrams go to ``remote`` (fixed) or, when ``remote`` is None, to
    every peer heard from (a vehicle answering ground stations). Only loopback addresses are
    accepted: this bench never sends off the machine.
    """

    def __init__(
        self,
        local: Address,
        remote: Address | None = None,
        *,
        system_id: int = 1,
        component_id: int = 1,
        accept_system: int | None = None,
        rcvbuf_bytes: int = 4 << 20,
        drop_nonfinite: bool = True,
    ) -> None:
        for host in [local[0]] + ([remote[0]] if remote else []):
            if not is_loopback(host):
                raise ValueError(f"{host}: only loopback addresses are allowed")
        self.remote = remote
        self.peers: list[Address] = [remote] if remote else []
        self.accept_system = accept_system
        # The sim link never carries NaN; on the GCS link NaN means "unset" in some fields
        # (COMMAND_LONG params, MAVSDK), so handlers validate what they use instead.
        self.drop_nonfinite = drop_nonfinite
        self.stats = LinkStats()
        self.mav = MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self.sock = bind_udp(local, rcvbuf_bytes)
        self.local = self.sock.getsockname()

    # -- context manager -------------------------------------------------------------


    def close(self) -> None:
        self.sock.close()

    def setup_signing(self, key: bytes, allow_unsigned: Callable[[int], bool]) -> None:
        """MAVLink 2 signing: sign what we send; accept unsigned messages only where
        ``allow_unsigned(msg_id)`` says so (wrongly signed ones never)."""
        if len(key) != 32:
            raise ValueError("a MAVLink signing key is 32 bytes")
        sig = self.mav.signing
        sig.secret_key = key
        sig.sign_outgoing = True
        sig.link_id = 0
        sig.allow_unsigned_callback = lambda _mav, msg_id: allow_unsigned(msg_id)
        # 10 us units since 2015-01-01, as pymavlink's mavutil does
        sig.timestamp = int(max(0.0, time.time() - 1420070400) * 100_000)

    # -- sending -----------------------------------------------------------------------
    def pack(self, msg: Message) -> bytes:
        """``msg``'s wire bytes, on this link's next sequence number (as pymavlink's
        ``MAVLink.send``): a receiver counts the gaps between sequence numbers as lost
        messages, so a link that repeated one number looked 99 % lossy to MAVProxy. A
        message whose fields do not pack raises and uses no number."""
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data

    def send(self, *msgs: Message, to: Address | None = None) -> None:
        """Pack ``msgs`` into one datagram for ``to`` (default: the remote or every peer)."""
        self.send_packed([self.pack(m) for m in msgs], to)

    def send_packed(self, frames: list[bytes], to: Address | None = None) -> None:
        """Messages already packed by :meth:`pack` on this link, in one datagram."""
        if frames:
            self.send_bytes(b"".join(frames), to)
            self.stats.tx_messages += len(frames)

    def send_bytes(self, data: bytes, to: Address | None = None) -> None:
        targets = [to] if to else self.peers
        for addr in targets:
            try:
                self.sock.sendto(data, addr)
            except OSError:
                # e.g. ECONNREFUSED from a peer that went away, or a full buffer: the
                # datagram is lost as UDP would lose it; the link layer above times out.
                self.stats.tx_errors += 1

    # -- receiving ---------------------------------------------------------------------
    def wait(self, timeout_s: float, spin_s: float = 0.0) -> bool:
        """Wait until a datagram is queued. ``spin_s`` first polls without sleeping: in
        lockstep the answer comes within ~100 us, and a sleeping vCPU takes longer than
        that to wake up, so a short spin doubles the lockstep rate. Each poll yields the
        core: on a machine with more runnable processes than cores (two lockstep flights
        on two cores) a spin that does not yield holds the core the answer is computed on,
        and two concurrent 60 s flights took 30 s each instead of 8 (measured)."""
        if spin_s > 0.0:
            end = time.perf_counter() + min(spin_s, timeout_s)
            while time.perf_counter() < end:
                r, _, _ = select.select([self.sock], [], [], 0.0)
                if r:
                    return True
                os.sched_yield()
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        return bool(r)

    def recv(
        self, timeout_s: float = 0.0, spin_s: float = 0.0, max_datagrams: int | None = None
    ) -> list[tuple[Message, Address]]:
        """Every valid message already queued (waiting up to ``timeout_s`` for the first);
        at most ``max_datagrams`` datagrams are read, the rest stay queued."""
        return [(m, addr) for data, addr in self.recv_datagrams(timeout_s, spin_s, max_datagrams)
                for m in self._parse(data)]  # fmt: skip

    def recv_datagrams(
        self, timeout_s: float = 0.0, spin_s: float = 0.0, max_datagrams: int | None = None
    ) -> list[tuple[bytes, Address]]:
        """Every datagram already queued, undecoded (for a caller with its own codec)."""
        out: list[tuple[bytes, Address]] = []
        if timeout_s > 0 and not self.wait(timeout_s, spin_s):
            return out
        while max_datagrams is None or len(out) < max_datagrams:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                self.stats.rx_bad += 1
                continue
            self.stats.rx_datagrams += 1
            if self.remote is None and addr not in self.peers:
                self.peers.append(addr)
            out.append((data, addr))
        return out

    def _parse(self, data: bytes) -> list[Message]:
        # Each datagram stands alone: forget any partial bytes a bad datagram left behind.
        self.mav.buf = bytearray()
        self.mav.buf_index = 0
        self.mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
        try:
            msgs = self.mav.parse_buffer(data) or []
        except Exception:  # pymavlink raises various errors on garbage even when robust
            self.stats.rx_bad += 1
            return []
        good: list[Message] = []
        for m in msgs:
            name = m.get_type()
            if name == "BAD_DATA":
                reason = str(getattr(m, "reason", ""))
                if "ign" in reason:  # "Invalid signature" / unsigned message refused
                    self.stats.rx_unsigned += 1
                else:
                    self.stats.rx_bad += 1
                continue
            if name.startswith("UNKNOWN") or (self.drop_nonfinite and not _finite_fields(m)):
                self.stats.rx_bad += 1
                continue
            if self.accept_system is not None and m.get_srcSystem() != self.accept_system:
                self.stats.rx_foreign += 1
                continue
            self.stats.rx_messages += 1
            self.stats.by_type[name] = self.stats.by_type.get(name, 0) + 1
            good.append(m)
        return good


def addressed_to(msg: Message, system_id: int, component_id: int) -> bool:
    """A request for this component: targeted at it, or broadcast (0) at either level."""
    ts = getattr(msg, "target_system", 0)
    tc = getattr(msg, "target_component", 0)
    return ts in (0, system_id) and tc in (0, component_id)


def _finite_fields(m: Message) -> bool:
    for name in m.get_fieldnames():
        v = getattr(m, name, None)
        if isinstance(v, float) and not math.isfinite(v):
            return False
        if isinstance(v, (list, tuple)):
            for e in v:
                if isinstance(e, float) and not math.isfinite(e):
                    return False
    return True


class TlogWriter(Closing):
    """pymavlink telemetry log: each record is a big-endian uint64 unix time [us] + the packet."""

    def __init__(self, path: Path, system_id: int = 1, component_id: int = 1) -> None:
        self.fh: BinaryIO = path.open("wb")
        self.mav = MAVLink(None, srcSystem=system_id, srcComponent=component_id)

    def write(self, t_unix_us: int, msgs: Iterable[Message]) -> None:
        for m in msgs:
            # received messages keep their wire bytes; new ones are empty
            buf = bytes(m.get_msgbuf()) or m.pack(self.mav)
            self.fh.write(struct.pack(">Q", t_unix_us) + buf)

    def close(self) -> None:
        self.fh.close()


