"""The air on the X-Cell (heli_plant.world.air) against theory.

Fuselage drag of equivalent flat plates and uniform-inflow momentum/blade-element rotor
thrust in a relative wind (Gavrilets, Mettler & Feron 2001; Padfield, Helicopter Flight
Dynamics, ch. 3). Numbers are the X-Cell 60's (configs/xcell60.toml).
"""

from __future__ import annotations

import decimal
import math
from decimal import Decimal as Dec

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.rotor import pitch_from_thrust_coeff, thrust_coeff, torque_coeff
from heli_plant.dynamics import rotor_loads
from heli_plant.world import air
from heli_plant.world.air import (
    fuselage_force_flu,
    hover_inflow,
    hub_velocity_flu,
    main_rotor_loads_in_air,
    rotor_inflow,
    rotor_loads_in_air,
    rotor_torque_coeff,
    tail_rotor_loads_in_air,
    vortex_ring_flag,
)

AF = Airframe.load()
C = AF.constants()
RHO = AF.air.density_kg_m3
TIP_M = AF.main_rotor.speed_rad_s * AF.main_rotor.radius_m  # 129.4 m/s
TIP_T = AF.tail_rotor.speed_rad_s * AF.tail_rotor.radius_m  # 101.2 m/s
S_X, S_Y, S_Z = 0.10, 0.22, 0.15  # X-Cell flat-plate areas incl. C_D, Gavrilets et al. 2001 [m^2]
ROTORS = {"main": (C.a_m, C.s_m, TIP_M), "tail": (C.a_t, C.s_t, TIP_T)}
which = st.sampled_from(sorted(ROTORS))

THETA_HOVER = pitch_from_thrust_coeff(C.mass_kg * C.gravity_m_s2 / C.thrust_scale_m, C.a_m, C.s_m)


def main_thrust(u: float = 0.0, v: float = 0.0, w: float = 0.0, theta: float = THETA_HOVER) -> float:
    return main_rotor_loads_in_air(theta, u, v, w, C, TIP_M, 1.0, 0.0)[0]


# --- hover: the air-free rotor map of heli_common.vehicle.rotor, exactly --------------------------------


@pytest.mark.parametrize("rotor", sorted(ROTORS))
def test_hover_reproduces_the_rotor_map(rotor: str) -> None:
    """mu = mu_z = 0: C_T/s = tc(theta) (closed form, eq 16), lam = sqrt(C_T/2) = sqrt(s tc/2),
    C_Q/s = qc(tc) (eq 17), over both signs of pitch. Below |theta| ~ 1e-4 the closed form
    itself loses digits to cancellation, so the grid starts there."""
    a, s, tip = ROTORS[rotor]
    mags = np.concatenate([np.geomspace(1e-4, 1e-2, 50), np.linspace(1e-2, 0.6, 200)])
    for theta in np.concatenate([mags, -mags]):
        for guess in (0.0, 0.03, -0.2, 1.0):
            c_t, lam = rotor_inflow(theta, 0.0, 0.0, 0.0, a, s, tip, 1.0, guess)
            tc = thrust_coeff(theta, a, s)
            assert_allclose(c_t / s, tc, rtol=1e-12, atol=0)
            assert_allclose(lam, math.copysign(math.sqrt(s * abs(tc) / 2.0), theta), rtol=1e-12, atol=0)
            assert_allclose(lam, hover_inflow(c_t, 1.0), rtol=1e-12, atol=0)
            c_q = rotor_torque_coeff(c_t, lam, 0.0, s, C.delta)
            assert_allclose(c_q / s, torque_coeff(tc, s, C.delta), rtol=1e-12, atol=0)


def test_hover_inflow_with_wake_factor() -> None:
    for eta_w in (0.7, 0.9, 1.0, 1.3):
        c_t, lam = rotor_inflow(THETA_HOVER, 0.0, 0.0, 0.0, C.a_m, C.s_m, TIP_M, eta_w, 0.0)
        assert_allclose(lam, hover_inflow(c_t, eta_w), rtol=1e-13)
        assert_allclose(c_t, C.a_m * C.s_m / 2.0 * (THETA_HOVER / 3.0 - lam / 2.0), rtol=1e-13)


