"""Every setting a campaign can vary, by its dotted name, applied to the base flight.

Roots (each a frozen dataclass the rest of the bench already loads and validates):

* ``world.*``: the world file's tree (``world.wind.speed_m_s``, ``world.servos.tau_s``,
  ``world.mismatch.mass``, ``world.sensors.gps.noise_h_m``, ``world.seed``); aliases
  ``plant.mismatch.*``, ``servo.*`` / ``servos.*`` and ``sensors.*`` name the same;
* ``gains.*``: the TLC's gain set (``gains.loop4.omega_rad_s``: ``loopN`` is loop N's table);
* ``pid.*``: the PID baseline's gains (``pid.rate.kp``, ``pid.velocity.ki[2]``), for a
  campaign with ``controller = "pid"``;
* ``estimator.*``: the estimator's tuning;
* ``run.*``: the scenario's run table (``run.rate_hz``, ``run.plant_substeps``);
* ``plant.*``: the flying plant's file tree, on a plant with a rotor (``plant =
  "gavrilets"``): ``plant.flapping.lon_gain_rad_per_rad``, ``plant.flapping.hub_stiffness_n_m_per_rad``,
  ``plant.flapping.stabilizer_bar_lock_number``, ``plant.main_rotor.speed_rad_s``, ... The
  controller keeps its design model (a rotor-aware gain set names its own ``design_plant``):
  this is the uncertainty of the plant alone. (``plant.mismatch.*`` is ``world.mismatch.*``);
* ``initial.*``: the initial state's fields, and three derived ones:
  ``initial.pos_offset_m`` (the start's distance from the trajectory's first point, along
  the scenario's own offset direction: 5.196 m is the paper's (3, -3, 3) m),
  ``initial.yaw_error_rad`` (added to the scenario's initial yaw) and
  ``initial.speed_m_s`` (initial forward body velocity).

A tuple-valued setting takes one number for all its elements (``world.servos.tau_s`` sets
all four servos), or an element by index (``world.servos.tau_s[2]``). A value is applied by
rebuilding its root through the same validated loader as a file, so a bad value fails
with the setting's name and range.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.pid.gains import PidGains, default_pid_gains
from autopilot.scenario import Scenario
from heli_common.config import ConfigError, as_table, build
from heli_common.vehicle.plant_model import PlantModel
from heli_common.vehicle.scenario_file import InitialState
from heli_common.world.config import World

ROOTS = ("world", "gains", "pid", "estimator", "run", "initial", "plant")
ALIASES = {
    "plant.mismatch.": "world.mismatch.",
    "servo.": "world.servos.",
    "servos.": "world.servos.",
    "sensors.": "world.sensors.",
}
LOOPS = {
    "loop1": "loop1_position_kinematics",
    "loop2": "loop2_position_dynamics",
    "loop3": "loop3_attitude_kinematics",
    "loop4": "loop4_attitude_dynamics",
}
DERIVED = ("initial.pos_offset_m", "initial.yaw_error_rad", "initial.speed_m_s")
_INDEX = re.compile(r"^(.*)\[(\d+)\]$")
T = TypeVar("T")


@dataclass(frozen=True)
class FlightSetup:
    """Everything one flight needs, as the in-process simulator and the launchers take it."""

    scenario: Scenario
    world: World
    estimator: EstimatorConfig
    controller: str = "tlc"  # "pid", or a user's "module:Class" (autopilot.user_controller)
    pid_gains: PidGains | None = None  # None: configs/gains_pid.toml
    plant: PlantModel = PlantModel("paper")


def canonical(key: str) -> str:
    """The setting's full name (aliases and ``loopN`` expanded)."""
    for short, full in ALIASES.items():
        if key.startswith(short):
            key = full + key[len(short) :]
            break
    parts = key.split(".")
    if parts[0] == "gains" and len(parts) > 1 and parts[1] in LOOPS:
        parts[1] = LOOPS[parts[1]]
    return ".".join(parts)


def _set(table: dict[str, Any], path: list[str], value: float, key: str) -> None:
    node: Any = table
    for i, name in enumerate(path):
        m = _INDEX.match(name)
        field_name, index = (m.group(1), int(m.group(2))) if m else (name, None)
        if not isinstance(node, dict) or field_name not in node:
            where = ".".join(path[: i + 1])
            raise ConfigError(f"{key}: no such setting ({where!r} is not in the table)")
        if i < len(path) - 1:
            if index is not None:
                raise ConfigError(f"{key}: an index only on the last part")
            node = node[field_name]
            continue
        old = node[field_name]
        if isinstance(old, dict):
            raise ConfigError(f"{key}: a table, not a number: name one of its keys ({', '.join(old)})")
        if isinstance(old, list):
            if index is None:
                node[field_name] = [_typed(o, value, key) for o in old]
            elif index < len(old):
                old[index] = _typed(old[index], value, key)
            else:
                raise ConfigError(f"{key}: index {index} out of range (it has {len(old)} values)")
        elif index is not None:
            raise ConfigError(f"{key}: not an array, no index")
        else:
            node[field_name] = _typed(old, value, key)


