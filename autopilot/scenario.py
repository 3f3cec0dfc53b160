"""A scenario: airframe, gains, trajectory, initial state, duration, rate, feedforward mode,
its own error windows."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from autopilot.tlc.controller import Feedforward
from autopilot.tlc.gains import Gains
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.factory import trajectory_from_table
from heli_common.airframe import Airframe
from heli_common.config import ConfigError, build, read_toml, spec
from heli_common.scenario_file import InitialState, scenario_path


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
            airframe=Airframe.load(base / run.airframe),
            gains=Gains.load(base / run.gains if gains is None else gains),
            trajectory=trajectory_from_table(table["trajectory"], src),
            initial=build(InitialState, table["initial_state"], f"{src}: initial_state"),
            source=path,
        )
