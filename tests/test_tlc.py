"""The TLC pieces (autopilot.tlc): linearising matrices, allocation, force inversion, the
pseudo-differentiator, loop signs around a hover equilibrium, bad input and saturation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import HoverEquilibrium, fly, hover_refs
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from autopilot.reference import N_REF
from autopilot.tlc.allocation import main_rotor_torque, solve_cyclic_tail
from autopilot.tlc.controller import (
    BAD_INPUT,
    BAD_OUTPUT,
    D_PSI_C,
    D_SAT_MASK,
    D_STATUS,
    OK,
    S_I1,
    TLCConstants,
    TLController,
)
from autopilot.tlc.differentiator import diff_reset, diff_step, discretize
from autopilot.tlc.gains import Gains
from autopilot.tlc.inversion import force_to_thrust_attitude, limit_tilt, yaw_rate_command
from autopilot.tlc.loops import a3_matrix, a4_matrix, a4_times
from heli_common.kinematics import euler_rates
from heli_common.state import N_STATE, Z_U, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.rotor import pitch_from_thrust_coeff
from heli_plant.dynamics import rotor_loads
from heli_plant.model import Plant

_AF = Airframe.load()
_C = _AF.constants()
_C_LM = dataclasses.replace(
    _AF, body=dataclasses.replace(_AF.body, main_hub_ahead_cg_m=0.03, ixz_kg_m2=0.04)
).constants()
MG = _C.mass_kg * _C.gravity_m_s2

angle = st.floats(-1.2, 1.2)
rate = st.floats(-3.0, 3.0)


def inertia(c: PlantConstants) -> FloatArray:
    return np.array([[c.ixx, 0.0, -c.ixz], [0.0, c.iyy, 0.0], [-c.ixz, 0.0, c.izz]])


def central_jacobian(f, x0: FloatArray, h: float = 1e-6) -> FloatArray:  # type: ignore[no-untyped-def]
    cols = []
    for i in range(x0.size):
        e = np.zeros(x0.size)
        e[i] = h
        cols.append((np.asarray(f(x0 + e)) - np.asarray(f(x0 - e))) / (2 * h))
    return np.column_stack(cols)


# --- A3, A4 --------------------------------------------------------------------------------------


@given(angle, angle, st.floats(-math.pi, math.pi), rate, rate, rate)
def test_a3_is_jacobian_of_euler_rates(
    phi: float, theta: float, psi: float, p: float, q: float, r: float
) -> None:
    num = central_jacobian(lambda g: euler_rates(g[0], g[1], p, q, r), np.array([phi, theta, psi]))
    assert_allclose(
        a3_matrix(phi, theta, p, q, r),
        num,
        atol=1e-7 * (1 + abs(p) + abs(q) + abs(r)) / math.cos(theta) ** 3,
    )
    assert np.all(a3_matrix(phi, theta, p, q, r)[:, 2] == 0.0)


@pytest.mark.parametrize("c", [_C, _C_LM], ids=["ixz=0", "ixz=0.04"])
@given(w=st.tuples(rate, rate, rate))
def test_a4_is_jacobian_of_gyroscopic_term(c: PlantConstants, w: tuple[float, float, float]) -> None:
    j = inertia(c)
    j_inv = np.linalg.inv(j)

    def gyro(om: FloatArray) -> FloatArray:
        return -j_inv @ np.cross(om, j @ om)

    om = np.array(w)
    assert_allclose(a4_matrix(om, j, j_inv), central_jacobian(gyro, om), atol=1e-7)


@pytest.mark.parametrize("c", [_C, _C_LM], ids=["ixz=0", "ixz=0.04"])
@given(w=st.tuples(rate, rate, rate), v=st.tuples(rate, rate, rate))
def test_a4_times_is_the_matrix_product(c: PlantConstants, w: tuple[float, float, float],
                                        v: tuple[float, float, float]) -> None:  # fmt: skip
    """The kernel's matrix-free A4 v equals A4(omega) @ v (to rounding)."""
    j = inertia(c)
    j_inv = np.linalg.inv(j)
    om, vv = np.array(w), np.array(v)
    assert_allclose(a4_times(om, j, j_inv, vv), a4_matrix(om, j, j_inv) @ vv, rtol=1e-12, atol=1e-12)


