"""A scenario: airframe, gains, trajectory, initial state, duration, rate, feedforward mode,
its own error windows."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from autopilot.tlc.controller import Feedforward
from autopilot.tlc.gains import Gains
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.factory import trajectory_from_table
from heli_common.config import ConfigError, build, read_toml, spec
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.scenario_file import InitialState, scenario_path


@dataclass(frozen=True)
class Run:
    name: str = spec()
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True)
    airframe: str = spec(default="xcell60.toml")
    gains: str = spec(default="gains_paper.toml")
    rate_hz: float = spec("Hz", 50.0, 1000.0, default=100.0)
    feedforward: str = spec(choices=("pseudo", "exact"), default="pseudo")
    plant_substeps: int = spec("", 1, 1000, default=1)
    # the scenario's own error windows, [t0, t1] pairs of trajectory time [s] (e.g. the
    # transient after a step, then the steady state), for whoever scores its flights:
    # autopilot.metrics.window_rms_m(record, t0, t1) each. Optional (none by default); a
    # window past the flown end is measured over the ticks it has (NaN if none)
    error_windows_s: tuple[tuple[float, float], ...] = spec("s", 0.0, 1e5, default=())

    def __post_init__(self) -> None:
        for t0, t1 in self.error_windows_s:
            if not t0 < t1:
                raise ValueError(f"error_windows_s: a window [t0, t1] needs t0 < t1, got [{t0}, {t1}]")


@dataclass(frozen=True)
class Scenario:
    run: Run
    airframe: Airframe
    gains: Gains
    trajectory: Trajectory
    initial: InitialState
    source: Path = field(default=Path("."))

    @property
    def feedforward(self) -> Feedforward:
        return Feedforward(self.run.feedforward)

    @classmethod
    def load(cls, name_or_path: str | Path, gains: str | Path | None = None) -> Scenario:
        """Load ``configs/scenario_<name>.toml`` (or a path) and the files it names;
        ``gains`` (a file, or a name in configs/) replaces the scenario's gain set."""
        path, table = read_toml(scenario_path(name_or_path))
        src = str(path)
        for key in ("run", "trajectory", "initial_state"):
            if not isinstance(table.get(key), dict):
                raise ConfigError(f"{src}: missing table [{key}]")
        extra = set(table) - {"run", "trajectory", "initial_state"}
        if extra:
            raise ConfigError(
                f"{src}: unknown table(s) {sorted(extra)}; expected run, trajectory, initial_state"
            )
        run = build(Run, table["run"], f"{src}: run")
        base = path.parent
        return cls(
            run=run,
            airframe=Airframe.load(_beside(base, run.airframe)),
            gains=Gains.load(_beside(base, run.gains) if gains is None else gains),
            trajectory=trajectory_from_table(table["trajectory"], src),
            initial=build(InitialState, table["initial_state"], f"{src}: initial_state"),
            source=path,
        )

    def flying(self, trajectory: Trajectory) -> Scenario:
        """This scenario flying ``trajectory`` instead, from its first point: the position, the
        velocity and (moving) the heading of its first reference row, level. (A trajectory
        flown from the scenario's own initial state would start wherever that is: the paper's
        is 5.2 m off its spiral.)"""
        ref = np.asarray(trajectory.sample(np.array([0.0])), dtype=float)[0]
        pos, vel = ref[0:3], ref[3:6]
        speed_h = math.hypot(vel[0], vel[1])
        psi = math.atan2(vel[1], vel[0]) if speed_h > 0.1 else float(self.initial.euler_rad[2])
        c, s = math.cos(psi), math.sin(psi)  # earth NWU -> body FLU, level
        body = (c * vel[0] + s * vel[1], -s * vel[0] + c * vel[1], float(vel[2]))
        start = InitialState(pos_nwu_m=(float(pos[0]), float(pos[1]), float(pos[2])),
                             vel_flu_m_s=(float(body[0]), float(body[1]), float(body[2])),
                             euler_rad=(0.0, 0.0, psi))  # fmt: skip
        return dataclasses.replace(self, trajectory=trajectory, initial=start)


def _beside(base: Path, name: str) -> Path | str:
    """A file a scenario names: beside the scenario, else by its name (configs/), so that a
    scenario copied out of configs/ still finds the shipped airframe and gains."""
    here = base / name
    return here if here.exists() or Path(name).is_absolute() else name
