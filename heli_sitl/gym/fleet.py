"""N vehicles flying one configuration, each its own seed: the arrays of the compiled batch
step (:func:`heli_sitl.engine.batch.batch_step`), built as the in-process loop builds a flight.

What a flight flies is resolved as :func:`heli_sitl.api.simulate` resolves it (preset names,
files or objects; a seed replaces the world's and its sensors' seeds, so that vehicle seed
``s`` flies ``hs.simulate(..., seed=s)``'s world). A vehicle is (re)started in Python from a
fresh :class:`~heli_plant.model.Plant` (its world's noise and turbulence streams seeded),
then every tick of every vehicle is one compiled call: the serial kernel, or with
``threads``, the parallel one on that many of numba's threads (the same bits).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.control import KernelController
from autopilot.controllers import build_kernel_controller
from autopilot.envelope import Envelope
from autopilot.estimation.config import EstimatorConfig
from autopilot.flight_metrics import FlightMetrics
from autopilot.metrics import FlightRecord
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from autopilot.tlc.controller import N_DIAG
from heli_common.config import ConfigError
from heli_common.jit import max_threads, set_threads
from heli_common.state import N_PITCH, N_STATE, FloatArray
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_common.world.sensors import SEED_MAX
from heli_plant.model import Plant
from heli_plant.rotor import N_ROTOR
from heli_plant.rotor import OFF as ROTOR_OFF
from heli_sitl.api import PID, TLC, TrajectoryLike, _scenario, _trajectory
from heli_sitl.engine import batch
from heli_sitl.engine.batch import (
    EP_GROUND,
    EP_MAX_ERR,
    EP_MAX_TILT,
    EP_RESIDUAL,
    EP_SCALE,
    EP_SERVOS_ON,
    EP_SETTLE,
    EP_TOUCHDOWN,
    EP_W_ALIVE,
    EP_W_ATT,
    EP_W_EFFORT,
    EP_W_POS,
    N_ENV_PARAMS,
    N_OBS,
    N_SCRATCH,
    N_VEHICLE,
)
from heli_sitl.engine.closed_loop import SensingArrays

ACTION_MODES = ("pitch", "residual")


@dataclass(frozen=True)
class RewardWeights:
    """The default reward per tick, on the truth after the step: ``alive * exp(-cost)`` with
    ``cost = pos * |p - p_ref|^2 + att * (phi^2 + theta^2) + effort * |a|^2``, ``a`` the action
    clipped to [-1, 1] (in residual mode its departure from the built-in law, in pitch mode
    from mid travel); units 1/m^2, 1/rad^2. In (0, alive]: every tick in the air pays, so
    leaving the envelope early never does (a quadratic cost alone would pay a crash: the
    paper's scenario starts 5.2 m off its path). The TLC on the paper's spiral earns about
    0.99 a tick once on its path (0.834 on average over the 120 s)."""

    alive: float = 1.0
    pos: float = 4.0
    att: float = 1.0
    effort: float = 0.1


DEFAULT_WEIGHTS = RewardWeights()


@dataclass(frozen=True)
class FlightSpec:
    """What every vehicle flies: the scenario (its trajectory, start, airframe, gains), the
    plant, the world (seeded per vehicle), the estimator, the control rate and the ticks."""

    scenario: Scenario
    plant: PlantModel
    world: World | None
    estimator: EstimatorConfig
    base: str  # the built-in law: "tlc" or "pid"
    pid_gains: PidGains | None
    rate_hz: float
    n_ticks: int  # the last tick's index: an episode is n_ticks steps

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    @classmethod
    def resolve(
        cls,
        scenario: str | Path | Scenario = "paper",
        plant: str | Path | PlantModel = "paper",
        world: str | Path | World | None = None,
        controller: TLC | PID | str = "tlc",
        estimator: str | Path | EstimatorConfig | None = None,
        duration_s: float | None = None,
        trajectory: str | Path | TrajectoryLike | None = None,
    ) -> FlightSpec:
        """As :func:`heli_sitl.api.simulate` takes them; ``controller`` the built-in law a
        residual rides on ("tlc", "pid", :class:`~heli_sitl.api.TLC`, :class:`~heli_sitl.api.PID`)."""
        if not isinstance(controller, (TLC, PID)) and controller not in ("tlc", "pid"):
            raise ConfigError(f"controller: the built-in law of the environment: 'tlc', 'pid', "
                              f"hs.TLC(...) or hs.PID(...), got {controller!r}")  # fmt: skip
        sc = _scenario(scenario, controller)
        if trajectory is not None:
            traj = _trajectory(trajectory)
            sc = sc.flying(traj)  # type: ignore[arg-type]
            end = getattr(traj, "duration_s", None)
            if duration_s is None and isinstance(end, (int, float)) and 0.0 < end < math.inf:
                duration_s = float(end)
        good = isinstance(duration_s, (int, float)) and 0.0 < duration_s < math.inf
        if duration_s is not None and not good:
            raise ConfigError(f"duration_s: expected a positive finite number of seconds, got {duration_s!r}")
        pm = plant if isinstance(plant, PlantModel) else PlantModel.load(plant)
        if pm.vehicle is not None:
            raise ConfigError(f"plant {pm.vehicle}: a plant of your own steps from Python, not in the "
                              "compiled environment")  # fmt: skip
        w = world if isinstance(world, World) or world is None else World.load(world)
        est = estimator if isinstance(estimator, EstimatorConfig) or estimator is None else (
            EstimatorConfig.load(estimator))
        use_pid = isinstance(controller, PID) or controller == "pid"
        rate = sc.run.rate_hz
        n = round((duration_s or sc.run.duration_s) * rate)
        return cls(sc, pm, w, est or EstimatorConfig(), "pid" if use_pid else "tlc",
                   controller.load() if isinstance(controller, PID) else None, rate, n)  # fmt: skip

    def seeded_world(self, seed: int) -> World | None:
        """The world of vehicle seed ``seed``, as hs.simulate(seed=...) seeds it."""
        if not (0 <= seed <= SEED_MAX):
            raise ConfigError(f"seed: expected an integer in [0, {SEED_MAX}], got {seed}")
        w = self.world or World()
        return dataclasses.replace(w, seed=seed, sensors=dataclasses.replace(w.sensors, seed=seed))

    def controller(self) -> KernelController[Any]:
        sc = self.scenario
        return build_kernel_controller(self.base, sc.airframe, sc.gains, self.rate_hz, sc.run.feedforward,
                                       self.pid_gains)  # fmt: skip

    def plant_for(self, seed: int) -> Plant:
        sc = self.scenario
        return Plant(sc.airframe, sc.initial.state().to_array(), substeps=sc.run.plant_substeps,
                     world=self.seeded_world(seed), step_s=self.dt_s, model=self.plant)  # fmt: skip


# the per-vehicle arrays, stacked: name -> what a fresh vehicle's row is built from
_ROWS = ("x", "held", "ws", "wp", "servo_s", "snp", "sns", "meas", "est", "loop_s", "ctrl")


def _fresh(spec: FlightSpec, ctrl: KernelController[Any], seed: int) -> tuple[dict[str, FloatArray], Plant,
                                                                               SensingArrays]:  # fmt: skip
    """A vehicle at tick 0 with world seed ``seed``: its rows, as closed_loop.simulate builds them."""
    plant = spec.plant_for(seed)
    w = plant.world or plant.calm
    sn = SensingArrays.build(plant, spec.estimator, spec.rate_hz, 1)
    if plant.world is not None:  # the servos' start: re-placed by the first command (batch_step)
        plant.world.prepare(spec.dt_s / plant.substeps, plant.u.copy(), np.column_stack([plant.lo, plant.hi]))
    rows = dict(x=plant.x.copy(), held=plant.u.copy(), ws=w.ws.copy(), wp=w.wp.copy(),
                servo_s=w.servo_s.copy(),
                snp=np.asarray(sn.snp, dtype=float).copy(), sns=sn.sns.copy(), meas=sn.meas.copy(),
                est=sn.est.copy(), loop_s=np.zeros(1), ctrl=np.zeros_like(ctrl.state))  # fmt: skip
    return rows, plant, sn


class Fleet:
    """``n`` vehicles of one :class:`FlightSpec`; ``record`` keeps each one's per-tick truth,
    commands and diagnostics (its :class:`FlightRecord` at the end; 2.4 MB per vehicle for
    the paper's 120 s). ``threads``: None steps the vehicles in turn on the calling thread
    (:func:`~heli_sitl.engine.batch.batch_step`); a number, on that many of numba's threads
    (:func:`~heli_sitl.engine.batch.batch_step_parallel`, 1 to
    :func:`~heli_common.jit.max_threads`)."""

    def __init__(self, spec: FlightSpec, n: int, action_mode: str, residual_scale: float,
                 envelope: Envelope, weights: RewardWeights, record: bool,
                 threads: int | None = None) -> None:  # fmt: skip
        if action_mode not in ACTION_MODES:
            raise ConfigError(f"action_mode: expected one of {ACTION_MODES}, got {action_mode!r}")
        if not (isinstance(residual_scale, (int, float)) and 0.0 < residual_scale <= 2.0):
            raise ConfigError(f"residual_scale: expected in (0, 2], got {residual_scale!r}")
        if n < 1:
            raise ConfigError(f"num_envs: expected >= 1, got {n}")
        if threads is not None and not (isinstance(threads, int) and 1 <= threads <= max_threads()):
            raise ConfigError(f"num_threads: expected 1 to {max_threads()} (the cores this process may use), "
                              f"got {threads!r}")  # fmt: skip
        self.threads = threads
        self._kernel = batch.batch_step if threads is None else batch.batch_step_parallel
        self.spec, self.n, self.envelope, self.record = spec, n, envelope, record
        self.ctrl = spec.controller()
        rows, plant, sn = _fresh(spec, self.ctrl, 0)
        w = plant.world or plant.calm
        self.lo, self.hi = plant.lo.copy(), plant.hi.copy()
        self.t = np.arange(spec.n_ticks + 1) / spec.rate_hz
        self.refs = np.ascontiguousarray(spec.scenario.trajectory.sample(self.t), dtype=float)
        self.rows = {k: np.zeros((n, *v.shape)) for k, v in rows.items()}
        ep = np.zeros(N_ENV_PARAMS)
        ep[EP_RESIDUAL] = 1.0 if action_mode == "residual" else 0.0
        ep[EP_SCALE] = residual_scale
        ep[EP_SERVOS_ON] = 1.0 if plant.world is not None and plant.world_config.servos.on else 0.0
        ep[EP_SETTLE], ep[EP_MAX_ERR] = envelope.settle_s, envelope.max_error_m
        ep[EP_MAX_TILT] = envelope.max_tilt_deg
        ep[EP_GROUND], ep[EP_TOUCHDOWN] = envelope.ground_m, envelope.max_touchdown_m_s
        ep[EP_W_ALIVE], ep[EP_W_POS] = weights.alive, weights.pos
        ep[EP_W_ATT], ep[EP_W_EFFORT] = weights.att, weights.effort
        self.ep = ep
        self.actions = np.zeros((n, N_PITCH))
        self.just_reset = np.zeros(n, dtype=bool)
        self.ticks = np.zeros(n, dtype=np.int64)
        self.diag = np.zeros((n, N_DIAG))
        self.base = np.zeros((n, N_PITCH))
        self.last_a = np.zeros((n, N_PITCH))
        self.vs = np.zeros((n, N_VEHICLE))
        self.obs = np.zeros((n, N_OBS))
        self.reward = np.zeros(n)
        self.terminated = np.zeros(n, dtype=bool)
        self.truncated = np.zeros(n, dtype=bool)
        m = spec.n_ticks + 1
        self.xs = np.full((n, m, N_STATE), np.nan) if record else np.zeros((1, 1, N_STATE))
        self.us = np.full((n, m, N_PITCH), np.nan) if record else np.zeros((1, 1, N_PITCH))
        self.diags = np.full((n, m, N_DIAG), np.nan) if record else np.zeros((1, 1, N_DIAG))
        g = plant.world.rotor if plant.world is not None else ROTOR_OFF
        r = self.rows
        # batch_step's arguments: what all vehicles share, then the per-vehicle arrays (first
        # axis n), the records (per vehicle, or placeholders), each vehicle's scratch
        shared = (self.ctrl.constants, plant.constants, w.air, g, self.t, self.refs, self.lo, self.hi,
                  int(spec.n_ticks), int(plant.substeps), float(spec.dt_s), plant.world is not None,
                  bool(sn.on), ep, w.servo_p, w.dryden, sn.home, sn.eparams)  # fmt: skip
        per_vehicle = (self.actions, self.just_reset, self.ticks, r["x"], r["held"], r["ws"], r["wp"],
                       r["servo_s"], r["snp"], r["sns"], r["meas"], r["est"], r["loop_s"], r["ctrl"],
                       self.diag, self.base, self.last_a, self.vs, self.obs, self.reward, self.terminated,
                       self.truncated)  # fmt: skip
        records = (self.xs, self.us, self.diags)
        # each vehicle's scratch: its row, its two-row windows of the per-tick logs
        scratch = (np.zeros((n, N_SCRATCH)), np.zeros((n, 2, N_STATE)), np.zeros((n, 2, sn.log.shape[1])),
                   np.zeros((n, 2, 3)), np.zeros((n, 2, N_PITCH)), np.zeros((n, 2, N_ROTOR + 1)))  # fmt: skip
        self._args: tuple[Any, ...] = (*shared, *per_vehicle, bool(record), *records, *scratch)
        self.shards = 0  # the runs of vehicles the parallel kernel shares among threads (0: serial)
        if threads is not None:
            # one run of vehicles a thread, each with its own handles on the law's constants
            cuts = min(threads, n)
            laws = batch.shard_list(_own(shared[:4]))
            for _ in range(cuts - 1):
                batch.shard_append(laws, _own(shared[:4]))
            self._args = (laws, cuts, *self._args[4:])
            self.shards = cuts
        self._entry: Any = None

    def start(self, v: int, seed: int) -> None:
        """Vehicle ``v`` back at tick 0 with world seed ``seed`` (observed at the next :meth:`step`)."""
        rows, _, _ = _fresh(self.spec, self.ctrl, seed)
        for k, a in rows.items():
            self.rows[k][v] = a
        self.just_reset[v] = True
        if self.record:
            self.xs[v] = np.nan
            self.us[v] = np.nan
            self.diags[v] = np.nan

    def step(self) -> None:
        """One compiled call: every vehicle's tick (:func:`~heli_sitl.engine.batch.batch_step`)
        with the actions in :attr:`actions`; the started vehicles only observed."""
        before = set_threads(self.threads) if self.threads is not None else 0
        try:
            if self._entry is not None:
                self._entry(*self._args)
            else:
                self._kernel(*self._args)
                self._entry = _entry_point(self._kernel, self._args)
        finally:
            if self.threads is not None:
                set_threads(before)
        self.just_reset[:] = False

    def flight_record(self, v: int) -> FlightRecord:
        """Vehicle ``v``'s flight so far as the in-process loop records it (the last tick's
        command: the one held into it)."""
        if not self.record:
            raise ValueError("this fleet keeps no records (record=False)")
        i = int(self.ticks[v])
        if i > 0:
            self.us[v, i] = self.us[v, i - 1]
            self.diags[v, i] = self.diags[v, i - 1]
        sc = self.spec.scenario
        extra: dict[str, object] = {"scenario": sc.run.name, "rate_hz": self.spec.rate_hz,
                                    "controller": "policy",
                                    "error_windows_s": [list(w) for w in sc.run.error_windows_s]}  # fmt: skip
        return FlightRecord.from_ticks(self.t[: i + 1], self.xs[v, : i + 1].copy(), self.refs[: i + 1],
                                       self.us[v, : i + 1].copy(), self.diags[v, : i + 1], 0.0,
                                       extra)  # fmt: skip

    def metrics(self, v: int) -> FlightMetrics:
        return FlightMetrics.of(self.flight_record(v), envelope=self.envelope)


def _own(obj: Any) -> Any:
    """``obj`` with a new handle on every array in it (a view: the same memory), tuples and
    named tuples rebuilt around them: a thread's own reference counts (batch_step_parallel)."""
    if isinstance(obj, np.ndarray):
        return obj.view()
    if isinstance(obj, tuple):
        items = [_own(o) for o in obj]
        return type(obj)(*items) if hasattr(obj, "_fields") else tuple(items)
    return obj


def _entry_point(dispatcher: Any, args: tuple[Any, ...]) -> Any:
    """The compiled overload of ``dispatcher`` for ``args``' types, called without the
    dispatcher's typing of every argument (~10 us a call for the constants' named tuples,
    more than a vehicle's tick); None where numba is off or the overload is not found."""
    try:
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        return dispatcher.overloads[sig].entry_point
    except (AttributeError, KeyError):
        return None