def _typed(old: Any, value: float, key: str) -> Any:
    """``value`` in the type the setting has (a bool from 0/1, an int from a whole number)."""
    if isinstance(old, bool):
        if value not in (0.0, 1.0):
            raise ConfigError(f"{key}: a switch takes 0 or 1, got {value:g}")
        return value == 1.0
    if isinstance(old, int):
        if value != round(value):
            raise ConfigError(f"{key}: a whole number, got {value:g}")
        return int(round(value))
    if isinstance(old, str):
        raise ConfigError(f"{key}: a text setting cannot be varied by number")
    return float(value)


def _rebuilt(obj: T, values: dict[str, float]) -> T:
    """``obj`` (a config dataclass) with the settings set, through its validated loader."""
    t = as_table(obj)
    t.pop("source", None)
    for key, v in values.items():
        _set(t, key.split(".")[1:], v, key)
    return build(type(obj), t, f"campaign: {next(iter(values)).split('.')[0]}")


def apply(base: FlightSetup, values: dict[str, float]) -> FlightSetup:
    """``base`` with each setting (full names, see :func:`canonical`) set."""
    by_root: dict[str, dict[str, float]] = {}
    for key, v in values.items():
        root = key.split(".", 1)[0]
        if root not in ROOTS or "." not in key:
            raise ConfigError(f"{key}: unknown setting; it must start with one of {', '.join(ROOTS)}")
        by_root.setdefault(root, {})[key] = v
    sc, world, est, pid = base.scenario, base.world, base.estimator, base.pid_gains
    if "world" in by_root:
        w = _rebuilt(world, by_root["world"])
        w = dataclasses.replace(w, source=world.source, sensors=dataclasses.replace(w.sensors, seed=w.seed))
        if w.air_matters and not (w.air.fuselage or w.air.rotor_inflow):
            raise ConfigError(
                "world: wind, gust or turbulence varied, but the base world's [air] has neither "
                "fuselage nor rotor_inflow on: the air would not act on the vehicle"
            )
        world = w
    if "gains" in by_root:
        sc = dataclasses.replace(sc, gains=_rebuilt(sc.gains, by_root["gains"]))
    if "pid" in by_root:
        pid = _rebuilt(pid or default_pid_gains(), by_root["pid"])
    if "estimator" in by_root:
        est = _rebuilt(est, by_root["estimator"])
    if "run" in by_root:
        sc = dataclasses.replace(sc, run=_rebuilt(sc.run, by_root["run"]))
    if "initial" in by_root:
        sc = dataclasses.replace(sc, initial=_initial(sc, by_root["initial"]))
    plant = base.plant
    if "plant" in by_root:
        if plant.rotor is None:
            key = next(iter(by_root["plant"]))
            raise ConfigError(f"{key}: the paper's plant has no rotor constants to vary; fly a plant with "
                              'a rotor (plant = "gavrilets")')  # fmt: skip
        plant = dataclasses.replace(plant, rotor=_rebuilt(plant.rotor, by_root["plant"]))
    return FlightSetup(sc, world, est, base.controller, pid, plant)


def _initial(sc: Scenario, values: dict[str, float]) -> InitialState:
    t = as_table(sc.initial)
    start = np.asarray(sc.trajectory.sample(0.0)[0, 0:3])
    pos = np.asarray(sc.initial.pos_nwu_m, dtype=float)
    for key, v in values.items():
        if key == "initial.pos_offset_m":
            if v < 0.0:
                raise ConfigError(f"{key}: a distance, >= 0, got {v:g}")
            off = pos - start
            norm = float(np.linalg.norm(off))
            unit = off / norm if norm > 0.0 else np.array([1.0, 0.0, 0.0])
            t["pos_nwu_m"] = (start + v * unit).tolist()
        elif key == "initial.yaw_error_rad":
            t["euler_rad"][2] = float(sc.initial.euler_rad[2] + v)
        elif key == "initial.speed_m_s":
            t["vel_flu_m_s"] = [float(v), 0.0, 0.0]
        else:
            _set(t, key.split(".")[1:], v, key)
    return build(InitialState, t, "campaign: initial")


def check(base: FlightSetup, key: str, probes: list[float]) -> None:
    """Refuse a setting that does not exist, or whose probe values are out of range."""
    full = canonical(key)
    for v in probes:
        if math.isfinite(v):
            try:
                apply(base, {full: v})
            except ConfigError as exc:
                text = str(exc)
                raise ConfigError(
                    text if text.startswith(full) or text.startswith(key) else f"{key}: {text}"
                ) from exc
