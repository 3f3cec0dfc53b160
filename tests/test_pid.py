"""The cascaded PID baseline (autopilot/pid): its rate loop against theory, anti-windup under
saturation, the same contract as the TLC in-process and over processes."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from autopilot.pid.controller import (
    N_PID_STATE,
    P_I_RATE,
    P_I_VEL,
    PIDController,
    make_pid_constants,
    rate_loop,
)
from autopilot.pid.gains import PidGains
from autopilot.reference import N_REF
from autopilot.scenario import Scenario
from autopilot.tlc.controller import D_TILT_LIMITED
from heli_common.vehicle.airframe import Airframe
from heli_sitl.engine.closed_loop import SimOptions, simulate


@pytest.mark.parametrize("gains_file", ["starts/pid_table2.toml", "gains_pid.toml"])
def test_rate_loop_step_matches_its_design_on_the_hover_inertia(gains_file: str) -> None:
    """About hover the body rates obey J w' = tau - w x J w, and the PID commands
    tau = J alpha + w x J w: each axis is w' = alpha = ff wc + kp e + ki int(e) - kd w'_filtered,
    and the rate loop closes to ((kp + ff) s + ki) / ((1 + kd) s^2 + kp s + ki) (the
    derivative filter, 20 Hz, far above the loop; the set point's feed-forward ff only in the
    numerator). Table 2's design: omega_n = sqrt(ki) = 12 rad/s,
    zeta = kp / (2 omega_n) = 0.708; the tuned gains have their own. The compiled loop at
    100 Hz (w held over a tick) gives that step response."""
    gains = PidGains.load(gains_file)
    k = make_pid_constants(Airframe.load(), gains, 100.0)
    s = np.zeros(N_PID_STATE)
    w = np.zeros(3)
    wc = np.array([0.2, 0.0, 0.0])  # a 0.2 rad/s roll-rate step
    n = 150
    out = np.empty(n)
    for i in range(n):
        out[i] = w[0]
        alpha = rate_loop(k, s, w, wc, i == 0)
        s[P_I_RATE : P_I_RATE + 3] += k.dt_s * (wc - w)  # as the kernel integrates (no saturation)
        w = w + k.dt_s * alpha
    kp, ki, kd, ff = gains.rate.kp[0], gains.rate.ki[0], gains.rate.kd[0], gains.rate.ff[0]
    t = np.arange(n) * k.dt_s
    _, theory = signal.step(signal.lti([kp + ff, ki], [1.0 + kd, kp, ki]), T=t)
    if gains_file == "starts/pid_table2.toml":
        assert math.sqrt(ki) == pytest.approx(12.0)
        assert kp / (2 * math.sqrt(ki)) == pytest.approx(0.708, abs=1e-3)
    # Euler's discretisation at dt omega_n <= 0.12: within 5 % of the 0.2 step everywhere
    np.testing.assert_allclose(out, 0.2 * theory, atol=0.05 * 0.2)
    rise = t[np.argmax(out >= 0.9 * 0.2)]
    rise_theory = t[np.argmax(theory >= 0.9)]
    assert rise == pytest.approx(rise_theory, abs=0.03)
    # the overshoot: the tick's hold adds up to 3 points (Table 2: 20.7 % continuous)
    assert out.max() / 0.2 - 1 == pytest.approx(theory.max() - 1, abs=0.04)


def test_integrators_hold_under_saturation() -> None:
    """300 m off the reference: the tilt limit and the pitch limits saturate for seconds;
    the velocity integrator does not move while the tilt is limited and the rate
    integrator stays within its clamp, so nothing winds up."""
    af = Airframe.load()
    ctrl = PIDController(af, PidGains.load(), 100.0)  # the shipped (tuned) gains
    x = np.zeros(12)
    x[2] = 20.0
    ref = np.zeros(N_REF)
    ref[0:3] = (300.0, 0.0, 20.0)
    limited = 0
    for _ in range(300):
        ctrl.update(0.0, x, ref)
        if ctrl.diag[D_TILT_LIMITED]:
            limited += 1
            assert np.all(ctrl.state[P_I_VEL : P_I_VEL + 3] == 0.0)
        clamp = ctrl.constants.i_max_rate / ctrl.constants.ki_rate
        assert np.all(np.abs(ctrl.state[P_I_RATE : P_I_RATE + 3]) <= clamp + 1e-12)
    assert limited == 300


def test_both_controllers_fly_the_paper_in_process_and_nothing_else_changes() -> None:
    sc = Scenario.load("paper")
    tlc = simulate(sc, SimOptions(duration_s=60.0))
    pid = simulate(sc, SimOptions(duration_s=60.0, controller="pid"))
    st, sp = tlc.summary(), pid.summary()
    assert sp["controller"] == "pid" and st["controller"] == "tlc"
    assert set(sp) == set(st)  # the same record, the same figures
    assert pid.rows().shape == tlc.rows().shape
    assert sp["rms_pos_err_m"]["10-60"] < 0.5 and sp["max_abs_phi_rad"] < 0.35
    assert not np.array_equal(pid.pitches, tlc.pitches)
    with pytest.raises(ValueError, match="tlc, pid or module:Class"):
        simulate(sc, SimOptions(duration_s=1.0, controller="lqr"))


@pytest.mark.processes
@pytest.mark.slow
def test_pid_in_lockstep_processes_flies_the_in_process_flight(tmp_path: Path) -> None:
    from ground.plots import read_csv_columns
    from heli_sitl.launch.demo import DemoOptions, run_demo

    rec = simulate(Scenario.load("paper"), SimOptions(duration_s=30.0, controller="pid"))
    opts = DemoOptions(mode="lockstep", out=tmp_path, timeout_s=600, via_ground=False, duration_s=30.0,
                       extra_autopilot_args=("--controller", "pid"))  # fmt: skip
    summary = run_demo(opts)
    cols = read_csv_columns(tmp_path / "run.csv")
    ref = rec.columns()
    d = np.stack([cols[k] - ref[k] for k in ("x_m", "y_m", "z_m")], axis=1)
    print(f"PID lockstep vs in-process: max {np.abs(d).max():.2e} m")
    assert cols["t_s"].size == ref["t_s"].size and np.abs(d).max() < 1e-3
    assert summary["controller"] == "pid"


def test_pid_gains_are_live_parameters() -> None:
    """The PID_ parameters reach the PID controller between two ticks (the TLC_ ones the
    TLC), through the autopilot's own apply step."""
    from autopilot.cli import apply_params
    from autopilot.flight.manager import FlightConfig, FlightManager
    from autopilot.params_table import ParamTable
    from autopilot.tlc.controller import TLController
    from heli_common.defaults import HOME

    sc = Scenario.load("paper")
    pid = PIDController(sc.airframe, PidGains.load(), 100.0)
    tlc = TLController(sc.airframe, sc.gains, 100.0)
    table = ParamTable(sc.gains, sc.airframe.limits, 100.0, pid_gains=pid.gains)
    assert table.set("PID_RATE_P_R", 9.5, armed=True).accepted
    assert table.set("TLC_L4_W_R", 10.0, armed=True).accepted
    manager = FlightManager(FlightConfig(home=HOME))
    apply_params(pid, manager, table)
    apply_params(tlc, manager, table)
    assert pid.gains.rate.kp[0] == 9.5 and pid.constants.kp_rate[0] == 9.5
    assert tlc.gains.loop4_attitude_dynamics.omega_rad_s[0] == 10.0


