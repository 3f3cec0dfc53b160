"""Where a real-time tick's time goes: the wall time of each section of the tick, the
garbage collector's pauses, and for each skipped tick what made it late (the tick before it
overran, or the sleep woke late: the operating system's scheduling).

Read on the runner's injected clock (:class:`~autopilot.clock.Clock`), so a test drives it
with a fake clock. The per-tick cost is a handful of counter reads into preallocated arrays:
no object per tick that outlives it (nothing for the collector to rescan).
"""

from __future__ import annotations

import gc
import heapq
from collections.abc import Callable
from typing import Any

# the tick's sections in the order it runs them (autopilot.runner.Runner.tick)
SECTIONS = (
    "navigate",  # the estimator and the failsafes' inputs
    "control",  # the reference and the control law
    "record",  # the row into the recorder's block
    "send",  # the servo command out
    "services",  # flight logic after the command, telemetry build and the ground link
    "flush",  # run.csv streamed to disk every ``flush_every`` rows
)
N_SECTIONS = len(SECTIONS)
NAVIGATE, CONTROL, RECORD, SEND, SERVICES, FLUSH = range(N_SECTIONS)
WORST_KEPT = 5


class TickTimer:
    """Per-section wall time of each tick (max and mean), the worst ticks' breakdowns, the
    collector's pauses by generation, and the cause of each skipped tick."""

    def __init__(self, perf_counter: Callable[[], float]) -> None:
        self._now = perf_counter
        # plain lists: a few float operations a tick, cheaper than numpy's per-call overhead
        self._laps = [0.0] * N_SECTIONS
        self._t = 0.0
        self.ticks = 0
        self.max_s = [0.0] * N_SECTIONS
        self.sum_s = [0.0] * N_SECTIONS
        # (total, t, laps, gc) of the slowest ticks: a min-heap of WORST_KEPT
        self._worst: list[tuple[float, float, tuple[float, ...], float]] = []
        self.gc_count = [0, 0, 0]
        self.gc_max_s = [0.0, 0.0, 0.0]
        self._gc_start = 0.0
        self._gc_in_tick_s = 0.0
        self.skips: list[dict[str, float]] = []  # one per skip event (few: each is reported)

    # the collector, timed by its own callbacks (gc.callbacks), whenever it runs
    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._gc_start = self._now()
            return
        dt = self._now() - self._gc_start
        g = min(int(info.get("generation", 2)), 2)
        self.gc_count[g] += 1
        self.gc_max_s[g] = max(self.gc_max_s[g], dt)
        self._gc_in_tick_s += dt

    def __enter__(self) -> TickTimer:
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    def begin(self) -> None:
        self._gc_in_tick_s = 0.0
        self._t = self._now()

    def lap(self, section: int) -> None:
        """The section ``section`` (an index into SECTIONS) ended now."""
        now = self._now()
        self._laps[section] += now - self._t
        self._t = now

    def end(self, t_s: float) -> None:
        laps, mx, sm = self._laps, self.max_s, self.sum_s
        total = 0.0
        for i in range(N_SECTIONS):
            v = laps[i]
            total += v
            sm[i] += v
            if v > mx[i]:
                mx[i] = v
        self.ticks += 1
        if len(self._worst) < WORST_KEPT or total > self._worst[0][0]:
            item = (total, t_s, tuple(laps), self._gc_in_tick_s)
            if len(self._worst) < WORST_KEPT:
                heapq.heappush(self._worst, item)
            else:
                heapq.heapreplace(self._worst, item)
        self._laps = [0.0] * N_SECTIONS

    def skipped(self, t_s: float, late_s: float, overslept_s: float, prev_work_s: float) -> None:
        """A wake more than the allowed periods late: how late, how much of it the sleep
        overshot (the OS), and how long the tick before it worked."""
        self.skips.append({"t_s": t_s, "late_ms": late_s * 1e3, "overslept_ms": overslept_s * 1e3,
                           "prev_work_ms": prev_work_s * 1e3})  # fmt: skip

    @staticmethod
    def _tick_row(total: float, t_s: float, laps: tuple[float, ...], gc_s: float) -> dict[str, float]:
        row = {"t_s": t_s, "total_ms": total * 1e3, "gc_ms": gc_s * 1e3}
        row.update({f"{k}_ms": v * 1e3 for k, v in zip(SECTIONS, laps, strict=True)})
        return row

    def summary(self) -> dict[str, Any]:
        n = max(self.ticks, 1)
        return {
            "section_max_ms": {k: float(v * 1e3) for k, v in zip(SECTIONS, self.max_s, strict=True)},
            "section_mean_us": {k: float(v / n * 1e6) for k, v in zip(SECTIONS, self.sum_s, strict=True)},
            "worst_ticks": [self._tick_row(*w) for w in sorted(self._worst, reverse=True)],
            "gc_collections": list(self.gc_count),
            "gc_max_ms": [v * 1e3 for v in self.gc_max_s],
            "skips": list(self.skips),
        }
