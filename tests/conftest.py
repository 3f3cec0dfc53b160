"""Shared fixtures: the X-Cell airframe, the paper gains and a converged hover equilibrium.

The closed-loop helpers fly the controller kernel and the plant through
:func:`heli_sitl.engine.closed_loop._run_ticks`, the same compiled loop ``simulate`` uses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import heli_common  # noqa: F401  (first: one BLAS thread per test worker, before numpy loads)

# isort: split
import lanes
import numpy as np
import pytest
from hypothesis import settings
from xdist.remote import Producer
from xdist.workermanage import WorkerController

from autopilot.reference import N_REF
from autopilot.tlc.controller import N_DIAG, TLCConstants, TLController
from autopilot.tlc.gains import Gains
from heli_common.state import N_PITCH, N_STATE, PSI, Z_U, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_plant.model import Plant
from heli_plant.rotor import N_ROTOR
from heli_plant.rotor import OFF as ROTOR_OFF
from heli_plant.trim import PlantFunction
from heli_plant.world.model import CalmArrays
from heli_sitl.engine.closed_loop import SensingArrays, _run_ticks

# The first call of a compiled function loads (or compiles) it: no per-example deadline.
# HYPOTHESIS_PROFILE=thorough runs 20x more examples per property.
settings.register_profile("heli", deadline=None)
settings.register_profile("thorough", deadline=None, max_examples=2000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "heli"))

# pytest-xdist (`make test`: a real-time and a CPU worker per core, at most four, in the
# lanes of tests/lanes.py) hands out the tests file by file (`--dist loadfile`), so that a
# module's fixtures (a running vehicle, a flown mission, a MAVSDK session, the margins of a
# gain set) are built once, not once on each worker that gets one of its tests. Process tests
# run side by side: each binds free loopback ports, or lives in a private network namespace
# it makes. The markers are labels: `processes` (starts processes on the host's loopback)
# and `netns` (all its processes in a namespace of its own); `-m "not processes and not
# netns"` is the in-process suite.
PROCESS_MODULES = lanes.PROCESS_MODULES


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """`-n auto`: a real-time and a CPU worker per core (tests/lanes.py).
    PYTEST_XDIST_AUTO_NUM_WORKERS still decides where it is set."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None  # xdist's own hook reads it
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return lanes.workers(cores)


def pytest_xdist_make_scheduler(config: pytest.Config, log: Producer) -> lanes.LaneScheduling | None:
    if config.getoption("dist") != "loadfile":
        return None
    return lanes.LaneScheduling(config, log)


def pytest_configure_node(node: WorkerController) -> None:
    """The controller tells each worker whether the lanes schedule it (`--dist loadfile`)."""
    node.workerinput["lanes"] = node.config.getoption("dist") == "loadfile"


def pytest_configure(config: pytest.Config) -> None:
    worker = getattr(config, "workerinput", None)
    if worker is not None and worker.get("lanes"):  # elsewhere no worker is niced
        lanes.enter_lane(worker["workerid"], int(worker["workercount"]))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        module = item.module.__name__.rsplit(".", 1)[-1] if isinstance(item, pytest.Function) else ""
        if module in PROCESS_MODULES:
            item.add_marker(pytest.mark.processes)


RATE_HZ = 100.0
HOVER_ALT_M = 50.0  # far from the ground plane (contact would level the attitude)
HOVER_PSI_RAD = 0.3
SETTLE_S = 400.0  # the slowest closed-loop mode (loop 1) decays as exp(-0.13 t)


@pytest.fixture(scope="session")
def airframe() -> Airframe:
    return Airframe.load()


@pytest.fixture(scope="session")
def consts(airframe: Airframe) -> PlantConstants:
    return airframe.constants()


@pytest.fixture(scope="session")
def gains() -> Gains:
    return Gains.load()