@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_zero_relative_air_is_todays_plant(theta_m: float, theta_t: float, gm: float, gt: float) -> None:
    """No wind, no motion: the plant's rotor_loads, whatever the starting inflow guesses."""
    tm, qm, tt, qt = rotor_loads(theta_m, theta_t, C)
    got = rotor_loads_in_air(theta_m, theta_t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, C, TIP_M, TIP_T, 1.0, gm, gt)
    assert_allclose(got[:4], [tm, qm, tt, qt], rtol=1e-12, atol=1e-12)


# --- the spec's computed numbers -------------------------------------------------------------


def test_hover_trim_and_induced_velocity() -> None:
    assert_allclose(THETA_HOVER, 0.0959, atol=5e-5)
    tm, _, lam, v_i = main_rotor_loads_in_air(THETA_HOVER, 0.0, 0.0, 0.0, C, TIP_M, 1.0, 0.0)
    assert_allclose(tm, C.mass_kg * C.gravity_m_s2, rtol=1e-12)
    assert_allclose(v_i, 4.17, atol=5e-3)  # v_h = sqrt(T/(2 rho A))
    assert_allclose(v_i, math.sqrt(tm / (2.0 * RHO * AF.main_rotor.disc_area_m2)), rtol=1e-12)
    assert_allclose(v_i, lam * TIP_M, rtol=1e-15)


def test_fuselage_numbers() -> None:
    v_h = main_rotor_loads_in_air(THETA_HOVER, 0.0, 0.0, 0.0, C, TIP_M, 1.0, 0.0)[3]
    fx, fy, fz = fuselage_force_flu(0.0, 0.0, 0.0, v_h, S_X, S_Y, S_Z, RHO)
    assert fx == 0.0 and fy == 0.0
    assert_allclose(-fz, 1.60, atol=5e-3)  # hover download, fuselage in one v_i of downwash
    assert_allclose(-fz / (C.mass_kg * C.gravity_m_s2), 0.020, atol=5e-4)
    assert_allclose(-fuselage_force_flu(0.0, 0.0, 0.0, 2.0 * v_h, S_X, S_Y, S_Z, RHO)[2], 6.4, atol=0.05)
    # the simple form (v_i = 0) in translation
    assert_allclose(-fuselage_force_flu(5.0, 0.0, 0.0, 0.0, S_X, S_Y, S_Z, RHO)[0], 1.53, atol=5e-3)
    assert_allclose(-fuselage_force_flu(10.0, 0.0, 0.0, 0.0, S_X, S_Y, S_Z, RHO)[0], 6.12, atol=5e-3)
    assert_allclose(-fuselage_force_flu(0.0, 5.0, 0.0, 0.0, S_X, S_Y, S_Z, RHO)[1], 3.37, atol=5e-3)


@pytest.mark.parametrize(
    ("u", "w", "ratio"),
    [
        (0.0, 0.5, 0.959),  # climb
        (0.0, 1.0, 0.915),
        (0.0, -0.5, 1.039),  # descent
        (2.0, 0.0, 1.038),  # edgewise: translational lift
        (5.0, 0.0, 1.189),
        (10.0, 0.0, 1.441),
    ],
)
def test_thrust_ratio_at_hover_collective(u: float, w: float, ratio: float) -> None:
    t0 = main_thrust()
    assert_allclose(main_thrust(u=u, w=w) / t0, ratio, atol=5e-4)
    # edgewise flow from any in-plane direction is the same
    assert_allclose(main_thrust(u=u / math.sqrt(2), v=-u / math.sqrt(2), w=w) / t0, ratio, atol=5e-4)


