"""In-process closed loop: controller and plant in one process, fixed control rate.

This loop is the only owner of time here: tick k is at t = k / rate, the controller sees
the state at t, its pitches are held (zero-order hold) while the plant integrates to t+dt.
The loop itself is compiled and calls the very kernels the processes use
(:func:`~autopilot.tlc.controller.tlc_kernel`, :func:`~heli_sitl.plant.model.plant_step`,
:func:`~heli_sitl.plant.model.accept_pitches`); a trajectory is a pure function of time, so
the references for every tick are sampled up front.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from autopilot.metrics import FlightRecord
from autopilot.scenario import Scenario
from autopilot.tlc.controller import (
    N_DIAG,
    TLCConstants,
    TLController,
    tlc_kernel,
)
from heli_common.airframe import PlantConstants
from heli_common.jit import njit
from heli_common.state import N_PITCH, FloatArray
from heli_common.world import World
from heli_sitl.plant.model import Plant, accept_pitches, plant_step
from heli_sitl.plant.world.model import N_WP, N_WS, WS_AIR, WS_PITCH, AirConstants, world_plant_step

Progress = Callable[[int, int], None]
CHUNK_TICKS = 500  # progress granularity; each chunk is one compiled call


@dataclass(frozen=True)
class SimOptions:
    rate_hz: float | None = None  # None: the scenario's
    feedforward: str | None = None
    plant_substeps: int | None = None
    duration_s: float | None = None
    world: World | None = None  # None: the paper's ideal world


@njit
def _run_ticks(
    k: TLCConstants,
    ctrl_state: FloatArray,
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
) -> FloatArray:
    x = x0.copy()
    out = np.empty(N_PITCH)
    diag = np.zeros(N_DIAG)
    dt = k.dt_s
    for i in range(k0, k1):
        tlc_kernel(k, ctrl_state, x, refs[i], False, out, diag)
        xs[i] = x
        us[i] = out
        diags[i] = diag
        if i < n_last:
            accept_pitches(out, lo, hi, held)
            if in_world:
                x, _ = world_plant_step(
                    t[i], x, held, c, air, dt, n_sub, True, wp, ws, servo_p, servo_s, dryden
                )
                # the truth of the hold that led to the next state, as the plant reports it
                airs[i + 1] = ws[WS_AIR : WS_AIR + 3]
                applied[i + 1] = ws[WS_PITCH : WS_PITCH + N_PITCH]
            else:
                x, _ = plant_step(t[i], x, held, c, dt, n_sub, True)
    return x


def simulate(
    scenario: Scenario, opts: SimOptions = SimOptions(), progress: Progress | None = None
) -> FlightRecord:
    run = scenario.run
    rate_hz = opts.rate_hz or run.rate_hz
    duration = opts.duration_s or run.duration_s
    ctrl = TLController(
        scenario.airframe, scenario.gains, rate_hz, opts.feedforward or run.feedforward
    )
    plant = Plant(
        scenario.airframe,
        scenario.initial.state().to_array(),
        substeps=opts.plant_substeps or run.plant_substeps,
        world=opts.world,
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
    w = plant.world or CALM_ARRAYS
    if plant.world is not None:
        # the servos start where the first command puts them, as in the plant process
        first = copy.deepcopy(ctrl).update(0.0, x, refs[0])
        u0 = plant.u.copy()
        accept_pitches(first, plant.lo, plant.hi, u0)
        plant.world.prepare(1.0 / rate_hz / plant.substeps, u0, np.column_stack([plant.lo, plant.hi]))

    def ticks(k0: int, k1: int, state: FloatArray, held: FloatArray, ws: FloatArray, servo_s: FloatArray,
              x: FloatArray) -> FloatArray:  # fmt: skip
        return _run_ticks(
            ctrl.constants, state, plant.constants, plant.lo, plant.hi, held, x, refs, t, k0, k1, n,
            plant.substeps, xs, us, diags, plant.world is not None, w.air, w.wp, ws, w.servo_p,
            servo_s, w.dryden, airs, applied,
        )  # fmt: skip

    # load (or compile) the kernels outside the timed flight, on throwaway copies
    ticks(0, 1, ctrl.state.copy(), plant.u.copy(), w.ws.copy(), w.servo_s.copy(), x)
    wall0 = time.perf_counter()
    for k0 in range(0, n + 1, CHUNK_TICKS):
        k1 = min(n + 1, k0 + CHUNK_TICKS)
        x = ticks(k0, k1, ctrl.state, plant.u, w.ws, w.servo_s, x)
        if progress is not None:
            progress(k1 - 1, n)
    wall = time.perf_counter() - wall0
    extra: dict[str, object] = {
        "scenario": run.name, "rate_hz": rate_hz, "feedforward": ctrl.feedforward.value,
        "plant_substeps": plant.substeps, "gains": scenario.gains.name,
    }  # fmt: skip
    if plant.world is not None:
        extra["world"] = plant.world.world.describe(scenario.airframe)
    rec = FlightRecord.from_ticks(t, xs, refs, us, diags, wall, extra)
    if plant.world is not None:
        rec = dataclasses.replace(rec, air_nwu_m_s=airs, servo_rad=applied)
    return rec


@dataclass(frozen=True)
class _Calm:
    """Placeholder world arrays for the compiled loop when the world is off (never read)."""

    air: AirConstants = AirConstants(False, False, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    wp: FloatArray = field(default_factory=lambda: np.zeros(N_WP))
    ws: FloatArray = field(default_factory=lambda: np.zeros(N_WS))
    servo_p: FloatArray = field(default_factory=lambda: np.zeros((N_PITCH, 1)))
    servo_s: FloatArray = field(default_factory=lambda: np.zeros(1))
    dryden: FloatArray = field(default_factory=lambda: np.zeros(1))


CALM_ARRAYS = _Calm()