@dataclass
class TickRecord:
    x: FloatArray  # (n+1, 12) state at each tick
    u: FloatArray  # (n+1, 4) pitches commanded at each tick
    diag: FloatArray  # (n+1, N_DIAG)
    t: FloatArray
    x_next: FloatArray  # the state one period after the last tick (pairs with the ctrl state)


def fly(
    k: TLCConstants,
    ctrl_state: FloatArray,
    plant: Plant,
    x0: FloatArray,
    refs: FloatArray,
) -> TickRecord:
    """Closed loop over len(refs) ticks from ``x0``; ``ctrl_state`` is updated in place.

    After the call, (``x_next``, ``ctrl_state``) is the closed-loop state one period after
    the last tick, ready for the next one.
    """
    n = refs.shape[0] - 1
    t = np.arange(n + 1) * k.dt_s
    xs = np.empty((n + 1, N_STATE))
    us = np.empty((n + 1, N_PITCH))
    diags = np.empty((n + 1, N_DIAG))
    held = np.zeros(N_PITCH)
    w = CalmArrays()  # the paper's ideal world
    x_next = _run_ticks(
        k, ctrl_state, k.dt_s, plant.constants, plant.lo, plant.hi, held,
        np.asarray(x0, dtype=float), refs, t, 0, n + 1, n + 1, plant.substeps, xs, us, diags, False, w.air,
        w.wp, w.ws, w.servo_p, w.servo_s, w.dryden, np.zeros((n + 1, 3)), np.zeros((n + 1, N_PITCH)),
        *SensingArrays.off().args(), np.zeros(1), ROTOR_OFF,
        np.zeros((1, N_ROTOR + 1)), False,  # sim_link off: the model's exact arithmetic
    )  # fmt: skip
    return TickRecord(xs, us, diags, t, x_next)


def hover_refs(pos: FloatArray, seconds: float, rate_hz: float = RATE_HZ) -> FloatArray:
    ref = np.zeros(N_REF)
    ref[0:3] = pos
    n = round(seconds * rate_hz)
    return np.tile(ref, (n + 1, 1))


@dataclass
class HoverEquilibrium:
    ctrl: TLController  # its .constants and .state are the equilibrium's
    plant: Plant
    x: FloatArray  # plant state at the equilibrium
    u: FloatArray  # pitches held there
    ref: FloatArray  # (9,) the constant hover reference


@pytest.fixture(scope="session")
def hover_eq(airframe: Airframe, gains: Gains) -> HoverEquilibrium:
    """Fly a constant hover reference for SETTLE_S seconds from a level start; the final
    plant and controller states are the closed loop's hover equilibrium."""
    ctrl = TLController(airframe, gains, RATE_HZ, "pseudo")
    x0 = np.zeros(N_STATE)
    x0[Z_U] = HOVER_ALT_M - 1.0
    x0[PSI] = HOVER_PSI_RAD
    plant = Plant(airframe, x0)
    pos = np.array([0.0, 0.0, HOVER_ALT_M])
    f = fly(ctrl.constants, ctrl.state, plant, x0, hover_refs(pos, SETTLE_S))
    return HoverEquilibrium(ctrl, plant, f.x_next, f.u[-1].copy(), hover_refs(pos, 0.0)[0])


def integrate_held(
    fn: PlantFunction, x0: np.ndarray, u: np.ndarray, seconds: float, idx: list[int], h: float = 1e-3
) -> np.ndarray:
    """The states ``idx`` over time with every other state held (RK4, step ``h``): the rotor's
    own dynamics with the body fixed, as a rotor on a test stand."""
    x = x0.copy()
    out = [x[idx].copy()]

    def f(z: np.ndarray) -> np.ndarray:
        y = x.copy()
        y[idx] = z
        return np.asarray(fn(y, u)[idx])

    for _ in range(round(seconds / h)):
        z = x[idx]
        k1 = f(z)
        k2 = f(z + 0.5 * h * k1)
        k3 = f(z + 0.5 * h * k2)
        k4 = f(z + h * k3)
        x[idx] = z + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x[idx].copy())
    return np.array(out)
