"""Speed of the control law and the plant, real-time factor of the in-process closed loop,
and the accuracy of the 10 ms RK4 plant step on the paper scenario.

Every timed call is measured on its own (``perf_counter_ns``) and the median is reported,
after a warm-up that loads (or compiles) the numba kernels.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable
from functools import cache

import numpy as np

from autopilot.metrics import FlightRecord
from autopilot.pid.controller import PIDController
from autopilot.pid.gains import default_pid_gains
from autopilot.scenario import Scenario
from autopilot.tlc.controller import N_DIAG, TLController, tlc_kernel
from benchmarks import Row, above, below, bench
from heli_common.state import N_PITCH, POS
from heli_common.vehicle.plant_model import PlantModel
from heli_common.wire.mavlink.sim_protocol import state_as_received
from heli_plant.model import Plant, plant_step
from heli_sitl.engine.closed_loop import SimOptions, simulate

SCENARIO = "paper"
# 1500x for the navigation-filter flight as a multiple of the ideal-world tick on the host
# where it was first measured: (120 s / 1500 / 12000 ticks) / 1.829 us
FLOORS_AT_1500X = 120.0 / 1500.0 / 12000.0 / 1.829e-6


@cache
def scenario() -> Scenario:
    return Scenario.load(SCENARIO)


@cache
def flight(feedforward: str = "pseudo", plant_substeps: int = 1) -> FlightRecord:
    """One paper flight (run twice: the first loads the kernels, the second is timed)."""
    opts = SimOptions(feedforward=feedforward, plant_substeps=plant_substeps)
    simulate(scenario(), opts)
    return simulate(scenario(), opts)


def median_ns(call: Callable[[int], object], n: int) -> float:
    """Median wall time of ``call(i)`` over i = 0..n-1, in nanoseconds (gc off)."""
    samples = np.empty(n)
    clock = time.perf_counter_ns
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for i in range(n):
            t0 = clock()
            call(i)
            samples[i] = clock() - t0
    finally:
        if gc_was:
            gc.enable()
    return float(np.median(samples))


@bench("control law")
def bench_tlc_step() -> list[Row]:
    """TLController.update and the raw kernel along the recorded paper flight (realistic
    states and references, every tick of the 120 s)."""
    rec = flight()
    sc = scenario()
    n = rec.t_s.size
    ctrl = TLController(sc.airframe, sc.gains, rec.extra["rate_hz"], rec.extra["feedforward"])
    ctrl.update(0.0, rec.x[0], rec.ref[0])  # load the kernel
    ctrl.reset()
    outs = np.empty((n, N_PITCH))

    # the flight's controller saw each state as the sim link carries it (float32 fields)
    seen = np.array([state_as_received(x) for x in rec.x])

    def update(i: int) -> None:
        outs[i] = ctrl.update(rec.t_s[i], seen[i], rec.ref[i])

    t_update = median_ns(update, n) / 1e3
    # replaying the states the controller saw must reproduce the recorded commands exactly
    same = bool(np.array_equal(outs, rec.pitches))

    k, st = ctrl.constants, np.zeros_like(ctrl.state)
    out, diag = np.empty(N_PITCH), np.zeros(N_DIAG)

    def kernel(i: int) -> None:
        tlc_kernel(k, st, rec.x[i], rec.ref[i], False, out, diag)

    t_kernel = median_ns(kernel, n) / 1e3
    per_tick = rec.wall_s / (n - 1) * 1e6
    # the PID baseline along the same states and references (the same contract and cost
    # of a call; its own flight would differ), against the TLC's measured in this run
    pid = PIDController(sc.airframe, default_pid_gains(), rec.extra["rate_hz"])
    pid.update(0.0, rec.x[0], rec.ref[0])
    pid.reset()
    t_pid = median_ns(lambda i: pid.update(rec.t_s[i], rec.x[i], rec.ref[i]), n) / 1e3
    return [
        Row("TLC step, TLController.update (median)", t_update, "us", *below(t_update, 50.0)),
        Row("TLC step, tlc_kernel called from Python", t_kernel, "us", *below(t_kernel, 30.0)),
        Row("PID step, PIDController.update / the TLC step above", t_pid / t_update, "x"),
        Row("closed-loop tick in the compiled loop", per_tick, "us", *below(per_tick, 20.0)),
        Row("replayed commands equal the flight's", float(same), "bool", "1", same),
    ]


@bench("plant")
def bench_plant_step() -> list[Row]:
    rec = flight()
    sc = scenario()
    plant = Plant(sc.airframe, rec.x[6000])
    plant.set_pitches(rec.pitches[6000])
    plant.step(0.01)  # load the kernel
    dt = 1.0 / rec.extra["rate_hz"]
    x, u, c = rec.x[6000], plant.u.copy(), plant.constants

    def step(i: int) -> None:
        plant.x = x.copy()
        plant.step(dt)

    def kernel(i: int) -> None:
        plant_step(0.0, x, u, c, dt, 1, True)

    n = 20000
    t_step = median_ns(step, n) / 1e3
    t_kernel = median_ns(kernel, n) / 1e3
    return [
        Row("plant RK4 step, Plant.step (10 ms, 1 sub-step)", t_step, "us", *below(t_step, 50.0)),
        Row("plant RK4 step, plant_step from Python", t_kernel, "us", *below(t_kernel, 30.0)),
    ]


@bench("in-process closed loop")
def bench_realtime() -> list[Row]:
    rows = []
    for ff in ("pseudo", "exact"):
        s = flight(ff).summary()
        rtf = float(s["realtime_factor"])
        rows.append(Row(f"paper 120 s at 100 Hz, {ff}: real-time factor", rtf, "x", *above(rtf, 100.0)))
        rows.append(Row(f"paper 120 s at 100 Hz, {ff}: wall time", s["wall_s"] * 1e3, "ms"))
    # the same compiled loop, the PID's law dispatched by its constants' type (control_law)
    opts = SimOptions(controller="pid")
    simulate(scenario(), opts)
    wall = min(simulate(scenario(), opts).wall_s for _ in range(3))
    rtf = 120.0 / wall
    rows.append(Row("paper 120 s at 100 Hz, PID: real-time factor", rtf, "x", *above(rtf, 100.0)))
    return rows


@bench("plant integration accuracy")
def bench_accuracy() -> list[Row]:
    """The paper scenario (pseudo, 100 Hz) with one 10 ms RK4 step per tick against 40 steps
    of 0.25 ms: same controller, so the gap is the plant integration error fed back."""
    coarse, fine = flight("pseudo", 1), flight("pseudo", 40)
    d = np.linalg.norm(coarse.x[:, POS] - fine.x[:, POS], axis=1)
    d_max, d_rms = float(d.max()), float(np.sqrt(np.mean(d**2)))

    def rms45(r: FlightRecord) -> float:
        m = r.window(45.0, 120.0)
        return float(np.sqrt(np.mean(r.pos_err_m[m] ** 2)))

    gap = abs(rms45(coarse) - rms45(fine))
    return [
        Row("position gap 10 ms vs 0.25 ms RK4, max", d_max, "m", *below(d_max, 1e-3)),
        Row("position gap 10 ms vs 0.25 ms RK4, RMS", d_rms, "m", *below(d_rms, 1e-3)),
        Row("RMS error [45, 120] s, 10 ms RK4", rms45(coarse), "m", *below(rms45(coarse), 0.05)),
        Row("RMS error [45, 120] s change, 10 ms vs 0.25 ms", gap, "m", *below(gap, 1e-4)),
    ]


@bench("in-process closed loop, world")
def bench_world() -> list[Row]:
    """The paper flight with every effect of the world on (``--world everything``), and
    each effect alone: its cost per plant step over the ideal world's flight (best of 3)."""
    from heli_common.world.config import AirLoads, Disturbance, Gust, Turbulence, Wind, World

    PAPER = PlantModel("paper")

    sc = Scenario.load("paper")
    everything = World.load("everything")

    def wall(world: World | None, plant: PlantModel = PAPER) -> float:
        return min(simulate(sc, SimOptions(world=world, plant=plant)).wall_s for _ in range(3))

    n_steps = round(sc.run.duration_s * sc.run.rate_hz)
    ideal = wall(None)
    t_all = wall(everything)
    rtf = sc.run.duration_s / t_all
    gav = PlantModel.load("gavrilets")
    t_gav = wall(everything, gav)
    rtf_gav = sc.run.duration_s / t_gav
    rows = [
        Row("paper 120 s at 100 Hz, --world everything: real-time factor", rtf, "x", *above(rtf, 1000.0)),
        Row("  floor: the same flight in the ideal world, per tick", ideal / n_steps * 1e6, "us"),
        Row("same on --plant gavrilets (rotor plant): real-time factor", rtf_gav, "x",
            *above(rtf_gav, 1000.0)),
        Row("  cost per tick of the rotor plant over the paper plant, both in everything",
            (t_gav - t_all) / n_steps * 1e6, "us"),
    ]  # fmt: skip
    air = AirLoads(fuselage=True)
    effects = {
        "servos (delay, lag, rate, quantum, dead band)": World(servos=everything.servos),
        "steady wind + fuselage drag": World(wind=Wind(speed_m_s=3.0), air=air),
        "rotor inflow (both rotors, Newton)": World(air=AirLoads(rotor_inflow=True)),
        "Dryden turbulence (+ drag)": World(turbulence=Turbulence(w20_m_s=3.0), air=air),
        "1-cosine gust (+ drag)": World(gust=Gust(amplitude_m_s=2.0), air=air),
        "injected sinusoidal force": World(disturbance=Disturbance(kind="sine", force_n=(1.0, 0.0, 0.0),
                                                                     frequency_hz=0.2)),
    }  # fmt: skip
    # Each effect against the same code path with no effect that costs anything: the world
    # path with only a model mismatch (it changes constants, not work). Subtracting the ideal
    # world's flight compared two paths and let noise pick the sign. Interleaved, best of 5.
    base_world = World(mismatch=everything.mismatch)
    worlds = {"base": base_world, **effects}
    best = dict.fromkeys(worlds, math.inf)
    for _ in range(5):
        for name, world in worlds.items():
            best[name] = min(best[name], simulate(sc, SimOptions(world=world, plant=PAPER)).wall_s)
    rows.append(Row("  baseline: the world path, a model mismatch only (constants), per tick",
                    best["base"] / n_steps * 1e6, "us"))  # fmt: skip
    for name in effects:
        cost = (best[name] - best["base"]) / n_steps * 1e6
        rows.append(Row(f"  cost per plant step: {name}", cost, "us"))
    return rows


