"""Benchmarks: ``python -m benchmarks`` (``make bench``) prints one table.

A benchmark is a function returning a list of :class:`Row`, registered with :func:`bench`
in a module listed in :data:`MODULES`. To add rows, write such a function (in
``bench_sim.py`` or a new module added to ``MODULES``); the runner times nothing itself.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import heli_common  # noqa: F401  (first: one BLAS thread, as every process of ours has)


class Row(NamedTuple):
    name: str
    value: float
    unit: str
    target: str = ""  # human-readable goal, e.g. "< 50"
    ok: bool | None = None  # whether the value meets the target (None: informational)


BenchFn = Callable[[], list[Row]]
REGISTRY: list[tuple[str, BenchFn]] = []
MODULES = (
    "benchmarks.bench_sim",
    "benchmarks.bench_estimator",
    "benchmarks.bench_can",
    "benchmarks.bench_processes",
    "benchmarks.bench_campaign",
    "benchmarks.bench_user_controller",
    "benchmarks.bench_mcap",
    "benchmarks.bench_gym",
)


def bench(title: str) -> Callable[[BenchFn], BenchFn]:
    """Register ``fn`` under ``title``; the table lists registries in import order."""

    def deco(fn: BenchFn) -> BenchFn:
        REGISTRY.append((title, fn))
        return fn

    return deco


def below(value: float, limit: float) -> tuple[str, bool]:
    return f"< {limit:g}", value < limit


def above(value: float, limit: float) -> tuple[str, bool]:
    return f"> {limit:g}", value > limit
