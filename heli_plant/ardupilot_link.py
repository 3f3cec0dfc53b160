"""The physics end of ArduPilot's JSON SITL backend: one UDP socket on loopback.

The firmware (``JSON::update``) sends a servo frame, then blocks until a state answer
arrives; it steps once per answer it parses. So the physics program steps once per NEW
frame and answers each exactly once. This class keeps that bookkeeping:

* :meth:`ArduPilotJsonLink.poll` returns only a frame with a new ``frame_count``. A frame
  whose ``frame_count`` was already seen is a re-send (``JSON::recv_fdm`` re-sends after
  about 1 s without an answer): ``poll`` itself sends the last answer again and returns
  None, so the caller never steps for it. If the caller has not answered that frame yet,
  nothing is sent (its coming answer is the answer).
* Every datagram queued is read; when several new frames are queued only the newest is
  returned (the older ones are counted ``superseded``). In lockstep at most one is ever
  queued; two mean the firmware took an extra (duplicate) answer as the answer to its next
  frame, and answering only the newest puts the two ends back in step.
* A ``frame_count`` that goes backwards, or a frame from a new address (a new firmware
  process has a new socket), is a reset: the frame is returned with
  :attr:`ArduPilotJsonLink.last_frame_was_reset` set, and the old answer is forgotten.
* :meth:`ArduPilotJsonLink.answer` sends to the address of the last valid frame.

Malformed datagrams are counted by reason in :class:`LinkCounters` and dropped; nothing
here raises on what arrives. Loopback only: the socket is bound to 127.0.0.1.
"""

from __future__ import annotations

import select
from dataclasses import dataclass, field

from heli_common.closing import Closing
from heli_common.wire.ardupilot_json import (
    MAX_DATAGRAM_BYTES,
    Refusal,
    RefusalReason,
    ServoFrame,
    parse_servo_packet,
)
from heli_common.wire.mavlink.udp import LOOPBACK, Address, bind_udp

__all__ = ["BASE_PORT", "ArduPilotJsonLink", "LinkCounters", "RefusedCounts", "port_for_instance"]

BASE_PORT = 9002  # SITL's default physics port; ``-I N`` adds 10 N
_COUNT_MOD = 1 << 32  # frame_count is a uint32


def port_for_instance(instance: int) -> int:
    """The UDP port ``arducopter -I instance --model JSON`` sends its servo frames to."""
    if instance < 0:
        raise ValueError(f"SITL instance {instance} is negative")
    return BASE_PORT + 10 * instance


@dataclass
class RefusedCounts:
    """Datagrams that were not servo frames, by :class:`RefusalReason`."""

    short: int = 0
    oversized: int = 0
    magic: int = 0
    frame_rate: int = 0

    def add(self, reason: RefusalReason) -> None:
        if reason is RefusalReason.SHORT:
            self.short += 1
        elif reason is RefusalReason.OVERSIZED:
            self.oversized += 1
        elif reason is RefusalReason.MAGIC:
            self.magic += 1
        else:
            self.frame_rate += 1

    @property
    def total(self) -> int:
        return self.short + self.oversized + self.magic + self.frame_rate


@dataclass
class LinkCounters:
    datagrams: int = 0  # every datagram read, valid or not
    frames: int = 0  # new frames returned by poll
    resends_answered: int = 0  # re-sent frames answered again with the last answer
    resends_unanswered: int = 0  # re-sent frames the caller had not answered yet: nothing sent
    superseded: int = 0  # new frames not returned because a newer one was queued behind
    skipped: int = 0  # frame_count values never seen (a gap in the count)
    resets: int = 0  # frame_count went backwards, or frames came from a new address
    answers: int = 0  # answers sent, re-sends included
    tx_errors: int = 0  # answers the socket refused to send
    rx_errors: int = 0  # socket errors while reading (not datagram contents)
    refused: RefusedCounts = field(default_factory=RefusedCounts)


