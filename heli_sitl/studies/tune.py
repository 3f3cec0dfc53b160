"""Tuning a controller's gains on the paper scenario, the same way for every controller.

A comparison is only fair if both contenders were tuned by the same procedure with the
same budget under the same limits. :func:`tune` is that procedure:

* **Knobs.** A controller's gains are reduced to a dozen knobs, each a gain (or the same
  gain of several channels: x and y, roll and pitch share one, since the scenario has no
  preferred horizontal direction) between bounds: a tenth to ten times the starting value
  on a log scale, or a range on a linear scale for the damping ratios (0.3-2) and for a
  gain that starts at zero (the PID's derivative, 0-1). The tilt limit, the rate limits
  and the pitch limits are not knobs: both controllers keep the same ones.
* **Flights.** Each candidate flies the scenario in-process three times: in the ideal
  world, with the hobby servos of ``configs/world/servos-default.toml`` (10 ms delay, 20 ms
  lag, rate limits), and in ``configs/world/everything.toml`` (those servos, 3 m/s of wind
  with turbulence and a gust, 10 % more mass and inertia, 3 % less rotor speed, a sine
  force). Gains that only work in the ideal world are worthless on a real helicopter:
  tuned on it alone, both controllers' optimisers bought tracking with loops a real servo
  or a heavier airframe cannot follow (docs/comparison.md).
* **Cost.** Per flight: the RMS 3-D position error from 10 s to the end (the tracking once
  the start's 5.2 m offset is worked off, the climb-to-circle break included) plus 1 m
  times the fraction of ticks with a saturated pitch; a flight whose state is not finite
  costs 100 m. The candidate's cost is the worst of its flights.
* **Optimiser.** On the knobs scaled to [0, 1]: differential evolution (scipy.optimize, a
  fixed seed, the shipped gains in its first population) for 60 % of a fixed number of
  cost evaluations, global enough for the rough landscape servo saturation makes, then
  Nelder-Mead (adaptive) from its best point for the rest.

* **Robustness constraint** (``--min-disk-margin``, off by default): before a candidate flies,
  its whole closed loop is linearised at hover on the constraint's plant with its servos
  (:mod:`heli_sitl.engine.loop_linear`, default the rotor plant with the default servos); a candidate
  whose worst disk margin over every loop break point is below the bound costs
  ``CONSTRAINT_COST_M`` plus ten times the shortfall (so the optimiser still sees the way to
  feasibility) and does not fly. 0.66 is +/- 6 dB and +/- 36 deg.
* **Seeds**: ``--seed`` sets the optimiser's; run several and compare their costs (the spread
  says how much of a result is the optimiser's luck).

``heli-sitl tune --controller pid|tlc`` runs it and writes the gains file; docs/comparison.md
gives the procedure, the budget and what it found.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution, minimize

from autopilot.controllers import build_kernel_controller
from autopilot.design_point import MIN_DISK_MARGIN
from autopilot.flight_metrics import FlightMetrics
from autopilot.pid.gains import PidGains, default_pid_gains
from autopilot.scenario import Scenario
from heli_common.config import as_table, build, to_toml
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.engine.loop_linear import linearize_loop, servo_model

#: the worlds every candidate flies ("" is the paper's ideal world)
TUNING_WORLDS = ("", "servos-default", "everything")
DIVERGED_COST_M = 100.0
CONSTRAINT_COST_M = 50.0  # plus 10 m per unit of disk margin short: below DIVERGED_COST_M
SPAN = 10.0  # a log knob's range: its start / SPAN to its start x SPAN
SATURATION_WEIGHT_M = 1.0
#: an unstable loop's shortfall grows with its spectral radius past 1 (per tick: 0.01 is a
#: mode growing at 1 /s at 100 Hz), a loop with no hover equilibrium's is larger still
UNSTABLE_SLOPE = 10.0
NO_EQUILIBRIUM_SHORTFALL = 2.0
#: the trajectories every candidate flies: the paper's, and a held-out one that turns both
#: ways at 5 m/s (the others judge the result: docs/comparison.md)
TUNING_SCENARIOS = ("paper", "figure_eight")


@dataclass(frozen=True)
class Knob:
    """One tuned quantity: ``section.field`` of the gains, elements ``index`` (all set to the
    same value; empty for a scalar), searched between ``lo`` and ``hi``."""

    section: str
    field: str
    index: tuple[int, ...]
    lo: float
    hi: float
    log: bool = True

    @property
    def name(self) -> str:
        return f"{self.section}.{self.field}" + (f"[{','.join(map(str, self.index))}]" if self.index else "")

    def to_unit(self, v: float) -> float:
        if self.log:
            return math.log(v / self.lo) / math.log(self.hi / self.lo)
        return (v - self.lo) / (self.hi - self.lo)

    def from_unit(self, u: float) -> float:
        u = min(max(u, 0.0), 1.0)
        if self.log:
            return float(self.lo * (self.hi / self.lo) ** u)
        return float(self.lo + u * (self.hi - self.lo))


def _get(gains: Any, k: Knob) -> float:
    v = getattr(getattr(gains, k.section), k.field)
    return float(v[k.index[0]] if k.index else v)


def with_knobs(gains: Any, knobs: Sequence[Knob], values: Sequence[float]) -> Any:
    """``gains`` with every knob set, rebuilt through the gains' validated loader."""
    t = as_table(gains)
    for k, v in zip(knobs, values, strict=True):
        node = t[k.section]
        if k.index:
            for i in k.index:
                node[k.field][i] = float(v)
        else:
            node[k.field] = float(v)
    return build(type(gains), t, "tuning")


