"""The clock the control loop reads and sleeps on (:mod:`heli_common.clock`, shared with
the plant's pacer).

The runner's scheduling (deadlines, overruns, skipped ticks, stall recovery) depends only
on what the clock says, so tests drive it with a fake clock whose time they move by hand,
with no real sleeping; the processes use :class:`SystemClock`, the ``time`` module itself.
"""

from __future__ import annotations

from heli_common.clock import Clock, SystemClock

__all__ = ["Clock", "SystemClock"]
