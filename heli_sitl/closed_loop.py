"""In-process closed loop: controller and plant in one process, fixed control rate.

This loop is the only owner of time here: tick k is at t = k / rate, the controller sees
the state at t, its pitches are held (zero-order hold) while the plant integrates to t+dt.
The loop itself is compiled and calls the very kernels the processes use
(:func:`~autopilot.tlc.controller.tlc_kernel`, :func:`~heli_sitl.plant.model.plant_step`,
:func:`~heli_sitl.plant.model.accept_pitches`); a trajectory is a pure function of time, so
the references for every tick are sampled up front.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

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
from heli_sitl.plant.model import Plant, accept_pitches, plant_step

Progress = Callable[[int, int], None]
CHUNK_TICKS = 500  # progress granularity; each chunk is one compiled call


@dataclass(frozen=True)
class SimOptions:
    rate_hz: float | None = None  # None: the scenario's
    feedforward: str | None = None
    plant_substeps: int | None = None
    duration_s: float | None = None


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
    )
    n = round(duration * rate_hz)
    t = np.arange(n + 1) / rate_hz
    refs = scenario.trajectory.sample(t)
    xs = np.empty((n + 1, plant.x.size))
    us = np.empty((n + 1, N_PITCH))
    diags = np.empty((n + 1, N_DIAG))
    x = plant.x
    # load (or compile) the kernels outside the timed flight, on throwaway copies
    _run_ticks(
        ctrl.constants, ctrl.state.copy(), plant.constants, plant.lo, plant.hi, plant.u.copy(),
        x, refs, t, 0, 1, n, plant.substeps, xs, us, diags,
    )  # fmt: skip
    wall0 = time.perf_counter()
    for k0 in range(0, n + 1, CHUNK_TICKS):
        k1 = min(n + 1, k0 + CHUNK_TICKS)
        x = _run_ticks(
            ctrl.constants, ctrl.state, plant.constants, plant.lo, plant.hi, plant.u,
            x, refs, t, k0, k1, n, plant.substeps, xs, us, diags,
        )  # fmt: skip
        if progress is not None:
            progress(k1 - 1, n)
    wall = time.perf_counter() - wall0
    extra = {"scenario": run.name, "rate_hz": rate_hz, "feedforward": ctrl.feedforward.value,
             "plant_substeps": plant.substeps}  # fmt: skip
    return FlightRecord.from_ticks(t, xs, refs, us, diags, wall, extra)