def test_a4_nonzero_ixz_couples_roll_and_yaw() -> None:
    """With Ixz != 0 the closed form must still match; a diagonal-J formula would not."""
    j = inertia(_C_LM)
    j_diag = np.diag(np.diag(j))
    om = np.array([0.7, -1.1, 0.4])
    a4 = a4_matrix(om, j, np.linalg.inv(j))
    a4_wrong = a4_matrix(om, j_diag, np.linalg.inv(j_diag))
    assert np.abs(a4 - a4_wrong).max() > 1e-2


# --- allocation and force inversion (design model, spec section 3) -------------------------------


def design_torque(tm: float, qm: float, tt: float, eps: float, eta: float, c: PlantConstants) -> FloatArray:
    return np.array(
        [
            tm * c.hm * eta + tt * c.ht + qm * eps,
            tm * c.lm + tm * c.hm * eps - qm * eta,
            -tm * c.lm * eta + tt * c.lt - qm,
        ]
    )


@pytest.mark.parametrize("c", [_C, _C_LM], ids=["xcell", "lm=0.03"])
@given(
    qc=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-20, 20)),
    tm=st.floats(5.0, 300.0),
)
def test_allocation_reproduces_torque_command(
    c: PlantConstants, qc: tuple[float, float, float], tm: float
) -> None:
    qm = main_rotor_torque(tm, c)
    tt, eps, eta = solve_cyclic_tail(np.array(qc), tm, qm, c, 0.0)
    assert_allclose(design_torque(tm, qm, tt, eps, eta, c), qc, rtol=1e-9, atol=1e-9)


@given(st.floats(-50.0, 400.0))
def test_main_rotor_torque_matches_plant(tm: float) -> None:
    theta_m = pitch_from_thrust_coeff(tm / _C.thrust_scale_m, _C.a_m, _C.s_m)
    tm2, qm, _, _ = rotor_loads(theta_m, 0.0, _C)
    assert_allclose(tm2, tm, rtol=1e-12, atol=1e-12)
    assert_allclose(main_rotor_torque(tm, _C), qm, rtol=1e-12)


def test_allocation_at_hover_gives_spec_tail_thrust() -> None:
    """Qc = 0 at hover thrust needs Tt = Qm / lt (about 4.9 N) and small cyclic."""
    qm = main_rotor_torque(MG, _C)
    tt, eps, eta = solve_cyclic_tail(np.zeros(3), MG, qm, _C, 0.0)
    assert_allclose(tt, 4.85, atol=0.01)
    # the tail's rolling moment Tt ht is balanced by lateral cyclic (eta < 0), and the pitch
    # moment -Qm eta that this creates by longitudinal cyclic: Tm hm eps = Qm eta
    assert -0.03 < eta < 0
    assert_allclose(MG * _C.hm * eps, qm * eta, rtol=1e-12)


@given(st.floats(0.0, 0.99 * MG), st.floats(-math.pi, math.pi), st.floats(-200.0, 200.0))
def test_force_inversion_reproduces_force_command(h: float, ang: float, fz: float) -> None:
    fc = np.array([h * math.cos(ang), h * math.sin(ang), fz])
    tm, phi, theta = force_to_thrust_attitude(fc.copy(), MG)
    f_design = np.array(
        [
            MG * math.sin(theta),
            -MG * math.cos(theta) * math.sin(phi),
            -MG * math.cos(theta) * math.cos(phi) + tm,
        ]
    )
    assert_allclose(f_design, fc, atol=1e-9 * MG)
    assert abs(phi) < math.pi / 2 and abs(theta) < math.pi / 2
    # signs of section 5: theta > 0 (nose down) for a forward force, phi > 0 for a -y force
    if fc[0] > 1.0:
        assert theta > 0
    if fc[1] < -1.0:
        assert phi > 0