def _around(gains: Any, section: str, fld: str, index: tuple[int, ...], *, lo: float = 0.0,
            hi: float = 0.0) -> Knob:  # fmt: skip
    """A knob from its start / SPAN to its start x SPAN on a log scale; ``lo``/``hi`` given: linear."""
    if hi > lo:
        return Knob(section, fld, index, lo, hi, log=False)
    k = Knob(section, fld, index, 1.0, 1.0)
    v = _get(gains, k)
    return Knob(section, fld, index, v / SPAN, v * SPAN)


H, Z, RP, Y, ALL = (0, 1), (2,), (0, 1), (2,), (0, 1, 2)
TLC_LOOPS = (
    "loop1_position_kinematics",
    "loop2_position_dynamics",
    "loop3_attitude_kinematics",
    "loop4_attitude_dynamics",
)


def tlc_knobs(gains: Any) -> tuple[Knob, ...]:
    """13 knobs: each loop's omega (horizontal or roll/pitch; vertical or yaw) and zeta (all
    channels, 0.3-2), and the pseudo-differentiator's omega; the rotor-aware TLC's loop 5 rate
    a 14th."""
    out: list[Knob] = []
    for loop in TLC_LOOPS:
        out += [_around(gains, loop, "omega_rad_s", H), _around(gains, loop, "omega_rad_s", Z)]
    out += [_around(gains, loop, "zeta", ALL, lo=0.3, hi=2.0) for loop in TLC_LOOPS]
    out.append(_around(gains, "differentiator", "omega_rad_s", ()))
    if getattr(gains, "rotor", None) is not None:  # the rotor-aware TLC: loop 5's rate too
        out.append(_around(gains, "rotor", "flapping_rate_rad_s", ()))
    return tuple(out)


def pid_knobs(gains: Any) -> tuple[Knob, ...]:
    """13 knobs: the position P, velocity P and I, attitude P, rate P and I (horizontal or
    roll/pitch; vertical or yaw each) and the roll/pitch rate D (0-1)."""
    out: list[Knob] = []
    for section, fld in (("position", "kp"), ("velocity", "kp"), ("velocity", "ki"), ("attitude", "kp"),
                         ("rate", "kp"), ("rate", "ki")):  # fmt: skip
        out += [_around(gains, section, fld, H), _around(gains, section, fld, Z)]
    out.append(_around(gains, "rate", "kd", RP, lo=0.0, hi=1.0))
    return tuple(out)


