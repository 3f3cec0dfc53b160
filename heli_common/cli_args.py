"""Argument types for every command line: a bad number is a usage error naming the option's
rule (argparse prints it with the usage line), never a traceback or a silent default."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _number(text: str, kind: type[float] | type[int]) -> float:
    try:
        value = kind(text)
    except ValueError:
        what = "an integer" if kind is int else "a number"
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def in_range(
    lo: float, hi: float, kind: type[float] | type[int] = float, lo_open: bool = False
) -> Callable[[str], float]:
    """A number in [lo, hi] (or (lo, hi] with ``lo_open``)."""

    def parse(text: str) -> float:
        v = _number(text, kind)
        if v < lo or v > hi or (lo_open and v == lo):
            raise argparse.ArgumentTypeError(f"{text} is outside {'(' if lo_open else '['}{lo:g}, {hi:g}]")
        return v

    parse.__name__ = f"number in [{lo:g}, {hi:g}]"
    return parse


def positive(text: str) -> float:
    """A finite number > 0 (a duration, a timeout)."""
    v = _number(text, float)
    if v <= 0.0:
        raise argparse.ArgumentTypeError(f"{text} must be > 0")
    return v


def port(text: str) -> int:
    """A UDP port to send to: 1-65535."""
    return int(in_range(1, 65535, int)(text))


def bind_port(text: str) -> int:
    """A UDP port to bind: 1-65535, or 0 for any free one."""
    return int(in_range(0, 65535, int)(text))


def count(text: str) -> int:
    """A whole number >= 1."""
    return int(in_range(1, 1_000_000, int)(text))


#: control rates the controller supports
control_rate_hz = in_range(50.0, 1000.0)
#: physics rates a real-time plant may run at (twice the control rate, typically)
physics_rate_hz = in_range(50.0, 4000.0)