@given(st.floats(-500.0, 500.0), st.floats(-500.0, 500.0), st.floats(-100.0, 100.0))
def test_limit_tilt(fx: float, fy: float, fz: float) -> None:
    tilt = 0.35
    f = np.array([fx, fy, fz])
    g = f.copy()
    limited = limit_tilt(g, MG, tilt)
    hmax = MG * math.sin(tilt)
    assert limited == (math.hypot(fx, fy) > hmax)
    assert math.hypot(g[0], g[1]) <= hmax * (1 + 1e-12)
    assert g[2] == fz
    if limited:
        assert abs(g[0] * f[1] - g[1] * f[0]) <= 1e-9 * (fx * fx + fy * fy)
        assert float(g[:2] @ f[:2]) > 0
    else:
        assert_allclose(g, f, rtol=0, atol=0)


def test_yaw_rate_command_on_the_paper_circle() -> None:
    """(27): dpsi/dt of the tangent heading atan2(y', x'), against a finite difference."""
    r, w = 10.0, 2 * math.pi / 80.0

    def vel(t: float) -> tuple[float, float]:
        return r * w * math.cos(w * t), -r * w * math.sin(w * t)

    def acc(t: float) -> tuple[float, float]:
        return -r * w * w * math.sin(w * t), -r * w * w * math.cos(w * t)

    for t in (0.0, 13.0, 37.5, 61.0):
        h = 1e-4
        (vx1, vy1), (vx0, vy0) = vel(t + h), vel(t - h)
        num = (math.atan2(vy1, vx1) - math.atan2(vy0, vx0)) / (2 * h)
        got = yaw_rate_command(*vel(t), *acc(t), 0.05)
        assert_allclose(got, num, rtol=1e-6)
        assert_allclose(got, -w, rtol=1e-12)
    assert yaw_rate_command(0.01, 0.02, 5.0, 5.0, 0.05) == 0.0  # held below the hold speed


# --- pseudo-differentiator -----------------------------------------------------------------------


def test_differentiator_is_exact_zoh_of_the_continuous_filter() -> None:
    """A unit step (exactly held by ZOH) gives the continuous step response at every sample."""
    wd, zd, dt = 5.0, 0.707, 0.01
    k = discretize(wd, zd, dt)
    st_ = np.zeros(6)
    diff_reset(st_, 0, np.zeros(3))
    u = np.array([1.0, 2.0, -3.0])
    d1, d2 = np.empty(3), np.empty(3)
    wdd = wd * math.sqrt(1 - zd * zd)
    for n in range(1, 300):
        diff_step(st_, 0, u, k, d1, d2)
        t = n * dt
        env = math.exp(-zd * wd * t)
        x1 = 1 - env * (math.cos(wdd * t) + zd / math.sqrt(1 - zd * zd) * math.sin(wdd * t))
        x2 = wd / math.sqrt(1 - zd * zd) * env * math.sin(wdd * t)
        assert_allclose(st_[0:3], u * x1, atol=1e-12)
        assert_allclose(st_[3:6], u * x2, atol=1e-12)


