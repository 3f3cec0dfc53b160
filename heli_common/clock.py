"""The clock a loop reads and sleeps on, as a small contract.

Scheduling that depends only on what the clock says (the autopilot runner's deadlines,
overruns, skipped ticks and stall recovery; the plant's pacer, which waits for a ground
station and releases a silent one) is tested on a fake clock whose time the test moves by
hand, with no real sleeping; the processes use :class:`SystemClock`, the ``time`` module
itself. Here, on the floor both the plant and the autopilot stand on (neither imports the
other).
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Monotonic time for scheduling, a sleep, and a fine counter for measuring work."""

    def monotonic(self) -> float:
        """Seconds from an arbitrary origin; never goes back."""
        ...

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` (at least)."""
        ...

    def perf_counter(self) -> float:
        """The highest-resolution seconds counter, for durations only."""
        ...


class SystemClock:
    """The real clocks of the ``time`` module."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def perf_counter(self) -> float:
        return time.perf_counter()