@dataclass(frozen=True)
class FlightCost:
    world: str
    rms_10_m: float
    rms_45_m: float
    max_err_10_m: float
    saturated_fraction: float
    cost_m: float
    scenario: str = "paper"

    def describe(self) -> str:
        sat = 100 * self.saturated_fraction
        where = self.world if self.scenario == "paper" else f"{self.scenario}, {self.world}"
        return (f"{where}: RMS[10,end] {self.rms_10_m:.4f} m, RMS[45,end] {self.rms_45_m:.4f} m, "
                f"max from 10 s {self.max_err_10_m:.3f} m, saturated {sat:.2f} %")  # fmt: skip


def flight_cost(scenario: Scenario, opts: SimOptions, world_name: str) -> FlightCost:
    rec = simulate(scenario, opts)
    m = FlightMetrics.of(rec)
    sat = m.saturated_fraction
    # a flight that left the safety envelope costs as much as one that blew up, back or not
    flown = bool(np.all(np.isfinite(rec.x))) and math.isfinite(m.rms_10_m) and not m.lost
    cost = m.rms_10_m + SATURATION_WEIGHT_M * sat if flown else DIVERGED_COST_M
    return FlightCost(world_name, m.rms_10_m, m.rms_45_m, m.max_err_after_10_s_m, sat, cost,
                      scenario.run.name)  # fmt: skip


@dataclass
class TuneResult:
    controller: str
    feedforward: str
    knobs: tuple[Knob, ...]
    start: tuple[float, ...]
    best: tuple[float, ...]
    gains: Any
    start_flights: tuple[FlightCost, ...]
    best_flights: tuple[FlightCost, ...]
    evaluations: int
    wall_s: float
    history: list[float] = field(default_factory=list)  # best cost after each evaluation
    seed: int = 1
    plant: str = "paper"
    constraint: MarginConstraint | None = None
    rejected: int = 0  # candidates the constraint kept from flying
    best_shortfall: float = 0.0  # the tuned gains' disk margin below the constraint (0: met)
    scenarios: tuple[str, ...] = ("paper",)  # what every candidate flew

    @staticmethod
    def cost(flights: Sequence[FlightCost]) -> float:
        return max(f.cost_m for f in flights)


@dataclass(frozen=True)
class MarginConstraint:
    """Every loop break point's disk margin >= ``min_disk`` on ``plant`` with ``servos``."""

    min_disk: float = MIN_DISK_MARGIN
    plant: str = "gavrilets"
    servos: str = "servos-default"

    def shortfall(self, scenario: Scenario, controller: str, gains: Any) -> float:
        """How far the candidate's worst disk margin is below the bound (0: it holds)."""
        pid = gains if controller == "pid" else None
        tlc = scenario.gains if controller == "pid" else gains
        c = build_kernel_controller(controller, scenario.airframe, tlc, scenario.run.rate_hz, pid_gains=pid)
        name, sv = servo_model(self.servos)
        try:
            lin = linearize_loop(c, PlantModel.load(self.plant), scenario.airframe, sv, name)
        except ValueError:  # no hover equilibrium: worse than any loop that has one
            return self.min_disk + NO_EQUILIBRIUM_SHORTFALL
        if not lin.stable:  # no disk at all; how unstable shows the optimiser the way back
            return self.min_disk + UNSTABLE_SLOPE * (lin.spectral_radius - 1.0)
        return max(0.0, self.min_disk - lin.worst().disk_margin)


