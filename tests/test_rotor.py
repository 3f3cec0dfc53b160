"""Rotor maps (heli_common.vehicle.rotor, Zhu & Huo eqs 16-17, 34) and the spec's hover sanity numbers."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.rotor import pitch_from_thrust_coeff, thrust_coeff, torque_coeff
from heli_plant.dynamics import rotor_loads

_C = Airframe.load().constants()
ROTORS = {"main": (_C.a_m, _C.s_m), "tail": (_C.a_t, _C.s_t)}
which = st.sampled_from(sorted(ROTORS))
pitch = st.floats(-0.5, 0.5)


@given(pitch, which)
def test_inverse_of_thrust_coeff(theta: float, rotor: str) -> None:
    a, s = ROTORS[rotor]
    assert_allclose(pitch_from_thrust_coeff(thrust_coeff(theta, a, s), a, s), theta, rtol=0, atol=1e-13)


@given(st.floats(-0.1, 0.1), which)
def test_thrust_coeff_of_inverse(tc: float, rotor: str) -> None:
    a, s = ROTORS[rotor]
    assert_allclose(thrust_coeff(pitch_from_thrust_coeff(tc, a, s), a, s), tc, rtol=1e-11, atol=1e-16)


@given(pitch, which)
def test_odd_and_even(theta: float, rotor: str) -> None:
    a, s = ROTORS[rotor]
    tc = thrust_coeff(theta, a, s)
    assert thrust_coeff(-theta, a, s) == -tc
    assert pitch_from_thrust_coeff(-tc, a, s) == -pitch_from_thrust_coeff(tc, a, s)
    assert torque_coeff(-tc, s, _C.delta) == torque_coeff(tc, s, _C.delta)  # |tc|^1.5
    assert math.copysign(1.0, tc) == math.copysign(1.0, theta) or tc == 0.0


@given(st.floats(0.0, 0.5), which)
def test_hover_momentum_theory(theta: float, rotor: str) -> None:
    """tc solves the blade-element/momentum balance tc = a theta/6 - a lambda/4,
    lambda = sqrt(s tc/2)."""
    a, s = ROTORS[rotor]
    tc = thrust_coeff(theta, a, s)
    lam = math.sqrt(s * tc / 2.0)
    assert_allclose(tc, a * theta / 6.0 - a * lam / 4.0, rtol=0, atol=1e-14)


def test_monotone_and_zero() -> None:
    for a, s in ROTORS.values():
        th = np.linspace(-0.5, 0.5, 1001)
        tc = np.array([thrust_coeff(v, a, s) for v in th])
        assert np.all(np.diff(tc) > 0)
        assert abs(thrust_coeff(0.0, a, s)) < 1e-30
        # torque coefficient: profile part at zero thrust, growing with |tc|
        assert torque_coeff(0.0, s, _C.delta) == _C.delta / 8.0
        qc = np.array([torque_coeff(v, s, _C.delta) for v in tc[tc >= 0]])
        assert np.all(np.diff(qc) > 0)


def test_solidity_and_scales(airframe: Airframe) -> None:
    m, t = airframe.main_rotor, airframe.tail_rotor
    assert_allclose(m.solidity, 2 * 0.058 / (math.pi * 0.775))
    assert_allclose(m.solidity, 0.0476, atol=1e-4)  # spec table 6a
    assert_allclose(t.solidity, 0.142, atol=1e-3)
    c = airframe.constants()
    rho = airframe.air.density_kg_m3
    assert_allclose(c.thrust_scale_m, rho * m.solidity * math.pi * 0.775**2 * (167.0 * 0.775) ** 2)
    assert_allclose(c.torque_scale_m, c.thrust_scale_m * 0.775)
    assert_allclose(t.speed_rad_s / m.speed_rad_s, 4.66, rtol=1e-4)


def test_spec_hover_sanity_numbers(consts: PlantConstants) -> None:
    """Spec section 2: Tm = m g -> tc_m 0.0436 -> theta_m 0.096 rad; Qm 4.4 N m;
    Tt = Qm / lt 4.9 N -> theta_t 0.15 rad."""
    c = consts
    tm = c.mass_kg * c.gravity_m_s2
    assert_allclose(tm, 80.4, atol=0.05)
    tc_m = tm / c.thrust_scale_m
    assert_allclose(tc_m, 0.0436, atol=5e-5)
    theta_m = pitch_from_thrust_coeff(tc_m, c.a_m, c.s_m)
    assert_allclose(theta_m, 0.096, atol=5e-4)
    qm = torque_coeff(tc_m, c.s_m, c.delta) * c.torque_scale_m
    assert_allclose(qm, 4.4, atol=0.05)
    tt = qm / c.lt
    assert_allclose(tt, 4.9, atol=0.05)
    theta_t = pitch_from_thrust_coeff(tt / c.thrust_scale_t, c.a_t, c.s_t)
    assert_allclose(theta_t, 0.15, atol=5e-3)
    # and the plant's rotor loads at those pitches give back the same thrusts and torque
    tm2, qm2, tt2, _ = rotor_loads(theta_m, theta_t, c)
    assert_allclose([tm2, qm2, tt2], [tm, qm, tt], rtol=1e-12)


@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))
def test_rotor_loads_use_the_maps(theta_m: float, theta_t: float) -> None:
    c = _C
    tm, qm, tt, qt = rotor_loads(theta_m, theta_t, c)
    tcm, tct = thrust_coeff(theta_m, c.a_m, c.s_m), thrust_coeff(theta_t, c.a_t, c.s_t)
    assert_allclose(tm, tcm * c.thrust_scale_m, rtol=1e-14, atol=1e-14)
    assert_allclose(tt, tct * c.thrust_scale_t, rtol=1e-14, atol=1e-14)
    assert_allclose(qm, torque_coeff(tcm, c.s_m, c.delta) * c.torque_scale_m, rtol=1e-14)
    assert_allclose(qt, torque_coeff(tct, c.s_t, c.delta) * c.torque_scale_t, rtol=1e-14)
    assert qm > 0 and qt > 0