def test_heave_damping() -> None:
    """dT/dw_a = -6.50 N/(m/s) by central difference and by the closed form
    dC_T/dmu_z = -2 a s lam/(16 lam + a s) (hover, eta_w = 1); Z_w = -0.79 1/s."""
    h = 1e-4
    fd = (main_thrust(w=h) - main_thrust(w=-h)) / (2.0 * h)
    lam = main_rotor_loads_in_air(THETA_HOVER, 0.0, 0.0, 0.0, C, TIP_M, 1.0, 0.0)[2]
    a, s = C.a_m, C.s_m
    closed = -2.0 * a * s * lam / (16.0 * lam + a * s) / s * C.thrust_scale_m / TIP_M
    assert_allclose(fd, closed, rtol=1e-7)
    assert_allclose(fd, -6.50, atol=5e-3)
    assert_allclose(fd / C.mass_kg, -0.79, atol=5e-3)


def test_tail_yaw_damping() -> None:
    """Tail trimmed against the hover torque (Tt = Qm/lt); yaw rate r moves the tail hub along
    its thrust (w_t = r lt), so N_r = lt dTt/dr / Izz = lt^2 dTt/dw_t / Izz = -1.0 1/s."""
    qm = main_rotor_loads_in_air(THETA_HOVER, 0.0, 0.0, 0.0, C, TIP_M, 1.0, 0.0)[1]
    theta_t = pitch_from_thrust_coeff(qm / C.lt / C.thrust_scale_t, C.a_t, C.s_t)
    h = 1e-4

    def yaw_moment(r: float) -> float:
        z = 0.0
        loads = rotor_loads_in_air(THETA_HOVER, theta_t, z, z, z, z, z, r, C, TIP_M, TIP_T, 1.0, z, z)
        return loads[2] * C.lt

    n_r = (yaw_moment(h) - yaw_moment(-h)) / (2.0 * h) / C.izz
    assert_allclose(n_r, -1.0, atol=0.01)


# --- structure: frames, signs, symmetry, continuity --------------------------------------------

vel = st.floats(-30.0, 30.0)


@given(vel, vel, vel, vel, vel, vel, vel, st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2))
def test_hub_velocity_is_va_plus_omega_cross_r(
    u: float, v: float, w: float, p: float, q: float, r: float, rx: float, ry: float, rz: float, _: float
) -> None:
    want = np.array([u, v, w]) + np.cross([p, q, r], [rx, ry, rz])
    assert_allclose(hub_velocity_flu(u, v, w, p, q, r, rx, ry, rz), want, rtol=1e-12, atol=1e-12)


@given(vel, vel, vel, vel, vel, vel, st.floats(-0.3, 0.3))
def test_tail_axial_and_in_plane_velocity(
    u: float, v: float, w: float, p: float, q: float, r: float, th: float
) -> None:
    """Tail hub at (-lt, 0, ht): axial (along -y) w_t = -v_a + r lt + p ht, in-plane
    (u_a + q ht, w_a + q lt); the tail rotor is the generic rotor on those velocities."""
    ut, vt, wt = hub_velocity_flu(u, v, w, p, q, r, -C.lt, 0.0, C.ht)
    assert_allclose([ut, -vt, wt], [u + q * C.ht, -v + r * C.lt + p * C.ht, w + q * C.lt], atol=1e-12)
    tt, qt, lam, v_i = tail_rotor_loads_in_air(th, ut, vt, wt, C, TIP_T, 1.0, 0.0)
    c_t, lam2 = rotor_inflow(th, ut, wt, -vt, C.a_t, C.s_t, TIP_T, 1.0, 0.0)
    assert tt == c_t / C.s_t * C.thrust_scale_t and lam == lam2 and v_i == lam * TIP_T
    assert qt == rotor_torque_coeff(c_t, lam, -vt / TIP_T, C.s_t, C.delta) / C.s_t * C.torque_scale_t
    got = rotor_loads_in_air(0.1, th, u, v, w, p, q, r, C, TIP_M, TIP_T, 1.0, 0.0, 0.0)
    assert got[2] == tt and got[3] == qt and got[5] == lam