class Tuner:
    """The cost of a candidate (the worst of its flights); counts evaluations."""

    def __init__(self, scenarios: Scenario | Sequence[Scenario], controller: str, feedforward: str,
                 base_gains: Any, knobs: Sequence[Knob], worlds: Sequence[str] = TUNING_WORLDS,
                 plant: str = "paper", constraint: MarginConstraint | None = None) -> None:  # fmt: skip
        self.scenarios = (scenarios,) if isinstance(scenarios, Scenario) else tuple(scenarios)
        self.scenario = self.scenarios[0]  # the design airframe and control rate
        self.controller, self.feedforward = controller, feedforward
        self.base, self.knobs = base_gains, tuple(knobs)
        self.worlds = [(w, World.load(w) if w else None) for w in worlds]
        self.plant = PlantModel.load(plant)
        self.constraint = constraint
        self.evaluations = 0
        self.rejected = 0  # candidates the constraint kept from flying
        self.history: list[float] = []

    def flights(self, values: Sequence[float]) -> tuple[FlightCost, ...]:
        gains = with_knobs(self.base, self.knobs, values)
        out = []
        for scenario in self.scenarios:
            sc = scenario if self.controller == "pid" else dataclasses.replace(scenario, gains=gains)
            for name, world in self.worlds:
                opts = SimOptions(world=world, feedforward=self.feedforward, controller=self.controller,
                                  pid_gains=gains if self.controller == "pid" else None,
                                  plant=self.plant)  # fmt: skip
                out.append(flight_cost(sc, opts, name or "ideal"))
        return tuple(out)

    def __call__(self, u: np.ndarray) -> float:
        values = [k.from_unit(float(x)) for k, x in zip(self.knobs, u, strict=True)]
        try:
            short = 0.0
            if self.constraint is not None:
                short = self.constraint.shortfall(self.scenario, self.controller,
                                                  with_knobs(self.base, self.knobs, values))  # fmt: skip
            if short > 0.0:
                self.rejected += 1
                cost = CONSTRAINT_COST_M + 10.0 * short
            else:
                cost = TuneResult.cost(self.flights(values))
        except ValueError:  # a candidate the loader refuses (outside a gain's range)
            cost = DIVERGED_COST_M
        self.evaluations += 1
        self.history.append(min(cost, self.history[-1]) if self.history else cost)
        return cost


