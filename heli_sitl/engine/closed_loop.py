"""In-process closed loop: controller and plant in one process, fixed control rate.

This loop is the only owner of time here: tick k is at t = k / rate, the controller sees
the state at t, its pitches are held (zero-order hold) while the plant integrates to t+dt.
The loop itself is compiled and calls the very kernels the processes use (the controller's,
dispatched by its constants' type when the loop is compiled:
:func:`~autopilot.control.control_law`; :func:`~heli_plant.model.plant_step`, and
:func:`~heli_plant.model.accept_pitches` behind the sim link's rounding,
:func:`~heli_common.wire.mavlink.sim_protocol.pitches_as_received`); a trajectory is a pure
function of time, so the references for every tick are sampled up front. What would cross the sim link is
rounded as the link rounds it (the state the controller sees, the pitches the plant holds,
the sensors' samples): a lockstep flight of the same scenario is the same flight, bit for
bit (docs/architecture.md, "Lockstep and in-process").
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from autopilot.control import KernelController, control_law
from autopilot.controller_names import BUILT_IN
from autopilot.controllers import build_kernel_controller
from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.log import N_EST_LOG
from autopilot.estimation.nav import make_nav_params, nav_init, nav_log, nav_state_size, nav_tick, nav_truth
from autopilot.metrics import FlightRecord
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from autopilot.tlc.controller import N_DIAG, TLController
from autopilot.user_controller import UserController, is_user_spec
from heli_common.jit import njit
from heli_common.state import N_PITCH, N_STATE, FloatArray
from heli_common.vehicle.airframe import PlantConstants
from heli_common.vehicle.plant_model import PlantModel
from heli_common.wire.mavlink.sim_protocol import as_received, pitches_as_received, state_as_received
from heli_common.wire.measurements import N_OUT
from heli_common.wire.sensor_wire import N_HOME
from heli_common.world.config import World
from heli_plant.model import Plant, accept_pitches
from heli_plant.rotor import N_ROTOR, RotorConstants
from heli_plant.rotor import OFF as ROTOR_OFF
from heli_plant.sensors.sensing import Sensing, sense
from heli_plant.sensors.truth import imu_bias_truth
from heli_plant.world.model import (
    WS_AIR,
    WS_PITCH,
    WS_ROTOR,
    WS_THROTTLE,
    AirConstants,
    world_plant_step,
)

Progress = Callable[[int, int], None]
CHUNK_TICKS = 500  # progress granularity; each chunk is one compiled call


LS_ON_GROUND = 0  # the loop's own state across chunks: the vehicle rests on the ground


@dataclass(frozen=True)
class SimOptions:
    rate_hz: float | None = None  # None: the scenario's
    feedforward: str | None = None
    plant_substeps: int | None = None
    duration_s: float | None = None
    world: World | None = None  # None: the paper's ideal world
    estimator: EstimatorConfig = EstimatorConfig()  # used when the world's sensors are on
    # "tlc", "pid" (the cascaded PID baseline), or a user's class: "module:Class",
    # "file.py:Class" or the class itself (autopilot.user_controller), flown tick by tick
    # from Python around the same compiled plant and sensing steps
    controller: str | type[Any] = "tlc"
    pid_gains: PidGains | None = None  # None: configs/gains_pid.toml
    plant: PlantModel = PlantModel("paper")  # or Gavrilets' rotor plant (--plant)


@njit
def _observe(
    i: int, t: FloatArray, x: FloatArray, held: FloatArray, c: PlantConstants, in_world: bool,
    air: AirConstants, wp: FloatArray, ws: FloatArray, snp: FloatArray, sns: FloatArray,
    meas: FloatArray, home: FloatArray, eparams: FloatArray, est: FloatArray,
    x_hats: FloatArray, est_log: FloatArray, loop_s: FloatArray, g: RotorConstants,
) -> FloatArray:  # fmt: skip
    """Tick ``i``'s state for the controller, flying from sensors: the estimate from what
    the sensors measured at t[i] (logged in ``x_hats[i]`` and ``est_log[i]``)."""
    resting = i == 0 or loop_s[LS_ON_GROUND] != 0.0
    mask = sense(t[i], x, held, c, resting, in_world, air, wp, ws, snp, sns, meas, home, g)
    gps = nav_tick(eparams, est, t[i], meas, mask, x_hats[i])
    nav_log(eparams, est, gps, est_log[i])
    gyro_bias, accel_bias = imu_bias_truth(t[i], snp, sns)
    nav_truth(eparams, est, x, gyro_bias, accel_bias, est_log[i])
    x_hat: FloatArray = x_hats[i]
    return x_hat


@njit
def _advance(
    i: int, t: FloatArray, x: FloatArray, out: FloatArray, lo: FloatArray, hi: FloatArray,
    held: FloatArray, c: PlantConstants, n_sub: int, dt: float, in_world: bool, air: AirConstants,
    wp: FloatArray, ws: FloatArray, servo_p: FloatArray, servo_s: FloatArray, dryden: FloatArray,
    airs: FloatArray, applied: FloatArray, loop_s: FloatArray, g: RotorConstants, rotors: FloatArray,
    sim_link: bool,
) -> FloatArray:  # fmt: skip
    """The command ``out`` held while the plant integrates from t[i] to t[i+1]; the world's
    truth of that hold logged in row i+1. Returns the next state."""
    if sim_link:  # the plant holds what the sim link delivers of the command (float32, normalised)
        pitches_as_received(out, lo, hi, held)
    else:
        accept_pitches(out, lo, hi, held)
    x, on_ground = world_plant_step(t[i], x, held, c, air, dt, n_sub, True, wp, ws, servo_p, servo_s,
                                    dryden, g)  # fmt: skip
    if in_world:
        # the truth of the hold that led to the next state, as the plant reports it
        airs[i + 1] = ws[WS_AIR : WS_AIR + 3]
        applied[i + 1] = ws[WS_PITCH : WS_PITCH + N_PITCH]
    if g.on:
        rotors[i + 1, :N_ROTOR] = ws[WS_ROTOR : WS_ROTOR + N_ROTOR]
        rotors[i + 1, N_ROTOR] = ws[WS_THROTTLE]
    loop_s[LS_ON_GROUND] = 1.0 if on_ground else 0.0
    return x


@njit
def _run_ticks(
    kc: Any,
    ctrl_state: FloatArray,
    dt_s: float,
    c: PlantConstants,
    lo: FloatArray,
    hi: FloatArray,
    held: FloatArray,
    x0: FloatArray,
    refs: FloatArray,
    t: FloatArray,
    k0: int,
    k1: int,
    n_last: int,
    n_sub: int,
    xs: FloatArray,
    us: FloatArray,
    diags: FloatArray,
    in_world: bool,
    air: AirConstants,
    wp: FloatArray,
    ws: FloatArray,
    servo_p: FloatArray,
    servo_s: FloatArray,
    dryden: FloatArray,
    airs: FloatArray,
    applied: FloatArray,
    sensing: bool,
    snp: FloatArray,
    sns: FloatArray,
    meas: FloatArray,
    home: FloatArray,
    eparams: FloatArray,
    est: FloatArray,
    x_hats: FloatArray,
    est_log: FloatArray,
    loop_s: FloatArray,
    g: RotorConstants,
    rotors: FloatArray,
    sim_link: bool = False,
) -> FloatArray:
    """Ticks ``k0`` to ``k1 - 1``, the controller being the compiled law registered for the
    type of its constants ``kc`` (:func:`~autopilot.control.control_law`: numba compiles this
    loop once per law, each a direct call), over its state ``ctrl_state``.
    ``sim_link``: round what would cross the sim link as the
    link rounds it (the controller flies on the float32 state, the plant holds the float32
    normalised pitches), so that the flight is a lockstep flight's, bit for bit; off, the
    loop is the exact arithmetic of the model (the tests' equilibria and linearisations)."""
    x = x0.copy()
    out = np.empty(N_PITCH)
    diag = np.zeros(N_DIAG)
    for i in range(k0, k1):
        # the controller flies on the state, as the sim link carries it (float32 fields), or
        # on the estimate from the sensors' samples (rounded as the link carries them)
        xc = x
        if sensing:
            xc = _observe(i, t, x, held, c, in_world, air, wp, ws, snp, sns, meas, home, eparams, est,
                          x_hats, est_log, loop_s, g)  # fmt: skip
        elif sim_link:
            xc = state_as_received(x)
        control_law(kc, ctrl_state, xc, refs[i], False, out, diag)
        xs[i] = x
        us[i] = out
        diags[i] = diag
        if i < n_last:
            x = _advance(i, t, x, out, lo, hi, held, c, n_sub, dt_s, in_world, air, wp, ws, servo_p,
                         servo_s, dryden, airs, applied, loop_s, g, rotors, sim_link)  # fmt: skip
    return x


def simulate(
    scenario: Scenario, opts: SimOptions = SimOptions(), progress: Progress | None = None
) -> FlightRecord:
    run = scenario.run
    rate_hz = opts.rate_hz or run.rate_hz
    duration = opts.duration_s or run.duration_s
    kind = opts.controller
    # the one controller flown: a compiled one (its kernel passed into the compiled loop), or
    # a user's class called tick by tick around the same compiled plant and sensing steps
    user: UserController | None = None
    ctrl: KernelController[Any] | None = None
    if not isinstance(kind, str) or is_user_spec(kind):
        user = UserController(kind, scenario.airframe, rate_hz, strict=True)
    elif kind in BUILT_IN:
        ctrl = build_kernel_controller(kind, scenario.airframe, scenario.gains, rate_hz,
                                       opts.feedforward or run.feedforward, opts.pid_gains)  # fmt: skip
    else:
        raise ValueError(f"controller must be tlc, pid or module:Class, got {kind!r}")
    dt_s = 1.0 / rate_hz
    plant = Plant(
        scenario.airframe,
        scenario.initial.state().to_array(),
        substeps=opts.plant_substeps or run.plant_substeps,
        world=opts.world,
        step_s=1.0 / rate_hz,
        model=opts.plant,
    )
    n = round(duration * rate_hz)
    t = np.arange(n + 1) / rate_hz
    refs = scenario.trajectory.sample(t)
    xs = np.empty((n + 1, plant.x.size))
    us = np.empty((n + 1, N_PITCH))
    diags = np.empty((n + 1, N_DIAG))
    airs = np.full((n + 1, 3), np.nan)  # row 0: no hold before the first state
    applied = np.full((n + 1, N_PITCH), np.nan)
    x = plant.x
    w = plant.world or plant.calm
    g = plant.world.rotor if plant.world is not None else ROTOR_OFF
    rotors = np.full((n + 1, N_ROTOR + 1), np.nan)
    if g.on:
        rotors[0, :N_ROTOR] = w.ws[WS_ROTOR : WS_ROTOR + N_ROTOR]
        rotors[0, N_ROTOR] = w.ws[WS_THROTTLE]
    sn = SensingArrays.build(plant, opts.estimator, rate_hz, n)
    if plant.world is not None:
        # the servos start where the first command puts them, as in the plant process; that
        # command answers the state the controller sees first (the estimate, from sensors)
        x_first = sn.first_estimate(plant) if sn.on else as_received(x)
        if ctrl is not None:
            first = ctrl.trial_update(0.0, x_first, refs[0])
        else:
            assert user is not None
            first = copy.deepcopy(user).update(0.0, x_first, refs[0])
        u0 = plant.u.copy()
        pitches_as_received(first, plant.lo, plant.hi, u0)
        plant.world.prepare(1.0 / rate_hz / plant.substeps, u0, np.column_stack([plant.lo, plant.hi]))


    def ticks(c: KernelController[Any], k0: int, k1: int, state: FloatArray, held: FloatArray,
              ws: FloatArray, servo_s: FloatArray, x: FloatArray, sns: FloatArray, meas: FloatArray,
              est: FloatArray, loop_s: FloatArray) -> FloatArray:  # fmt: skip
        return _run_ticks(
            c.constants, state, dt_s, plant.constants, plant.lo, plant.hi, held, x, refs, t,
            k0, k1, n, plant.substeps, xs, us, diags, plant.world is not None, w.air, w.wp, ws, w.servo_p,
            servo_s, w.dryden, airs, applied, sn.on, sn.snp, sns, meas, sn.home, sn.eparams, est,
            sn.x_hats, sn.log, loop_s, g, rotors, True,
        )  # fmt: skip

    def user_ticks(u: UserController, k0: int, k1: int, held: FloatArray, ws: FloatArray, servo_s: FloatArray,
                   x: FloatArray, sns: FloatArray, meas: FloatArray, est: FloatArray,
                   loop_s: FloatArray) -> FloatArray:  # fmt: skip
        """The compiled loop's ticks with the controller called from Python: the very same
        sensing and plant steps around it (a wrapped TLC flies bit for bit as compiled)."""
        in_world = plant.world is not None
        for i in range(k0, k1):
            if sn.on:
                xc = _observe(i, t, x, held, plant.constants, in_world, w.air, w.wp, ws, sn.snp, sns,
                              meas, sn.home, sn.eparams, est, sn.x_hats, sn.log, loop_s,
                              g)  # fmt: skip
            else:  # as the sim link carries it (see _run_ticks)
                xc = state_as_received(x)
            out = u.update(float(t[i]), xc, refs[i])
            xs[i] = x
            us[i] = out
            diags[i] = u.diag
            if i < n:
                x = _advance(i, t, x, out, plant.lo, plant.hi, held, plant.constants, plant.substeps,
                             dt_s, in_world, w.air, w.wp, ws, w.servo_p, servo_s, w.dryden,
                             airs, applied, loop_s, g, rotors, True)  # fmt: skip
        return x

    loop_s = np.zeros(1)
    if plant.vehicle is not None:  # a plant of the user's: its derivative from Python, tick by tick
        wall0 = time.perf_counter()
        _own_plant_ticks(ctrl if ctrl is not None else user, plant, refs, t, n, xs, us, diags, progress)
    else:
        # load (or compile) the kernels outside the timed flight, on throwaway copies
        warm = (plant.u.copy(), w.ws.copy(), w.servo_s.copy(), x, sn.sns.copy(), sn.meas.copy(),
                sn.est.copy(), loop_s.copy())  # fmt: skip
        if ctrl is not None:
            ticks(ctrl, 0, 1, ctrl.state.copy(), *warm)
        else:
            assert user is not None
            user_ticks(copy.deepcopy(user), 0, 1, *warm)
        wall0 = time.perf_counter()
        # chunks only where someone watches the progress: each compiled call checks its ~40
        # arguments' types (~30 us), 25 calls a 120 s flight, paid by every campaign flight
        chunk = CHUNK_TICKS if progress is not None else n + 1
        for k0 in range(0, n + 1, chunk):
            k1 = min(n + 1, k0 + chunk)
            if ctrl is not None:
                x = ticks(ctrl, k0, k1, ctrl.state, plant.u, w.ws, w.servo_s, x, sn.sns, sn.meas, sn.est,
                          loop_s)  # fmt: skip
            else:
                assert user is not None
                x = user_ticks(user, k0, k1, plant.u, w.ws, w.servo_s, x, sn.sns, sn.meas, sn.est, loop_s)
            if progress is not None:
                progress(k1 - 1, n)
    wall = time.perf_counter() - wall0
    extra: dict[str, object] = {
        "scenario": run.name, "rate_hz": rate_hz,
        "feedforward": ctrl.feedforward.value if isinstance(ctrl, TLController) else None,
        "plant_substeps": plant.substeps,
        "gains": ctrl.gains.name if ctrl is not None else user.name if user is not None else "",
        "controller": user.spec if user is not None else kind,
        "error_windows_s": [list(w) for w in run.error_windows_s],
    }  # fmt: skip
    extra["plant"] = plant.model.kind
    if plant.world is not None or sn.on:
        extra["world"] = plant.world_config.describe(scenario.airframe)
    if sn.on:
        extra["estimator"] = dataclasses.asdict(opts.estimator)
    rec = FlightRecord.from_ticks(t, xs, refs, us, diags, wall, extra)
    if plant.world is not None and plant.world_config.on:
        rec = dataclasses.replace(rec, air_nwu_m_s=airs, servo_rad=applied)
    if g.on:
        rec = dataclasses.replace(rec, rotor=rotors)
    if sn.on:
        rec = dataclasses.replace(rec, x_hat=sn.x_hats, est_log=sn.log)
    return rec


def _own_plant_ticks(
    flyer: KernelController[Any] | UserController | None, plant: Plant, refs: FloatArray, t: FloatArray,
    n: int, xs: FloatArray, us: FloatArray, diags: FloatArray, progress: Progress | None,
) -> None:  # fmt: skip
    """The loop of :func:`_run_ticks` for a plant of the user's (heli_plant.vehicle), from
    Python: the controller flies on the state as the sim link carries it, the plant holds the
    pitches as the link delivers them and steps as the plant process steps it (the same
    flight as in lockstep)."""
    assert flyer is not None
    for i in range(n + 1):
        x = plant.x
        out = flyer.update(float(t[i]), state_as_received(x), refs[i])
        xs[i], us[i], diags[i] = x, out, flyer.diag
        if i < n:
            pitches_as_received(out, plant.lo, plant.hi, plant.u)
            plant.step(float(t[i + 1] - t[i]))
        if progress is not None and (i % CHUNK_TICKS == 0 or i == n):
            progress(i, n)


@dataclass
class SensingArrays:
    """The arrays of the sensors and the estimator for the compiled loop (placeholders,
    never read, when the world's sensors are off)."""

    on: bool
    snp: FloatArray
    sns: FloatArray
    meas: FloatArray
    home: FloatArray
    eparams: FloatArray
    est: FloatArray
    x_hats: FloatArray
    log: FloatArray

    @classmethod
    def build(cls, plant: Plant, cfg: EstimatorConfig, rate_hz: float, n: int) -> SensingArrays:
        s = plant.sensing
        if s is None:
            return cls.off()
        eparams = make_nav_params(cfg, rate_hz, plant.home)
        m = s.model
        # the plant sampled its sensors at t = 0 when it was built; the loop samples them
        # itself, tick by tick, from a fresh start of the same configuration
        fresh = Sensing.build(m.config, m.step_s, m.gravity_m_s2, plant.home)
        est = np.zeros(nav_state_size(eparams))
        # started from the spawn state as the autopilot process receives it (float32 on the
        # sim link), so that a lockstep flight's estimator starts from the very same numbers
        nav_init(eparams, est, as_received(plant.x))
        return cls(True, fresh.model.params, fresh.model.state, fresh.meas, fresh.home, eparams, est,
                   np.full((n + 1, plant.x.size), np.nan),
                   np.full((n + 1, N_EST_LOG), np.nan))  # fmt: skip

    @classmethod
    def off(cls) -> SensingArrays:
        z = np.zeros(1)
        return cls(False, z, z, np.zeros(N_OUT), np.zeros(N_HOME), z, z, np.zeros((1, N_STATE)),
                   np.zeros((1, N_EST_LOG)))  # fmt: skip

    def first_estimate(self, plant: Plant) -> FloatArray:
        """The estimate of tick 0 (sensors sampled and fused on copies of the arrays)."""
        w = plant.world or plant.calm
        g = plant.world.rotor if plant.world is not None else ROTOR_OFF
        meas, sns, est, x_hat = self.meas.copy(), self.sns.copy(), self.est.copy(), np.empty(N_STATE)
        mask = sense(0.0, plant.x, plant.u, plant.constants, True, plant.world is not None, w.air, w.wp,
                     w.ws.copy(), self.snp, sns, meas, self.home, g)  # fmt: skip
        nav_tick(self.eparams, est, 0.0, meas, mask, x_hat)
        return x_hat

    def args(self) -> tuple[object, ...]:
        """The loop's sensing arguments, in order (its own arrays)."""
        return (self.on, self.snp, self.sns, self.meas, self.home, self.eparams, self.est,
                self.x_hats, self.log)  # fmt: skip