@given(vel, vel, vel, st.floats(0.0, 10.0))
def test_drag_opposes_relative_air(u: float, v: float, w: float, v_i: float) -> None:
    f = np.array(fuselage_force_flu(u, v, w, v_i, S_X, S_Y, S_Z, RHO))
    rel = np.array([u, v, w + v_i])
    assert f @ rel <= 0.0
    assert np.all(f * rel <= 0.0)  # each plate's force opposes its own component
    assert_allclose(
        np.array(fuselage_force_flu(2 * u, 2 * v, 2 * w, 2 * v_i, S_X, S_Y, S_Z, RHO)), 4 * f, atol=1e-12
    )
    speed = float(np.linalg.norm(rel))
    assert_allclose(f, -0.5 * RHO * speed * np.array([S_X, S_Y, S_Z]) * rel, rtol=1e-12, atol=1e-12)


@given(st.floats(-0.6, 0.6), vel, vel, vel, st.floats(-0.2, 0.2), which)
def test_odd_in_thrust(theta: float, u: float, v: float, w: float, guess: float, rotor: str) -> None:
    a, s, tip = ROTORS[rotor]
    c_t, lam = rotor_inflow(theta, u, v, w, a, s, tip, 1.0, guess)
    c_t2, lam2 = rotor_inflow(-theta, u, v, -w, a, s, tip, 1.0, -guess)
    assert c_t2 == -c_t and lam2 == -lam
    c_q = rotor_torque_coeff(c_t, lam, w / tip, s, C.delta)
    assert rotor_torque_coeff(c_t2, lam2, -w / tip, s, C.delta) == c_q  # even


@given(
    st.floats(-1.0, 1.0),
    st.floats(-300.0, 300.0),
    st.floats(-300.0, 300.0),
    st.floats(-300.0, 300.0),
    st.one_of(st.floats(-1.0, 1.0), st.just(math.nan), st.just(math.inf)),
    st.floats(0.5, 1.5),
    which,
)
def test_solution_satisfies_both_equations(
    theta: float, u: float, v: float, w: float, guess: float, eta_w: float, rotor: str
) -> None:
    """Any finite state and any guess (also vortex-ring and windmill descent): finite, and both
    the blade-element and the momentum equation hold to 1e-12."""
    a, s, tip = ROTORS[rotor]
    c_t, lam = rotor_inflow(theta, u, v, w, a, s, tip, eta_w, guess)
    assert math.isfinite(c_t) and math.isfinite(lam)
    mu, mu_z = math.hypot(u, v) / tip, w / tip
    k = a * s / 2.0 * theta * (1.0 / 3.0 + mu * mu / 2.0)
    scale = abs(k) + a * s / 4.0 * (abs(mu_z) + abs(lam)) + 1e-300
    assert abs(c_t - (k - a * s / 4.0 * (mu_z + lam))) <= 1e-12 * scale
    assert abs(2.0 * eta_w * lam * math.hypot(mu, lam + mu_z) - c_t) <= 1e-12 * scale
    assert c_t * lam >= 0.0  # induced flow along the thrust


@given(st.floats(-0.6, 0.6), st.floats(0.0, 30.0), st.floats(-2.0, 30.0), st.floats(-1.0, 1.0))
def test_guess_does_not_matter_outside_descent(theta: float, u: float, w: float, guess: float) -> None:
    """Climb, hover, forward flight, slow descent: a single root, found from any start."""
    ref = rotor_inflow(theta, u, 0.0, w if theta >= 0 else -w, C.a_m, C.s_m, TIP_M, 1.0, 0.0)
    got = rotor_inflow(theta, u, 0.0, w if theta >= 0 else -w, C.a_m, C.s_m, TIP_M, 1.0, guess)
    assert_allclose(got, ref, rtol=1e-12, atol=1e-15)