def tune(
    scenario: Scenario,
    controller: str,
    budget: int = 2000,
    feedforward: str | None = None,
    start: Any = None,
    progress: Callable[[int, float], None] | None = None,
    seed: int = 1,
    plant: str = "paper",
    constraint: MarginConstraint | None = None,
    also: Sequence[Scenario] = (),
) -> TuneResult:
    """Tune ``controller`` ("tlc" or "pid") from ``start`` (default: the scenario's gains or
    configs/gains_pid.toml) with ``budget`` cost evaluations; every candidate flies ``scenario``
    and each of ``also`` in every tuning world."""
    if controller not in ("tlc", "pid"):
        raise ValueError(f"controller must be tlc or pid, got {controller!r}")
    ff = feedforward or scenario.run.feedforward
    base = start if start is not None else (default_pid_gains() if controller == "pid" else scenario.gains)
    knobs = pid_knobs(base) if controller == "pid" else tlc_knobs(base)
    tuner = Tuner((scenario, *also), controller, ff, base, knobs, plant=plant, constraint=constraint)
    x0 = np.array([k.to_unit(_get(base, k)) for k in knobs])
    t0 = time.perf_counter()

    def cb(*_: Any, **__: Any) -> None:
        if progress is not None:
            progress(tuner.evaluations, tuner.history[-1])

    n = len(knobs)
    bounds = [(0.0, 1.0)] * n
    # x n candidates per generation: 10 (scipy's default) with budget for it, down to 3 so that
    # a short budget still runs two generations beyond the first population
    popsize = int(min(10, max(3, 0.6 * budget // (3 * n))))
    generations = max(0, int(0.6 * budget) // (popsize * n) - 1)
    x_best = x0
    if generations:
        de = differential_evolution(tuner, bounds, popsize=popsize, maxiter=generations, seed=seed, x0=x0,
                                    polish=False, tol=0.0, init="latinhypercube", callback=cb)  # fmt: skip
        x_best = de.x  # x0 is in the first population: never worse than the start
    # the simplex: a twentieth of each knob's range around the best point, inward at a bound
    steps = np.diag(np.where(x_best < 0.9, 0.05, -0.05))
    simplex = np.vstack([x_best, np.clip(x_best + steps, 0.0, 1.0)])
    left = max(n + 2, budget - tuner.evaluations)
    res = minimize(tuner, x_best, method="Nelder-Mead", bounds=bounds, callback=cb,
                   options={"maxfev": left, "initial_simplex": simplex, "adaptive": True,
                            "xatol": 1e-4, "fatol": 1e-5})  # fmt: skip
    # four significant digits: what a gains file should carry (the cost moves in the 6th)
    best = tuple(float(f"{k.from_unit(float(x)):.4g}") for k, x in zip(knobs, res.x, strict=True))
    start_values = tuple(_get(base, k) for k in knobs)
    tuned = with_knobs(base, knobs, best)
    short = constraint.shortfall(scenario, controller, tuned) if constraint is not None else 0.0
    return TuneResult(
        controller, ff, knobs, start_values, best, tuned,
        tuner.flights(start_values), tuner.flights(best), tuner.evaluations, time.perf_counter() - t0,
        tuner.history, seed, plant, constraint, tuner.rejected, short,
        tuple(sc.run.name for sc in tuner.scenarios),
    )  # fmt: skip


def gains_toml(result: TuneResult, command: str) -> str:
    """The tuned gains as a config file, its header saying how they were found."""
    t = as_table(result.gains)
    t["name"] = f"{result.controller.upper()}, tuned ({result.evaluations} evaluations)"
    if result.constraint is not None:  # the margins it was tuned to prove are its design point
        t["design"] = {"plant": result.constraint.plant, "servos": result.constraint.servos}
    before, after = TuneResult.cost(result.start_flights), TuneResult.cost(result.best_flights)
    lines = [
        f"# {result.controller.upper()} gains tuned by heli_sitl/studies/tune.py (docs/comparison.md): "
        "differential",
        f"# evolution then Nelder-Mead on the scenarios {', '.join(result.scenarios)} (feed-forward",
        f"# {result.feedforward!r}), each candidate flown in the ideal world, the servos-default and",
        "# everything worlds (configs/world/); cost = the worst flight's RMS error from 10 s + 1 m x",
        "# its saturated fraction.",
        f"# Command: {command}",
        f"# Plant {result.plant}, optimiser seed {result.seed}.",
        f"# Cost {before:.4f} m -> {after:.4f} m in {result.evaluations} evaluations.",
    ]
    if result.constraint is not None:
        c = result.constraint
        lines.append(f"# Constraint: disk margin >= {c.min_disk} at every loop break point on the {c.plant} "
                     f"plant with {c.servos} ({result.rejected} candidates rejected unflown).")  # fmt: skip
        if result.best_shortfall > 0.0:
            lines.append(f"# NOT MET: no candidate met it; these gains fall {result.best_shortfall:.2f} "
                         "short.")  # fmt: skip
    lines += [f"#   {f.describe()}" for f in result.best_flights]
    return "\n".join(lines) + "\n" + to_toml(t)


def write_gains(result: TuneResult, path: Path, command: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(gains_toml(result, command))
    # what was written loads back to the tuned gains
    loaded = PidGains.load(path) if result.controller == "pid" else type(result.gains).load(path)
    if loaded != dataclasses.replace(result.gains, name=loaded.name, design=loaded.design):
        raise RuntimeError(f"{path}: the written gains do not load back as tuned")