class ArduPilotJsonLink(Closing):
    """UDP endpoint for one ArduPilot SITL instance (``--model JSON``), bound to
    127.0.0.1:``port``. Use as a context manager; see the module docstring for the rules."""

    def __init__(self, port: int = BASE_PORT, *, max_drain: int = 256) -> None:
        if max_drain < 1:
            raise ValueError("max_drain must be at least 1")
        self.max_drain = max_drain
        self.counters = LinkCounters()
        self.last_frame_was_reset = False  # the frame poll last returned starts a new session
        self._peer: Address | None = None
        # the newest frame read; between polls, the frame poll last returned (of this session)
        self._seen: ServoFrame | None = None
        self._answer: bytes | None = None  # the answer to ``_answered_count``
        self._answered_count: int | None = None
        self.sock = bind_udp((LOOPBACK, port))
        self.local: Address = self.sock.getsockname()

    @property
    def port(self) -> int:
        return self.local[1]

    @property
    def peer(self) -> Address | None:
        """Where the last valid frame came from: where answers go."""
        return self._peer

    def close(self) -> None:
        self.sock.close()

    # -- receiving -------------------------------------------------------------------------
    def _read(self) -> list[tuple[bytes, Address]]:
        out: list[tuple[bytes, Address]] = []
        while len(out) < self.max_drain:
            try:
                data, addr = self.sock.recvfrom(MAX_DATAGRAM_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.counters.rx_errors += 1
                break
            out.append((data, (str(addr[0]), int(addr[1]))))
        self.counters.datagrams += len(out)
        return out

    def _is_reset(self, frame: ServoFrame, addr: Address) -> bool:
        if self._seen is None:
            return False
        if addr != self._peer:
            return True
        delta = (frame.frame_count - self._seen.frame_count) % _COUNT_MOD
        return delta >= _COUNT_MOD // 2  # backwards (modulo the uint32's wrap)

    def poll(self, timeout_s: float = 0.0) -> ServoFrame | None:
        """Wait up to ``timeout_s`` for datagrams, read every one queued (at most
        ``max_drain``) and return the newest NEW frame, or None: on timeout, or when what
        arrived held no new frame (refused datagrams, a re-send, which poll answers itself
        with the last answer when the caller has answered that frame)."""
        try:
            ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        except (OSError, ValueError):  # a closed socket
            self.counters.rx_errors += 1
            return None
        if not ready:
            return None
        newest: ServoFrame | None = None
        reset = False
        resend = False
        for data, addr in self._read():
            frame = parse_servo_packet(data)
            if isinstance(frame, Refusal):
                self.counters.refused.add(frame.reason)
                continue
            if self._is_reset(frame, addr):
                self.counters.resets += 1
                reset = True
                self._seen = None
                self._answer = self._answered_count = None
            self._peer = addr
            if self._seen is not None and frame.frame_count == self._seen.frame_count:
                resend = newest is None  # a re-send of a frame already returned earlier
                continue
            if self._seen is not None:
                self.counters.skipped += (frame.frame_count - self._seen.frame_count - 1) % _COUNT_MOD
            if newest is not None:
                self.counters.superseded += 1
            newest = self._seen = frame
        if newest is not None:
            self.counters.frames += 1
            self.last_frame_was_reset = reset
            return newest
        if resend:
            answered = self._seen is not None and self._answered_count == self._seen.frame_count
            if self._answer is not None and answered:
                self._send(self._answer)
                self.counters.resends_answered += 1
            else:
                self.counters.resends_unanswered += 1
        return None

    # -- answering ---------------------------------------------------------------------------
    def answer(self, state: bytes) -> None:
        """Send ``state`` (from :func:`heli_common.wire.ardupilot_json.state_json`) as the answer
        to the frame poll last returned. Raises RuntimeError if poll has returned no frame
        (of this session) yet, ValueError if ``state`` is not newline-framed."""
        if self._seen is None or self._peer is None:
            raise RuntimeError("no servo frame to answer: poll() has not returned one")
        if not (state.startswith(b"\n") and state.endswith(b"\n")) or len(state) < 3:
            raise ValueError("a state answer is newline-framed: b'\\n' + JSON + b'\\n' (state_json)")
        self._answer = state
        self._answered_count = self._seen.frame_count
        self._send(state)

    def _send(self, data: bytes) -> None:
        assert self._peer is not None
        try:
            self.sock.sendto(data, self._peer)
        except OSError:
            self.counters.tx_errors += 1
            return
        self.counters.answers += 1
