"""The whole closed loop linearised (heli_sitl.loop_linear) against simulation."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.controllers import build_controller
from autopilot.scenario import Scenario
from heli_common.plant_model import PlantModel
from heli_common.state import EPS
from heli_common.world import Servos, World
from heli_sitl.closed_loop import SimOptions, simulate
from heli_sitl.loop_linear import linearize_loop, servo_model

SC = Scenario.load("paper")


def _tlc():  # type: ignore[no-untyped-def]
    return build_controller("tlc", SC.airframe, SC.gains, 100.0)


def test_table2_on_the_paper_plant_is_stable_with_margins() -> None:
    lin = linearize_loop(_tlc(), PlantModel.load("paper"), SC.airframe, Servos(), "ideal")
    assert lin.stable and 0.99 < lin.spectral_radius < 1.0  # the slow integral modes, 0.13 rad/s
    eps = next(b for b in lin.break_points if b.name == "input eps")
    # the balanced disk at the cyclic input: 0.71 (+/- 16.2 dB, +/- 39 deg) with ideal servos
    assert 0.65 < eps.disk_margin < 0.78
    assert 35.0 < eps.phase_margin_deg < 43.0
    # the default servos (10 ms + 20 ms) shrink it to 0.32 (18 deg)
    sv = World.load("servos-default").servos
    slow = linearize_loop(_tlc(), PlantModel.load("paper"), SC.airframe, sv, "default")
    eps2 = next(b for b in slow.break_points if b.name == "input eps")
    assert 0.28 < eps2.disk_margin < 0.36


def test_table2_on_the_rotor_plant_is_unstable_at_the_simulated_limit_cycle() -> None:
    """The linear check predicts a growing rotor-body oscillation; the nonlinear flight shows
    it as a limit cycle of the cyclic between its stops at the same frequency."""
    name, sv = servo_model("ideal")
    lin = linearize_loop(_tlc(), PlantModel.load("gavrilets"), SC.airframe, sv, name)
    assert not lin.stable
    w_lin = abs(lin.dominant_rad_s.imag)
    assert 22.0 < w_lin < 30.0  # 26 rad/s
    rec = simulate(SC, SimOptions(duration_s=20.0, plant=PlantModel.load("gavrilets")))
    e = rec.pitches[rec.t_s >= 10.0, EPS]
    crossings = np.count_nonzero(np.diff(np.sign(e - e.mean())) != 0)
    w_sim = np.pi * crossings / 10.0  # two crossings a period
    print(f"linear {w_lin:.1f} rad/s, simulated limit cycle {w_sim:.1f} rad/s")
    assert w_sim == pytest.approx(w_lin, rel=0.15)
    # and it is a limit cycle, not a divergence: the cyclic sits on its stops, the flight goes on
    assert np.mean(np.abs(e) >= 0.14 - 1e-9) > 0.3
    assert np.all(np.isfinite(rec.x))