def _exact_root(theta: float, mu: float, mu_z: float, a: float, s: float, eta_w: float, lam: float) -> float:
    """The root of the solver's own float-defined residual, by Newton in 50-digit decimals
    from ``lam``: what a solve could return with no rounding at all."""
    half = 0.5 * a * s
    k = half * (theta * (1.0 / 3.0 + 0.5 * mu * mu) - 0.5 * mu_z)
    sgn = 1.0 if k > 0.0 else -1.0
    with decimal.localcontext() as ctx:
        ctx.prec = 50
        kk, mz, two_eta, quarter = Dec(sgn * k), Dec(sgn * mu_z), Dec(2.0 * eta_w), Dec(0.5 * half)
        m, x = Dec(mu), Dec(sgn * lam)
        for _ in range(40):
            d = x + mz
            q = (m * m + d * d).sqrt()
            x -= (two_eta * x * q + quarter * x - kk) / (two_eta * (q + x * d / q) + quarter)
        return sgn * float(x)


def test_last_newton_step_taken_early_loses_no_accuracy(monkeypatch: pytest.MonkeyPatch) -> None:
    """The solver stops after a Newton step whose quadratic remainder is under a quarter of an
    ulp (no confirming iteration): its roots are as close to the exact root of the residual
    as those of the solve that iterates until the step itself is 1e-13 of lam (measured: both
    within 2-3 ulp, 0.36-0.40 ulp on average, over 2000 forward-flight, climb and descent
    cases from guesses 1e-3 off, as the plant's stages start). A remainder bound 100 times
    looser leaves errors of up to 19 ulp, 1e4 times looser 1500 ulp (checked)."""
    rng = np.random.default_rng(7)
    a, s = C.a_m, C.s_m
    plain = getattr(air._solve_inflow, "py_func", air._solve_inflow)  # Python, as NUMBA_DISABLE_JIT
    early, full = [], []
    for _ in range(2000):
        theta, mu = rng.uniform(-0.05, 0.25), abs(rng.normal(0.0, 0.1))
        mu_z, eta_w = rng.normal(0.0, 0.03), rng.uniform(0.8, 1.2)
        start = air._solve_inflow(theta, mu, mu_z, a, s, eta_w, 0.0)[1]
        guess = start * (1.0 + rng.normal(0.0, 1e-3))
        lam = air._solve_inflow(theta, mu, mu_z, a, s, eta_w, guess)[1]
        with monkeypatch.context() as m:
            m.setattr(air, "_QUAD_TOL", 0.0)  # the plain Python function reads it at each call
            lam_full = plain(theta, mu, mu_z, a, s, eta_w, guess)[1]
        exact = _exact_root(theta, mu, mu_z, a, s, eta_w, lam_full)
        ulp = float(np.spacing(abs(exact)))
        early.append(abs(lam - exact) / ulp)
        full.append(abs(lam_full - exact) / ulp)
    assert max(early) <= 4.0 and max(full) <= 4.0
    assert np.mean(early) <= np.mean(full) + 0.1


@pytest.mark.parametrize("u", [0.0, 3.0, 10.0])
def test_thrust_continuous_through_zero_climb(u: float) -> None:
    """T(w) at fixed collective through w = 0 (mu_z = 0), with a Lipschitz bound: |dC_T/dmu_z|
    <= a s/4 away from the vortex ring."""
    ws = np.linspace(-1.0, 1.0, 4001)
    t = np.array([main_thrust(u=u, w=w) for w in ws])
    bound = C.a_m * C.s_m / 4.0 / C.s_m * C.thrust_scale_m / TIP_M  # N per m/s
    assert np.max(np.abs(np.diff(t))) <= bound * (ws[1] - ws[0])
    assert np.all(np.diff(t) < 0)  # climb unloads the rotor, descent loads it
    assert abs(main_thrust(u=u, w=1e-12) - main_thrust(u=u, w=-1e-12)) <= bound * 3e-12


