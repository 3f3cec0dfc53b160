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


def add_instance_args(p: argparse._ActionsContainer, sysid: bool = True) -> None:
    """``--instance N`` (ArduPilot's convention: every default port + 10 N, so several
    vehicles run on one host) and ``--sysid`` (default 1 + N: a ground station tells the
    vehicles apart by system id)."""
    p.add_argument("--instance", type=in_range(0, 99, int), default=0,
                   help="vehicle instance N: every default port + 10 N (default 0)")
    if sysid:
        p.add_argument("--sysid", type=in_range(1, 250, int), default=None,
                       help="MAVLink system id of the vehicle (default 1 + instance)")


def resolve_instance(args: argparse.Namespace, port_options: dict[str, str]) -> None:
    """Fill the port options left unset (None) from the instance's defaults, and the sysid.

    ``port_options`` maps an option's dest (``gcs_port``) to a field of
    :class:`heli_common.defaults.Ports` (``gcs``)."""
    from heli_common.defaults import ports

    if not hasattr(args, "instance"):  # a subcommand without ports (e.g. plot)
        return
    defaults = ports(int(args.instance))
    for dest, field in port_options.items():
        if getattr(args, dest, None) is None:
            setattr(args, dest, getattr(defaults, field))
    if hasattr(args, "sysid") and args.sysid is None:
        args.sysid = 1 + int(args.instance)
