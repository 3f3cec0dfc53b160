"""Closed loop (heli_sitl.engine.closed_loop.simulate): the paper scenario against the spec's bounds,
linearised stability of hover and climb, a climb in simulation and rate sensitivity."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import RATE_HZ, HoverEquilibrium, fly
from numpy.testing import assert_allclose
from scipy.optimize import fsolve

from autopilot.metrics import FlightRecord
from autopilot.scenario import Scenario
from autopilot.tlc.controller import (
    N_DIAG,
    S_LAST_U,
    S_PSI_C,
    S_SENT,
    S_STARTED,
    TLCConstants,
    TLController,
    tlc_kernel,
)
from autopilot.tlc.gains import Gains
from autopilot.trajectory.analytic import StraightLine
from heli_common.state import N_PITCH, N_STATE, OMEGA, PHI, THETA, VEL, Z_U, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_plant.dynamics import derivative
from heli_plant.model import Plant, accept_pitches, plant_step
from heli_sitl.engine.closed_loop import SimOptions, simulate

# --- the paper scenario --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


_runs: dict[tuple[str, float], FlightRecord] = {}


def run(paper: Scenario, ff: str, rate_hz: float = 100.0) -> FlightRecord:
    key = (ff, rate_hz)
    if key not in _runs:
        _runs[key] = simulate(paper, SimOptions(rate_hz=rate_hz, feedforward=ff))
    return _runs[key]


def rms(rec: FlightRecord, t0: float, t1: float) -> float:
    m = rec.window(t0, t1)
    return float(np.sqrt(np.mean(rec.pos_err_m[m] ** 2)))


# RMS 3-D position error over [45, 120] s, pseudo feedforward, by control rate [Hz], as the
# in-process flight (deterministic: no random input, no clock) measures it
RMS_PSEUDO_M = {50.0: 0.04087643259, 100.0: 0.04015409608, 400.0: 0.03962897479}


def test_paper_pseudo_100hz(paper: Scenario) -> None:
    """Spec section 7 at 100 Hz, pseudo-differentiators everywhere."""
    rec = run(paper, "pseudo")
    t, e = rec.t_s, rec.pos_err_m
    assert rec.t_s[-1] == pytest.approx(120.0)
    assert np.all(np.isfinite(rec.x))
    # target: about 0.040; README: 0.0402. A deterministic flight: pinned (its own 0.0037 m
    # with the exact feedforward shows the pseudo-differentiator lag is really there)
    assert rms(rec, 45, 120) == pytest.approx(RMS_PSEUDO_M[100.0], rel=1e-6)
    assert e[rec.window(40, 45)].max() <= 0.3  # target: about 0.25, mostly z
    z_err = np.abs(rec.ref[:, 2] - rec.x[:, Z_U])
    assert z_err[rec.window(40, 45)].max() > 0.8 * e[rec.window(40, 45)].max()
    # error history: overshoot near 11 s, then below 0.1 m from about 26 s (until the jump)
    early = rec.window(5, 20)
    assert 1.0 < e[early].max() < 1.3
    assert 10.0 < t[early][np.argmax(e[early])] < 13.0
    assert e[rec.window(27, 40)].max() < 0.1
    # pitches
    p = rec.pitches
    assert p[:, 0].min() >= 0.08 and p[:, 0].max() <= 0.11  # theta_m
    assert p[:, 1].min() >= 0.08 and p[:, 1].max() <= 0.18  # theta_t
    after = rec.window(1.0, 120.0)
    assert np.abs(p[after, 2:4]).max() <= 0.11  # cyclics, once past the start transient
    # attitude
    assert np.abs(rec.x[:, PHI]).max() < 0.2
    assert np.abs(rec.x[:, THETA]).max() < 0.3
    late = rec.window(10.0, 120.0)
    assert np.abs(rec.x[late, PHI]).max() < 0.05
    assert np.abs(rec.x[late, THETA]).max() < 0.05


def test_paper_pseudo_saturates_only_at_start(paper: Scenario) -> None:
    """Known finding: pseudo mode saturates eps for ~15 ticks in the first 0.7 s, never
    afterwards: the position command's differentiator starts from zero derivative while the
    path already moves at 0.785 m/s, so the outer loops command a fast pitch swing."""
    rec = run(paper, "pseudo")
    sat_t = rec.t_s[rec.saturated]
    assert sat_t.size < 30
    assert np.all(sat_t < 1.0)


def test_paper_exact_100hz(paper: Scenario) -> None:
    rec = run(paper, "exact")
    assert rms(rec, 45, 120) == pytest.approx(0.003678417845, rel=1e-6)  # target: about 0.004; README 0.0037
    assert int(np.count_nonzero(rec.saturated)) == 0
    assert rec.pos_err_m[rec.window(40, 45)].max() <= 0.3
    assert np.abs(rec.x[:, PHI]).max() < 0.2
    assert np.abs(rec.x[:, THETA]).max() < 0.3


@pytest.mark.parametrize("rate_hz", [50.0, 400.0])
def test_paper_rate_sensitivity(paper: Scenario, rate_hz: float) -> None:
    """Spec: 0.0409 / 0.0402 / 0.0396 m RMS over [45, 120] at 50 / 100 / 400 Hz: a faster
    loop tracks better, by 0.0007 m from 100 to 50 Hz and 0.0005 m from 100 to 400 Hz."""
    rec = run(paper, "pseudo", rate_hz)
    r = rms(rec, 45, 120)
    assert r == pytest.approx(RMS_PSEUDO_M[rate_hz], rel=1e-6)
    assert round(r, 4) == {50.0: 0.0409, 400.0: 0.0396}[rate_hz]  # the spec's digits
    assert (r > rms(run(paper, "pseudo"), 45, 120)) == (rate_hz < 100.0)
    assert np.all(rec.t_s[rec.saturated] < 1.0)


def _heading_error(rec: FlightRecord, t0: float) -> float:
    tangent = np.arctan2(rec.ref[:, 4], rec.ref[:, 3])
    d = np.angle(np.exp(1j * (rec.x[:, 8] - tangent)))
    return float(np.abs(d[rec.window(t0, 120.0)]).max())


def test_paper_nose_along_the_path_exact(paper: Scenario) -> None:
    assert _heading_error(run(paper, "exact"), 10.0) < 0.01


def test_paper_nose_along_the_path_pseudo(paper: Scenario) -> None:
    assert _heading_error(run(paper, "pseudo"), 10.0) < 0.05


# --- linearised stability ------------------------------------------------------------------------

_EXCLUDED = {S_PSI_C, S_STARTED, *range(S_LAST_U, S_LAST_U + N_PITCH)}
# the paper's TLC uses the blocks before the rotor-aware ones (from S_SENT on)
CTRL_IDX = np.array([i for i in range(S_SENT) if i not in _EXCLUDED])


def one_tick_map(k: TLCConstants, st_full: FloatArray, plant: Plant, ref: FloatArray):  # type: ignore[no-untyped-def]
    """z = (plant state, controller state without psi_c, started flag and last output) at a
    tick -> z one control period later (the kernel, the servo gate, one RK4 hold)."""

    def step(z: FloatArray) -> FloatArray:
        st = st_full.copy()
        st[CTRL_IDX] = z[N_STATE:]
        x = z[:N_STATE].copy()
        out, diag, held = np.empty(N_PITCH), np.zeros(N_DIAG), np.zeros(N_PITCH)
        tlc_kernel(k, st, x, ref, False, out, diag)
        accept_pitches(out, plant.lo, plant.hi, held)
        x_new, _ = plant_step(0.0, x, held, plant.constants, k.dt_s, plant.substeps, True)
        return np.concatenate([x_new, st[CTRL_IDX]])

    return step


def fd_jacobian(f, z0: FloatArray, h: float = 1e-6) -> FloatArray:  # type: ignore[no-untyped-def]
    cols = []
    for i in range(z0.size):
        dz = h * max(1.0, abs(z0[i]))
        e = np.zeros(z0.size)
        e[i] = dz
        cols.append((f(z0 + e) - f(z0 - e)) / (2 * dz))
    return np.column_stack(cols)


def test_one_tick_map_layout() -> None:
    assert CTRL_IDX.size == 36  # I1..I4 and the four pseudo-differentiators
    assert N_STATE + CTRL_IDX.size == 48


def test_hover_equilibrium_is_the_plant_trim(hover_eq: HoverEquilibrium, airframe: Airframe) -> None:
    """The controller settles on the plant's true trim (integrators absorb the design-model
    gap): zero accelerations at the held pitches, and the same pitches fsolve finds."""
    c = airframe.constants()
    d = derivative(0.0, hover_eq.x, hover_eq.u, c)
    assert np.abs(d[VEL]).max() < 1e-10 and np.abs(d[OMEGA]).max() < 1e-10
    assert_allclose(hover_eq.x[0:3], hover_eq.ref[0:3], atol=1e-9)

    def resid(v: FloatArray) -> FloatArray:
        x = hover_eq.x.copy()
        x[PHI], x[THETA] = v[4], v[5]
        dd = derivative(0.0, x, np.asarray(v[:4]), c)
        return np.concatenate([dd[VEL], dd[OMEGA]])

    guess = np.array([0.1, 0.15, 0.0, 0.0, 0.0, 0.0])
    trim = fsolve(resid, guess, xtol=1e-13)
    assert_allclose(hover_eq.u, trim[:4], atol=1e-8)
    assert_allclose(hover_eq.x[[PHI, THETA]], trim[4:], atol=1e-8)


def _eigs_at(k: TLCConstants, st: FloatArray, plant: Plant, x: FloatArray, ref: FloatArray) -> FloatArray:
    f = one_tick_map(k, st, plant, ref)
    z0 = np.concatenate([x, st[CTRL_IDX]])
    return np.asarray(np.linalg.eigvals(fd_jacobian(f, z0)))


def test_hover_one_tick_map_is_stable(hover_eq: HoverEquilibrium) -> None:
    k, st = hover_eq.ctrl.constants, hover_eq.ctrl.state
    f = one_tick_map(k, st, hover_eq.plant, hover_eq.ref)
    z0 = np.concatenate([hover_eq.x, st[CTRL_IDX]])
    assert np.abs(f(z0) - z0).max() < 1e-12  # really an equilibrium
    ev = _eigs_at(k, st, hover_eq.plant, hover_eq.x, hover_eq.ref)
    mod = np.abs(ev)
    print(f"hover one-tick map: max |eigenvalue| = {mod.max():.8f}")
    assert mod.max() < 1.0
    # the slowest modes are loop 1's designed error dynamics, s = w(-z +- j sqrt(1 - z^2))
    g = Gains.load().loop1_position_kinematics
    w, z = g.omega_rad_s[0], g.zeta[0]
    s_slow = np.log(ev[np.argsort(-mod)[:6]].astype(complex)) / k.dt_s
    assert_allclose(s_slow.real, -z * w, rtol=0.02)
    assert_allclose(np.abs(s_slow.imag), w * math.sqrt(1 - z * z), rtol=0.02)
    # sanity: the same map with loop 1's regulator sign flipped is unstable
    w2, zw2 = k.w2.copy(), k.zw2.copy()
    w2[0] *= -1.0
    zw2[0] *= -1.0
    stf = st.copy()
    stf[0:3] *= -1.0
    ev_f = _eigs_at(k._replace(w2=w2, zw2=zw2), stf, hover_eq.plant, hover_eq.x, hover_eq.ref)
    assert np.abs(ev_f).max() > 1.0


@pytest.mark.parametrize("vel", [(0.0, 0.0, 1.0), (1.0, 0.0, 1.0)], ids=["climb", "climb-fwd"])
def test_climb_one_tick_map_is_stable(
    airframe: Airframe, gains: Gains, vel: tuple[float, float, float]
) -> None:
    """Spec loop 2: the earth-frame differentiation of Vc keeps a 1 m/s climb stable (the
    paper's body-frame form is unstable above about 0.67 m/s)."""
    ctrl = TLController(airframe, gains, RATE_HZ, "pseudo")
    x0 = np.zeros(N_STATE)
    x0[Z_U] = 50.0
    plant = Plant(airframe, x0)
    line = StraightLine(start_nwu_m=(0.0, 0.0, 50.0), vel_nwu_m_s=vel, duration_s=400.0)
    n = round(400.0 * RATE_HZ)
    refs = line.sample(np.arange(n + 2) / RATE_HZ)
    f = fly(ctrl.constants, ctrl.state, plant, x0, refs[: n + 1])
    assert np.linalg.norm(f.x_next[0:3] - refs[n + 1, 0:3]) < 1e-6  # settled on the line
    ev = _eigs_at(ctrl.constants, ctrl.state, plant, f.x_next, refs[n + 1])
    print(f"climb {vel} one-tick map: max |eigenvalue| = {np.abs(ev).max():.8f}")
    assert np.abs(ev).max() < 1.0


# --- a climb in simulation -----------------------------------------------------------------------


@pytest.mark.parametrize("ff", ["pseudo", "exact"])
def test_climb_1m_s(paper: Scenario, ff: str) -> None:
    """A 1 m/s vertical climb from rest on the line: the start transient (about 0.5 m) dies
    out and the error keeps shrinking to 60 s."""
    sc = dataclasses.replace(
        paper,
        trajectory=StraightLine(start_nwu_m=(0.0, 0.0, 10.0), vel_nwu_m_s=(0.0, 0.0, 1.0), duration_s=60.0),
        initial=dataclasses.replace(paper.initial, pos_nwu_m=(0.0, 0.0, 10.0), euler_rad=(0.0, 0.0, 0.0)),
        run=dataclasses.replace(paper.run, duration_s=60.0, feedforward=ff),
    )
    rec = simulate(sc)
    e = rec.pos_err_m
    late = e[rec.window(50, 60)].max()
    print(f"climb 1 m/s ({ff}): max {e.max():.3f} m, [50, 60] {late:.2e} m, 60 s {e[-1]:.2e} m")
    assert np.all(np.isfinite(rec.x))
    assert e.max() < 1.0
    assert e[rec.window(50, 60)].max() < 0.01
    assert e[rec.window(50, 60)].max() < 0.5 * e[rec.window(30, 40)].max()
    assert rec.x[-1, Z_U] == pytest.approx(70.0, abs=0.01)
    assert int(np.count_nonzero(rec.saturated)) == 0
