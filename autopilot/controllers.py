"""The controllers by name, for every command that flies (``--controller tlc|pid``)."""

from __future__ import annotations

from typing import Any

from autopilot.control import KernelController
from autopilot.pid.controller import PIDController
from autopilot.pid.gains import PidGains, default_pid_gains
from autopilot.tlc.controller import Feedforward, TLController
from autopilot.tlc.gains import Gains
from heli_common.airframe import Airframe

CONTROLLERS = ("tlc", "pid")
CONTROLLER_HELP = "the paper's TLC, or the cascaded PID baseline (configs/gains_pid.toml)"


def build_controller(
    kind: str,
    airframe: Airframe,
    gains: Gains,
    rate_hz: float,
    feedforward: Feedforward | str = Feedforward.PSEUDO,
    pid_gains: PidGains | None = None,
) -> KernelController[Any]:
    """``kind`` "tlc" (with ``gains`` and ``feedforward``) or "pid" (with ``pid_gains``,
    default configs/gains_pid.toml)."""
    if kind == "tlc":
        return TLController(airframe, gains, rate_hz, feedforward)
    if kind == "pid":
        return PIDController(airframe, pid_gains or default_pid_gains(), rate_hz)
    raise ValueError(f"controller must be one of {', '.join(CONTROLLERS)}, got {kind!r}")