@bench("in-process closed loop, sensors and estimator")
def bench_sensors() -> list[Row]:
    """The paper flight from sensors (the sensor models, the wire's rounding and the
    estimator each tick): with every world effect and the `noisy` sensors at once, and each
    preset's cost per tick over the same world path without sensors (interleaved, best of 5)."""
    import dataclasses

    from autopilot.estimation.config import EstimatorConfig
    from heli_common.world.config import World

    sc = Scenario.load("paper")
    noisy = World.load("noisy")
    everything = World.load("everything")
    both = dataclasses.replace(everything, sensors=dataclasses.replace(noisy.sensors, seed=everything.seed))

    def wall(world: World | None, est: EstimatorConfig | None = None) -> float:
        opts = SimOptions(world=world, estimator=est or EstimatorConfig())
        return min(simulate(sc, opts).wall_s for _ in range(3))

    n_steps = round(sc.run.duration_s * sc.run.rate_hz)
    ideal = wall(None)
    est = EstimatorConfig.load("noisy")
    t_all = wall(both, dataclasses.replace(est, attitude="ins"))
    t_ahrs = wall(both, dataclasses.replace(est, attitude="ideal-ahrs"))
    rtf = sc.run.duration_s / t_all
    rtf_ahrs = sc.run.duration_s / t_ahrs
    rows = [
        # issue 24's target: the navigation filter (the default estimator since issue 24)
        Row("paper 120 s at 100 Hz, everything + noisy sensors + navigation filter: real-time factor",
            rtf, "x", *above(rtf, 1000.0)),
        # issue 25's target, on "today's estimator" of its text: the per-axis filters, the only
        # estimator when it was filed (its 800-1185x were theirs; the filter came with issue 24)
        Row("  the same on the attitude source and per-axis filters (ideal-ahrs)", rtf_ahrs, "x",
            *above(rtf_ahrs, 1500.0)),
        Row("  cost per tick of the navigation filter over the per-axis filters",
            (t_all - t_ahrs) / n_steps * 1e6, "us"),
        Row("  floor: the same flight in the ideal world, per tick", ideal / n_steps * 1e6, "us"),
        # The target in floors: 1500x is 6.67 us a tick, set on the host whose ideal-world
        # tick was 1.829 us (README, 2026-11-25); hosts lent here differ by 20 % from day
        # to day, the ratio to the floor measured beside it does not (3.71-3.83 for one
        # code on two hosts)
        Row("  the navigation-filter flight's tick in floors (the ideal world's tick beside it)",
            t_all / ideal, "x", *below(t_all / ideal, FLOORS_AT_1500X)),
    ]  # fmt: skip
    # Each preset against the same code path with the sensors off: the world path with only a
    # model mismatch (constants, no work). The ideal world's flight runs another path (no
    # world arrays), and subtracting it let the machine's noise pick the sign. The presets'
    # own air (if any) is the same in both: only their sensors are taken.
    presets = {name: World.load(name) for name in ("gps-typical", "imu-consumer", "noisy")}
    base = World(mismatch=everything.mismatch)
    worlds = {"base": base, **{n: dataclasses.replace(base, sensors=w.sensors) for n, w in presets.items()}}
    best = dict.fromkeys(worlds, math.inf)
    for _ in range(5):
        for name, world in worlds.items():
            opts = SimOptions(world=world, estimator=EstimatorConfig())
            best[name] = min(best[name], simulate(sc, opts).wall_s)
    rows.append(Row("  baseline: the world path without sensors (a model mismatch only), per tick",
                    best["base"] / n_steps * 1e6, "us"))  # fmt: skip
    for name in presets:
        cost = (best[name] - best["base"]) / n_steps * 1e6
        rows.append(Row(f"  cost per tick: sensors + estimator, {name}", cost, "us"))
    return rows
