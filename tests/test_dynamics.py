"""The plant (heli_plant.dynamics, integrate, plant): invariants of the rigid body, finite-
difference checks of the kinematics, gravity, forces, RK4 order and a hover trim."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.optimize import fsolve
from scipy.spatial.transform import Rotation

from heli_common.state import EULER, N_STATE, OMEGA, POS, VEL, Z_U, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_plant.dynamics import derivative, forces_torques, rigid_body, rotor_loads
from heli_plant.model import Plant, plant_step

ZERO3 = np.zeros(3)


def with_ixz(airframe: Airframe, ixz: float) -> PlantConstants:
    return dataclasses.replace(airframe, body=dataclasses.replace(airframe.body, ixz_kg_m2=ixz)).constants()


def inertia(c: PlantConstants) -> FloatArray:
    return np.array([[c.ixx, 0.0, -c.ixz], [0.0, c.iyy, 0.0], [-c.ixz, 0.0, c.izz]])


def rt(x: FloatArray) -> FloatArray:
    """Body -> earth rotation from scipy (independent of heli_common.kinematics)."""
    return Rotation.from_euler("ZYX", [x[8], x[7], x[6]]).as_matrix()


def skew(w: FloatArray) -> FloatArray:
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def rk4(x: FloatArray, f: FloatArray, q: FloatArray, c: PlantConstants, h: float, n: int) -> FloatArray:
    """A local classical RK4 over rigid_body (forces and torques held)."""
    out = np.empty((n + 1, x.size))
    out[0] = x
    for i in range(n):
        y = out[i]
        k1 = rigid_body(y, f, q, c)
        k2 = rigid_body(y + 0.5 * h * k1, f, q, c)
        k3 = rigid_body(y + 0.5 * h * k2, f, q, c)
        k4 = rigid_body(y + h * k3, f, q, c)
        out[i + 1] = y + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def random_state(rng: np.random.Generator, rate_scale: float = 1.0) -> FloatArray:
    x = np.empty(N_STATE)
    x[POS] = rng.uniform(-10, 10, 3)
    x[VEL] = rng.uniform(-5, 5, 3)
    x[EULER] = [rng.uniform(-0.8, 0.8), rng.uniform(-0.6, 0.6), rng.uniform(-3, 3)]
    x[OMEGA] = rng.uniform(-1, 1, 3) * rate_scale
    return x


# --- the rigid body ------------------------------------------------------------------------------


@pytest.mark.parametrize("ixz", [0.0, 0.05, -0.12])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_torque_free_invariants(airframe: Airframe, ixz: float, seed: int) -> None:
    """F = Q = 0: kinetic energies, earth-frame angular momentum Rt J w and earth-frame
    velocity Rt V are conserved, so the position moves on a straight line."""
    c = with_ixz(airframe, ixz)
    x0 = random_state(np.random.default_rng(seed))
    h, n = 1e-3, 1500
    traj = rk4(x0, ZERO3, ZERO3, c, h, n)
    assert np.max(np.abs(traj[:, 7])) < 1.4  # stayed away from gimbal lock: the test is valid
    j = inertia(c)
    v, w = traj[:, VEL], traj[:, OMEGA]
    e_tr = 0.5 * c.mass_kg * np.einsum("ij,ij->i", v, v)
    e_rot = 0.5 * np.einsum("ij,jk,ik->i", w, j, w)
    h_earth = np.array([rt(xk) @ j @ xk[OMEGA] for xk in traj])
    v_earth = np.array([rt(xk) @ xk[VEL] for xk in traj])
    assert_allclose(e_tr, e_tr[0], rtol=1e-10)
    assert_allclose(e_rot, e_rot[0], rtol=1e-10)
    assert_allclose(h_earth, np.tile(h_earth[0], (n + 1, 1)), atol=1e-10)
    assert_allclose(v_earth, np.tile(v_earth[0], (n + 1, 1)), atol=1e-10)
    t = np.arange(n + 1) * h
    assert_allclose(traj[:, POS], x0[POS] + np.outer(t, v_earth[0]), atol=1e-9)
    # the motion is not trivial: the attitude really changed
    assert np.ptp(traj[:, EULER], axis=0).max() > 0.5


@given(st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.05, -0.12]))
@settings(max_examples=40)
def test_rigid_body_matches_newton_euler(seed: int, ixz: float) -> None:
    """rigid_body against an independent matrix implementation of section 2."""
    c = with_ixz(Airframe.load(), ixz)
    rng = np.random.default_rng(seed)
    x = random_state(rng, rate_scale=3.0)
    f, q = rng.uniform(-50, 50, 3), rng.uniform(-5, 5, 3)
    j = inertia(c)
    v, w = x[VEL], x[OMEGA]
    phi, theta = x[6], x[7]
    e = np.array(
        [
            [1, 0, -math.sin(theta)],
            [0, math.cos(phi), math.sin(phi) * math.cos(theta)],
            [0, -math.sin(phi), math.cos(phi) * math.cos(theta)],
        ]
    )
    want = np.concatenate(
        [
            rt(x) @ v,
            -np.cross(w, v) + f / c.mass_kg,
            np.linalg.solve(e, w),
            np.linalg.solve(j, -np.cross(w, j @ w) + q),
        ]
    )
    assert_allclose(rigid_body(x, f, q, c), want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("ixz", [0.0, 0.07])
@pytest.mark.parametrize("seed", range(4))
def test_finite_difference_kinematics(airframe: Airframe, ixz: float, seed: int) -> None:
    """Along the flow: dP/dt = Rt V (central difference of P), dRt/dt = Rt [w]x (so the Euler
    rates are right), d(Rt V)/dt = Rt F / m and d(Rt J w)/dt = Rt Q (earth-frame Newton-Euler)."""
    c = with_ixz(airframe, ixz)
    rng = np.random.default_rng(100 + seed)
    x = random_state(rng, rate_scale=2.0)
    f, q = rng.uniform(-50, 50, 3), rng.uniform(-5, 5, 3)
    j = inertia(c)
    h = 1e-4
    # a short exact-enough piece of trajectory on each side
    fwd = rk4(x, f, q, c, h / 10, 10)[-1]
    bwd = rk4(x, f, q, c, -h / 10, 10)[-1]
    dx = rigid_body(x, f, q, c)
    assert_allclose((fwd[POS] - bwd[POS]) / (2 * h), rt(x) @ x[VEL], rtol=1e-7, atol=1e-8)
    assert_allclose(dx[POS], rt(x) @ x[VEL], rtol=1e-13, atol=1e-13)
    # rotation: perturb the Euler angles along the computed rate
    r_dot = (rt(x + h * dx) - rt(x - h * dx)) / (2 * h)
    assert_allclose(r_dot, rt(x) @ skew(x[OMEGA]), atol=1e-6)
    # earth-frame momentum rates
    ve_dot = (rt(fwd) @ fwd[VEL] - rt(bwd) @ bwd[VEL]) / (2 * h)
    assert_allclose(ve_dot, rt(x) @ f / c.mass_kg, atol=1e-6)
    he_dot = (rt(fwd) @ j @ fwd[OMEGA] - rt(bwd) @ j @ bwd[OMEGA]) / (2 * h)
    assert_allclose(he_dot, rt(x) @ q, atol=1e-6)


# --- forces --------------------------------------------------------------------------------------


@given(
    st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.14, 0.14), st.floats(-0.14, 0.14),
    st.floats(-1.0, 1.0), st.floats(-1.0, 1.0),
)  # fmt: skip
def test_forces_structure(
    theta_m: float, theta_t: float, eps: float, eta: float, phi: float, theta: float
) -> None:
    """Section 2: F = gravity + main thrust of magnitude Tm along the tilted shaft - Tt y_b."""
    c = Airframe.load().constants()
    x = np.zeros(N_STATE)
    x[6], x[7], x[8] = phi, theta, 0.4
    u = np.array([theta_m, theta_t, eps, eta])
    f, q = forces_torques(x, u, c)
    tm, qm, tt, qt = rotor_loads(theta_m, theta_t, c)
    grav_body = rt(x).T @ np.array([0.0, 0.0, -c.mass_kg * c.gravity_m_s2])
    rotor_f = f - grav_body + np.array([0.0, tt, 0.0])
    assert_allclose(np.linalg.norm(rotor_f), abs(tm), rtol=1e-12, atol=1e-12)
    # the shaft leans forward with eps and to the right (-y) with eta; D normalises it
    if abs(tm) > 1.0:
        seps, ceps, seta, ceta = math.sin(eps), math.cos(eps), math.sin(eta), math.cos(eta)
        shaft = np.array([seps * ceta, -ceps * seta, ceps * ceta])
        assert_allclose(rotor_f / tm, shaft / np.linalg.norm(shaft), atol=1e-12)
    # torques, as printed in eq. 13
    seps, ceps, seta, ceta = math.sin(eps), math.cos(eps), math.sin(eta), math.cos(eta)
    want_q = [
        tm * c.hm * seta + tt * c.ht + qm * seps,
        tm * c.lm + tm * c.hm * seps + qt - qm * seta,
        -tm * c.lm * seta + tt * c.lt - qm * ceps * ceta,
    ]
    assert_allclose(q, want_q, rtol=1e-12, atol=1e-12)


@given(st.integers(0, 2**32 - 1))
@settings(max_examples=30)
def test_gravity_only_acceleration(seed: int) -> None:
    """Zero pitches: no thrust, so for any attitude and motion the earth-frame acceleration
    d(Rt V)/dt = Rt (dV/dt + w x V) is exactly (0, 0, -g)."""
    c = Airframe.load().constants()
    x = random_state(np.random.default_rng(seed), rate_scale=2.0)
    dx = derivative(0.0, x, np.zeros(4), c)
    acc_earth = rt(x) @ (dx[VEL] + np.cross(x[OMEGA], x[VEL]))
    assert_allclose(acc_earth, [0.0, 0.0, -c.gravity_m_s2], atol=1e-12)


def test_free_fall(airframe: Airframe) -> None:
    """Plant at zero pitch from a tumbling start: z(t) = z0 + vz0 t - g t^2 / 2 and uniform
    horizontal motion, although the rotor's drag torque spins the body up (several rad/s in
    its rates: 10 RK4 sub-steps per 10 ms keep the integration error well below the tolerance)."""
    x0 = np.zeros(N_STATE)
    x0[Z_U] = 500.0
    x0[VEL] = [1.0, -0.5, 2.0]
    x0[EULER] = [0.2, -0.1, 0.5]
    x0[OMEGA] = [0.3, -0.2, 0.4]
    plant = Plant(airframe, x0, substeps=10, ground_contact=False)
    assert plant.set_pitches(np.zeros(4))
    v_earth0 = rt(x0) @ x0[VEL]
    dt, n = 0.01, 200
    for _ in range(n):
        plant.step(dt)
    t = n * dt
    g = airframe.body.gravity_m_s2
    want = x0[POS] + v_earth0 * t + np.array([0.0, 0.0, -0.5 * g * t * t])
    assert_allclose(plant.x[POS], want, atol=1e-7)
    assert_allclose(rt(plant.x) @ plant.x[VEL], v_earth0 + np.array([0.0, 0.0, -g * t]), atol=1e-7)
    assert plant.x[11] - x0[11] < -1.0  # spun clockwise (from above) by the main rotor torque


# --- integrator and plant guards -----------------------------------------------------------------


def test_rk4_is_fourth_order(consts: PlantConstants) -> None:
    x = random_state(np.random.default_rng(7), rate_scale=2.0)
    u = np.array([0.12, 0.1, 0.05, -0.04])
    dt = 0.2
    exact = plant_step(0.0, x, u, consts, dt, 2048, False)[0]
    errs = [np.abs(plant_step(0.0, x, u, consts, dt, n, False)[0] - exact).max() for n in (4, 8, 16)]
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(12.0 < r < 20.0 for r in ratios), (errs, ratios)


def test_plant_clips_and_refuses(airframe: Airframe) -> None:
    plant = Plant(airframe, np.zeros(N_STATE))
    assert plant.set_pitches(np.array([1.0, -1.0, 0.5, -0.5]))
    lim = airframe.limits
    assert_allclose(plant.u, [lim.theta_m_rad[1], lim.theta_t_rad[0], lim.eps_rad[1], lim.eta_rad[0]])
    held = plant.u.copy()
    assert not plant.set_pitches(np.array([0.1, math.nan, 0.0, 0.0]))
    assert not plant.set_pitches(np.array([0.1, 0.0, math.inf, 0.0]))
    assert_allclose(plant.u, held)
    assert plant.rejected_commands == 2
    with pytest.raises(ValueError):
        Plant(airframe, np.full(N_STATE, math.nan))


# --- hover trim ----------------------------------------------------------------------------------


def _trim_residual(v: FloatArray, c: PlantConstants) -> FloatArray:
    u = np.asarray(v[:4])
    x = np.zeros(N_STATE)
    x[6], x[7] = v[4], v[5]
    d = derivative(0.0, x, u, c)
    return np.concatenate([d[VEL], d[OMEGA]])


def _hover_trim(c: PlantConstants) -> FloatArray:
    sol, _info, _ier, msg = fsolve(
        _trim_residual, [0.1, 0.15, 0.0, 0.0, 0.0, 0.0], args=(c,), full_output=True, xtol=1e-13
    )
    assert np.abs(_trim_residual(sol, c)).max() < 1e-10, msg
    return np.asarray(sol)


def _drift_after(airframe: Airframe, v: FloatArray, seconds: float) -> float:
    x0 = np.zeros(N_STATE)
    x0[Z_U] = 100.0
    x0[6], x0[7], x0[8] = v[4], v[5], 0.7
    plant = Plant(airframe, x0)
    assert plant.set_pitches(v[:4])
    assert_allclose(plant.u, v[:4])  # inside the servo limits: nothing clipped
    for _ in range(round(seconds / 0.01)):
        plant.step(0.01)
    return float(np.linalg.norm(plant.x[POS] - x0[POS]))


def test_hover_trim_holds_open_loop(airframe: Airframe, consts: PlantConstants) -> None:
    v = _hover_trim(consts)
    theta_m, theta_t, eps, eta, phi, theta = v
    # near the spec's sanity numbers (the tail thrust needs a little roll and cyclic)
    assert_allclose(theta_m, 0.096, atol=2e-3)
    assert_allclose(theta_t, 0.152, atol=5e-3)
    assert abs(eps) < 0.02 and abs(eta) < 0.03
    assert -0.06 < phi < 0.0  # leans left against the tail thrust (Tt pushes to -y)
    assert abs(theta) < 0.02
    assert _drift_after(airframe, v, 2.0) < 1e-9
    # an untrimmed hover (pitches rounded to 1e-4 rad) drifts visibly in the same time
    assert _drift_after(airframe, np.round(v, 4), 2.0) > 1e-3


def test_hover_trim_with_ixz_and_lm(airframe: Airframe) -> None:
    """The trim exists (and holds) with product of inertia and an offset hub as well."""
    af = dataclasses.replace(
        airframe,
        body=dataclasses.replace(airframe.body, ixz_kg_m2=0.04, main_hub_ahead_cg_m=0.02),
    )
    v = _hover_trim(af.constants())
    assert _drift_after(af, v, 2.0) < 1e-9
