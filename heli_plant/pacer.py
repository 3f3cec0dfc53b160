"""A ground station in the lockstep: the physics waits for a client that streams on its clock.

ArduPilot's JSON SITL is lockstep between the firmware and the physics: the firmware waits
for each answer. A ground station that streams setpoints on the vehicle's clock
(``heli-ground fly --guided``) is outside that loop: with ``--speedup 10`` on a loaded
machine, a tenth of a second without the CPU is a second of flight without setpoints, and
ArduPilot stops following after GUID_TIMEOUT. The pacer closes the loop: a client sends,
to UDP ``port_for_instance(N) + PACE_PORT_OFFSET``, the physics time up to which it is
ready (one little-endian float64 [s]); the physics does not step past it. A NaN or +inf
releases the physics; so does a client silent for ``release_after_s`` of wall time (a
ground station that died must not freeze the simulation). Without a client nothing waits.

The pacer reads the time on an injected :class:`~heli_common.clock.Clock` (the ``time``
module's by default): the clock says when a silent client is given up and how long the
physics waited; a datagram wakes the wait at once. Tests drive it on a fake clock.
"""

from __future__ import annotations

import math
import select
from dataclasses import dataclass

from heli_common.clock import Clock, SystemClock
from heli_common.closing import Closing
from heli_common.wire.ardupilot_json import PACE as _PACE
from heli_common.wire.ardupilot_json import PACE_PORT_OFFSET, encode_pace
from heli_common.wire.mavlink.udp import LOOPBACK, bind_udp

__all__ = ["PACE_PORT_OFFSET", "Pacer", "PacerCounts", "encode_pace"]


@dataclass
class PacerCounts:
    datagrams: int = 0
    refused: int = 0  # not 8 bytes
    waits: int = 0  # steps that waited for the client
    wait_s: float = 0.0  # time spent waiting, on the pacer's clock
    releases: int = 0  # a client released the physics, or went silent


class Pacer(Closing):
    """Bound to 127.0.0.1:``port`` (0: a free port the system picks, read from ``sock``);
    ``wait_until(t)`` before stepping to physics time ``t``."""

    def __init__(self, port: int, release_after_s: float = 5.0, clock: Clock | None = None) -> None:
        self.sock = bind_udp((LOOPBACK, port))
        self.release_after_s = release_after_s
        self.clock: Clock = SystemClock() if clock is None else clock
        self.until_s: float | None = None  # None: no client, nothing waits
        self.counts = PacerCounts()
        self._last_heard = 0.0

    def close(self) -> None:
        self.sock.close()

    def _read(self) -> None:
        while True:
            try:
                data = self.sock.recv(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.counts.refused += 1
                return
            self.counts.datagrams += 1
            if len(data) != _PACE.size:
                self.counts.refused += 1
                continue
            (t,) = _PACE.unpack(data)
            self._last_heard = self.clock.monotonic()
            if math.isnan(t) or math.isinf(t):
                if self.until_s is not None:
                    self.counts.releases += 1
                self.until_s = None
            else:
                self.until_s = t if self.until_s is None else max(self.until_s, t)

    def wait_until(self, t_s: float) -> None:
        """Return once the client is ready for physics time ``t_s`` (at once without one)."""
        self._read()
        if self.until_s is None or t_s <= self.until_s:
            return
        self.counts.waits += 1
        w0 = self.clock.monotonic()
        while self.until_s is not None and t_s > self.until_s:
            left = self._last_heard + self.release_after_s - self.clock.monotonic()
            if left <= 0.0:  # a silent client: run free
                self.until_s = None
                self.counts.releases += 1
                break
            select.select([self.sock], [], [], min(left, 0.5))
            self._read()
        self.counts.wait_s += self.clock.monotonic() - w0
