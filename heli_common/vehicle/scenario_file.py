"""What the plant process needs from a scenario file: the airframe, initial state, rate.

The plant reads only its own part of ``configs/scenario_*.toml`` ([run] airframe and rate,
[initial_state]) so it does not depend on the controller's configuration.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heli_common.config import ConfigError, build, read_toml, spec
from heli_common.state import FloatArray, State
from heli_common.vehicle.airframe import Airframe


@dataclass(frozen=True)
class InitialState:
    pos_nwu_m: tuple[float, float, float] = spec("m", -1e6, 1e6)
    vel_flu_m_s: tuple[float, float, float] = spec("m/s", -100.0, 100.0, default=(0.0, 0.0, 0.0))
    euler_rad: tuple[float, float, float] = spec("rad", -7.0, 7.0, default=(0.0, 0.0, 0.0))
    omega_flu_rad_s: tuple[float, float, float] = spec("rad/s", -50.0, 50.0, default=(0.0, 0.0, 0.0))

    def state(self) -> State:
        return State(self.pos_nwu_m, self.vel_flu_m_s, self.euler_rad, self.omega_flu_rad_s)


def scenario_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    return p if p.suffix == ".toml" else Path(f"scenario_{name_or_path}.toml")


def load_vehicle(name_or_path: str | Path, on_ground: bool = False) -> tuple[Airframe, FloatArray, float]:
    path, table = read_toml(scenario_path(name_or_path))
    run = table.get("run")
    if not isinstance(run, dict):
        raise ConfigError(f"{path}: missing table [run]")
    airframe = Airframe.load(path.parent / str(run.get("airframe", "xcell60.toml")))
    rate = float(run.get("rate_hz", 100.0))
    if on_ground:
        return airframe, np.zeros(12), rate
    init = build(InitialState, table.get("initial_state", {}), f"{path}: initial_state")
    return airframe, init.state().to_array(), rate