def _ramp_outputs(rate_hz: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    dt = 1.0 / rate_hz
    k = discretize(5.0, 0.707, dt)
    st_ = np.zeros(6)
    diff_reset(st_, 0, np.zeros(3))
    slope = np.array([0.5, -2.0, 1.0])
    d1, d2 = np.empty(3), np.empty(3)
    for n in range(round(10.0 * rate_hz)):
        diff_step(st_, 0, slope * n * dt, k, d1, d2)
    return slope, d1, d2


def test_differentiator_tracks_a_ramp() -> None:
    slope, d1, _ = _ramp_outputs(100.0)
    # the held (staircase) input costs (wd dt)^2 / 12 of the slope: 2e-4 at 100 Hz
    assert_allclose(d1, slope, rtol=3e-4)




@pytest.mark.parametrize("rate_hz", [50.0, 100.0])
def test_differentiator_second_derivative_of_a_ramp_is_zero(rate_hz: float) -> None:
    slope, _, d2 = _ramp_outputs(rate_hz)
    assert_allclose(d2, 0.0, atol=0.01 * np.abs(slope).max())


def test_pseudo_differentiated_circle_gives_the_yaw_rate() -> None:
    """Pseudo mode: x', y', x'', y'' all from the differentiator should give dpsi/dt = -w on
    the paper circle (the filter's lag is common to both and cancels in the ratio)."""
    r, w, dt = 10.0, 2 * math.pi / 80.0, 0.01
    k = discretize(5.0, 0.707, dt)
    st_ = np.zeros(6)
    d1, d2 = np.empty(3), np.empty(3)
    pos = lambda t: np.array([r * math.sin(w * t), r * (math.cos(w * t) - 1.0), 0.0])  # noqa: E731
    diff_reset(st_, 0, pos(0.0))
    rates = []
    for n in range(6000):
        diff_step(st_, 0, pos(n * dt), k, d1, d2)
        if n * dt > 20.0:
            rates.append(yaw_rate_command(d1[0], d1[1], d2[0], d2[1], 0.05))
    assert_allclose(rates, -w, rtol=2e-3)


# --- loop signs around the hover equilibrium -----------------------------------------------------

LOOP_CASES = [
    # (label, state index, offset, loop whose regulator holds it, seconds, error slice)
    ("x", 0, 0.5, 0, 30.0, slice(0, 3)),
    ("y", 1, 0.5, 0, 30.0, slice(0, 3)),
    ("z", 2, 0.5, 0, 30.0, slice(0, 3)),
    ("u", 3, 0.5, 1, 15.0, slice(3, 6)),
    ("v", 4, 0.5, 1, 15.0, slice(3, 6)),
    ("w", 5, 0.5, 1, 15.0, slice(3, 6)),
    ("roll", 6, 0.1, 2, 3.0, slice(6, 9)),
    ("pitch", 7, 0.1, 2, 3.0, slice(6, 9)),
    ("yaw", 8, 0.2, 2, 3.0, slice(6, 9)),
    ("p", 9, 0.5, 3, 1.0, slice(9, 12)),
    ("q", 10, 0.5, 3, 1.0, slice(9, 12)),
    ("r", 11, 0.5, 3, 1.0, slice(9, 12)),
]


def flipped(k: TLCConstants, st_: FloatArray, loop: int) -> tuple[TLCConstants, FloatArray]:
    """The same controller with loop ``loop``'s regulator sign flipped (u_ctrl = +K x_aug).
    The loop's integral is negated too, so the equilibrium stays an equilibrium."""
    w2, zw2, s = k.w2.copy(), k.zw2.copy(), st_.copy()
    w2[loop] *= -1.0
    zw2[loop] *= -1.0
    s[S_I1 + 3 * loop : S_I1 + 3 * loop + 3] *= -1.0
    return k._replace(w2=w2, zw2=zw2), s


def _error(eq: HoverEquilibrium, k: TLCConstants, st_: FloatArray, idx: int, d: float,
           secs: float, sl: slice) -> FloatArray:  # fmt: skip
    x0 = eq.x.copy()
    x0[idx] += d
    f = fly(k, st_, eq.plant, x0, hover_refs(eq.ref[0:3], secs))
    with np.errstate(invalid="ignore"):
        e = np.linalg.norm(f.x[:, sl] - eq.x[sl], axis=1)
    return np.where(np.isfinite(e), e, np.inf)


@pytest.mark.parametrize(
    ("label", "idx", "d", "loop", "secs", "sl"), LOOP_CASES, ids=[c[0] for c in LOOP_CASES]
)
def test_loop_sign_error_decays(
    hover_eq: HoverEquilibrium, label: str, idx: int, d: float, loop: int, secs: float, sl: slice
) -> None:
    k, st0 = hover_eq.ctrl.constants, hover_eq.ctrl.state
    e = _error(hover_eq, k, st0.copy(), idx, d, secs, sl)
    assert e[0] == pytest.approx(d)
    assert e[-1] < 0.05 * d, f"{label}: error {e[-1]:.3g} after {secs} s from {d}"
    # with the loop's regulator sign flipped the same offset is not corrected: it grows
    kf, sf = flipped(k, st0, loop)
    ef = _error(hover_eq, kf, sf, idx, d, secs, sl)
    assert ef.max() > 2.0 * d, f"{label}: flipped loop {loop + 1} still corrects ({ef.max():.3g})"


def test_flipped_loops_keep_the_equilibrium(hover_eq: HoverEquilibrium) -> None:
    """The sign-flip construction itself does not disturb the equilibrium (so the growth above
    is the loop's instability, not a kick)."""
    for loop in range(4):
        kf, sf = flipped(hover_eq.ctrl.constants, hover_eq.ctrl.state, loop)
        tick = TLController(_AF, Gains.load())
        tick.constants, tick.state = kf, sf
        u = tick.update(0.0, hover_eq.x, hover_eq.ref)
        assert_allclose(u, hover_eq.u, atol=1e-9)


# --- bad input, saturation, yaw initialisation ---------------------------------------------------


def _hover_state(z: float = 20.0) -> FloatArray:
    x = np.zeros(N_STATE)
    x[Z_U] = z
    return x


def _ref(pos: tuple[float, float, float], vel: tuple[float, float, float] = (0, 0, 0)) -> FloatArray:
    r = np.zeros(N_REF)
    r[0:3], r[3:6] = pos, vel
    return r


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_state_returns_last_valid_command(gains: Gains, bad: float) -> None:
    ctrl = TLController(_AF, gains, 100.0)
    twin = TLController(_AF, gains, 100.0)
    ref = _ref((1.0, -1.0, 21.0))
    # before any valid tick: zero pitches, finite
    x_bad = _hover_state()
    x_bad[7] = bad
    u0 = ctrl.update(0.0, x_bad, ref)
    assert_allclose(u0, np.zeros(4), rtol=0, atol=0)
    assert ctrl.status == BAD_INPUT
    plant = Plant(_AF, _hover_state())
    last = None
    for i in range(50):
        last = ctrl.update(i * 0.01, plant.x, ref)
        assert_allclose(twin.update(i * 0.01, plant.x, ref), last, rtol=0, atol=0)
        plant.set_pitches(last)
        plant.step(0.01)
    state_before = ctrl.state.copy()
    for field in (1, 5, 8, 11):
        x = plant.x.copy()
        x[field] = bad
        u = ctrl.update(0.5, x, ref)
        assert np.all(np.isfinite(u))
        assert_allclose(u, last, rtol=0, atol=0)
        assert ctrl.status == BAD_INPUT
    ref_bad = ref.copy()
    ref_bad[2] = bad
    assert_allclose(ctrl.update(0.5, plant.x, ref_bad), last, rtol=0, atol=0)
    # the bad ticks left no trace: the next valid tick equals the twin's
    assert_allclose(ctrl.state, state_before, rtol=0, atol=0)
    assert_allclose(ctrl.update(0.5, plant.x, ref), twin.update(0.5, plant.x, ref), rtol=0, atol=0)
    assert ctrl.status == OK


def test_unknown_derivative_in_exact_mode_returns_last_valid(gains: Gains) -> None:
    ctrl = TLController(_AF, gains, 100.0, "exact")
    ref = _ref((0.0, 0.0, 20.0))
    good = ctrl.update(0.0, _hover_state(), ref)
    assert ctrl.status == OK
    ref_nan = ref.copy()
    ref_nan[3:9] = math.nan
    u = ctrl.update(0.01, _hover_state(), ref_nan)
    assert ctrl.status == BAD_OUTPUT
    assert_allclose(u, good, rtol=0, atol=0)


@pytest.mark.parametrize("far", [(0.0, 0.0, 1000.0), (1000.0, 0.0, 20.0), (-700.0, 700.0, 900.0)])
def test_saturation_and_anti_windup(gains: Gains, far: tuple[float, float, float]) -> None:
    """A reference far away saturates the outputs: they stay inside the servo limits, finite,
    and the integrators do not move on saturated ticks (conditional integration)."""
    ctrl = TLController(_AF, gains, 100.0)
    plant = Plant(_AF, _hover_state())
    lim = np.array(_AF.limits.as_tuple())
    ref = _ref(far)
    n_sat = 0
    for i in range(1000):
        ints_before = ctrl.state[0:12].copy()
        u = ctrl.update(i * 0.01, plant.x, ref)
        assert ctrl.status == OK
        assert np.all(np.isfinite(u))
        assert np.all(u >= lim[:, 0]) and np.all(u <= lim[:, 1]), u
        if ctrl.diag[D_SAT_MASK] != 0:
            n_sat += 1
            assert_allclose(ctrl.state[0:12], ints_before, rtol=0, atol=0)
        assert plant.set_pitches(u)
        plant.step(0.01)
        assert np.all(np.isfinite(plant.x))
    assert n_sat > 900  # the case really exercised saturation
    assert np.abs(ctrl.state[0:12]).max() < 1.0


def test_initial_yaw_command(gains: Gains) -> None:
    """psi_c(0) from the trajectory's initial tangent; held at the current yaw without one."""
    ctrl = TLController(_AF, gains, 100.0, "exact")
    ctrl.update(0.0, _hover_state(), _ref((0, 0, 20), (0.0, 2.0, 0.0)))
    assert_allclose(ctrl.diag[D_PSI_C], math.pi / 2)
    ctrl = TLController(_AF, gains, 100.0)
    x = _hover_state()
    x[8] = -2.5
    ctrl.update(0.0, x, _ref((0, 0, 20)))
    assert_allclose(ctrl.diag[D_PSI_C], -2.5)
    assert ctrl.diag[D_STATUS] == OK


@settings(max_examples=25)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0))
def test_yaw_error_is_wrapped(gains: Gains, psi: float, psi_c: float) -> None:
    """The yaw channel only sees the wrapped error: adding 2 pi to the measured yaw is a no-op."""
    a = TLController(_AF, gains, 100.0)
    b = TLController(_AF, gains, 100.0)
    x = _hover_state()
    x[8] = psi_c
    a.update(0.0, x, _ref((0, 0, 20)))  # psi_c := psi_c (held)
    b.update(0.0, x, _ref((0, 0, 20)))
    x[8] = psi
    xb = x.copy()
    xb[8] = psi + 2 * math.pi
    assert_allclose(a.update(0.01, x, _ref((0, 0, 20))), b.update(0.01, xb, _ref((0, 0, 20))), atol=1e-9)


def test_a_trial_update_gives_the_next_command_and_changes_nothing(gains: Gains) -> None:
    """What the in-process loop asks for its first command (the servos start there): the
    command the next update gives, bit for bit, with the controller's state untouched."""
    ctrl = TLController(_AF, gains, 100.0)
    plant = Plant(_AF, _hover_state())
    ref = _ref((1.0, -1.0, 21.0))
    for i in range(30):
        plant.set_pitches(ctrl.update(i * 0.01, plant.x, ref))
        plant.step(0.01)
    state, diag = ctrl.state.copy(), ctrl.diag.copy()
    trial = ctrl.trial_update(0.3, plant.x, ref)
    assert np.array_equal(ctrl.state, state) and np.array_equal(ctrl.diag, diag)
    assert np.array_equal(trial, ctrl.update(0.3, plant.x, ref))
    assert not np.array_equal(ctrl.state, state)  # the real update moved it
    with pytest.raises(ValueError, match="state must be"):
        ctrl.trial_update(0.0, np.zeros(3), ref)