@pytest.mark.slow
def test_a_ground_station_sees_the_same_vehicle_with_either_controller() -> None:
    """``heli-sitl up --controller pid``: the same parameter table (PID_ values from the
    shipped file, settable live), the same telemetry messages as the TLC vehicle."""
    from test_ground_client import client, running_vehicle

    from autopilot.params_table import SPECS

    seen: dict[str, set[str]] = {}
    for controller in ("tlc", "pid"):
        with running_vehicle("--controller", controller) as v, client(v.gcs_port) as gc:
            params = gc.param_list()
            assert len(params) == len(SPECS)
            pid = PidGains.load()
            assert params["PID_RATE_I_Y"].value == pytest.approx(pid.rate.ki[2], rel=1e-6)
            assert params["PID_POS_P_Z"].value == pytest.approx(pid.position.kp[2], rel=1e-6)
            res = gc.param_set("PID_ATT_P_R", 2.5)
            assert res.accepted and res.value.value == 2.5
            types: set[str] = set()
            t_end = time.monotonic() + 2.0
            while time.monotonic() < t_end:
                types |= {m.get_type() for m in gc.poll(0.1) if gc.from_vehicle(m)}
            seen[controller] = types - {"PARAM_VALUE", "STATUSTEXT", "COMMAND_ACK"}
    print(f"telemetry: {sorted(seen['pid'])}")
    assert seen["pid"] == seen["tlc"] and {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED"} <= seen["pid"]