@pytest.mark.parametrize(("u", "w"), [(0.0, 0.0), (0.0, 0.5), (0.0, -0.5), (5.0, 0.0), (5.0, 1.0)])
def test_thrust_continuous_through_zero_pitch(u: float, w: float) -> None:
    """T(theta) through theta = 0 and through zero thrust (where the sign reflection acts),
    with |dC_T/dtheta| below its blade-element bound (1.5 x for the windmill side)."""
    ths = np.linspace(-0.03, 0.03, 6001)
    t = np.array([main_thrust(u=u, w=w, theta=th) for th in ths])
    mu = u / TIP_M
    bound = 1.5 * C.a_m * C.s_m / 2.0 * (1.0 / 3.0 + mu * mu / 2.0) / C.s_m * C.thrust_scale_m
    assert np.max(np.abs(np.diff(t))) <= bound * (ths[1] - ths[0])
    assert abs(main_thrust(u=u, w=w, theta=1e-15) - main_thrust(u=u, w=w, theta=-1e-15)) <= bound * 3e-15
    if u > 0.0 or w == 0.0:  # no axial flow through an unloaded disc: monotone
        assert np.all(np.diff(t) > 0)


@pytest.mark.parametrize("rotor", sorted(ROTORS))
@pytest.mark.parametrize("frac", [-3.0, -1.5, -0.9, -0.3, 0.3, 0.9, 1.5, 3.0])
def test_zero_pitch_in_axial_flow(rotor: str, frac: float) -> None:
    """Closed-form roots of the two equations at theta = 0, mu = 0 (here mu_z = frac a s/8):
    for |mu_z| < a s/8 the inflow cancels the axial flow, lam = -mu_z, and C_T = 0 (the disc
    is unloaded, momentum theory's degenerate root); beyond, the windmill-brake root
    lam = -sign(mu_z) a s/8 with C_T = -(a s/4)(mu_z + lam) (main: |w| > 4.24 m/s).
    So near zero thrust in axial flow T(theta) is continuous but not monotone (a dip of
    ~0.3 N for the main rotor at 0.5 m/s)."""
    a, s, tip = ROTORS[rotor]
    mu_z = frac * a * s / 8.0
    c_t, lam = rotor_inflow(0.0, 0.0, 0.0, mu_z * tip, a, s, tip, 1.0, 0.0)
    if abs(frac) < 1.0:
        assert_allclose(lam, -mu_z, rtol=1e-12)
        assert abs(c_t) <= 1e-12 * a * s * abs(mu_z)
    else:
        lam_w = -math.copysign(a * s / 8.0, mu_z)
        assert_allclose(lam, lam_w, rtol=1e-12)
        assert_allclose(c_t, -a * s / 4.0 * (mu_z + lam_w), rtol=1e-12)


def test_vortex_ring_flag() -> None:
    lam_h = hover_inflow(C.mass_kg * C.gravity_m_s2 / C.thrust_scale_m * C.s_m, 1.0)
    assert_allclose(lam_h * TIP_M, 4.17, atol=5e-3)
    assert not vortex_ring_flag(0.0, 0.0, lam_h)
    assert not vortex_ring_flag(0.0, -0.2 * lam_h, lam_h)
    assert vortex_ring_flag(0.0, -0.3 * lam_h, lam_h)
    assert vortex_ring_flag(0.049, -2.0 * lam_h, lam_h)
    assert not vortex_ring_flag(0.051, -2.0 * lam_h, lam_h)  # enough forward speed: wake blown clear
    assert not vortex_ring_flag(0.0, 1.0, lam_h)  # climb
    assert vortex_ring_flag(0.0, 0.3 * lam_h, -lam_h)  # negative thrust: mirrored
    assert not vortex_ring_flag(0.0, -0.3 * lam_h, -lam_h)


def test_absurd_finite_inputs_stay_finite() -> None:
    for big in (1e6, 1e30, 1e300):
        for sgn in (1.0, -1.0):
            out = main_rotor_loads_in_air(0.1 * sgn, big, -big, sgn * big, C, TIP_M, 1.0, big)
            assert all(math.isfinite(x) for x in out)
            out = main_rotor_loads_in_air(big * sgn, 0.0, 0.0, -sgn * big, C, TIP_M, 1.0, -big)
            assert all(math.isfinite(x) for x in out)
