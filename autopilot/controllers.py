"""The controllers by name, for every command that flies (``--controller``).

A name is "tlc", "pid", or a user's class as ``"package.module:Class"`` or
``"path/to/file.py:Class"`` (:mod:`autopilot.user_controller` has the contract).
"""

from __future__ import annotations

from typing import Any

from autopilot.control import KernelController
from autopilot.controller_names import BUILT_IN
from autopilot.pid.controller import PIDController
from autopilot.pid.gains import PidGains, default_pid_gains
from autopilot.tlc.controller import Feedforward, TLController
from autopilot.tlc.gains import Gains
from autopilot.user_controller import UserController, is_user_spec, normalise_spec
from heli_common.config import ConfigError
from heli_common.vehicle.airframe import Airframe

CONTROLLERS = BUILT_IN

FlyingController = KernelController[Any] | UserController


def controller_arg(value: str) -> str:
    """argparse type of ``--controller``: the name checked (a user's class loaded once)."""
    import argparse

    try:
        return normalise_spec(value)
    except ConfigError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def build_controller(
    kind: str,
    airframe: Airframe,
    gains: Gains,
    rate_hz: float,
    feedforward: Feedforward | str = Feedforward.PSEUDO,
    pid_gains: PidGains | None = None,
    *,
    strict: bool = False,
) -> FlyingController:
    """``kind`` "tlc" (with ``gains`` and ``feedforward``), "pid" (with ``pid_gains``,
    default configs/gains_pid.toml), or a user's ``module:Class`` (``strict``: its exceptions
    propagate, as in-process; otherwise the last valid command is held, as a flying
    autopilot must)."""
    if is_user_spec(kind):
        return UserController(kind, airframe, rate_hz, strict=strict)
    return build_kernel_controller(kind, airframe, gains, rate_hz, feedforward, pid_gains)


def build_kernel_controller(
    kind: str,
    airframe: Airframe,
    gains: Gains,
    rate_hz: float,
    feedforward: Feedforward | str = Feedforward.PSEUDO,
    pid_gains: PidGains | None = None,
) -> KernelController[Any]:
    """A compiled controller ("tlc" or "pid"): what the loop's linearisation needs, since it
    reads and writes the controller's state vector (a user's class keeps its own)."""
    if kind == "tlc":
        return TLController(airframe, gains, rate_hz, feedforward)
    if kind == "pid":
        return PIDController(airframe, pid_gains or default_pid_gains(), rate_hz)
    if is_user_spec(kind):
        raise ConfigError(f"controller {kind!r}: margins and tuning need a compiled controller (tlc or pid); "
                          "they linearise its state vector, which a user's class keeps")  # fmt: skip
    normalise_spec(kind)  # raises, naming the forms
    raise AssertionError(kind)
