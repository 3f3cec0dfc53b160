"""The un-simplified helicopter model (Zhu & Huo eqs 7-13, 16-17) as a pure function.

``derivative(t, x, u, c)`` returns dx/dt for the named state layout of
:mod:`heli_common.state`, pitches ``u`` [rad] and :class:`~heli_common.vehicle.airframe.PlantConstants`.
Frames: earth NWU, body FLU, main thrust along +z_body. Torques follow the paper's
printed eq. 13 (see docs/model.md section 2.2 for the physically derived
alternative and why the printed one is kept).
"""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.state import (
    EPS,
    ETA,
    N_STATE,
    P_X,
    PHI,
    PSI,
    Q_Y,
    R_Z,
    THETA,
    THETA_M,
    THETA_T,
    U_F,
    V_L,
    W_U,
    X_N,
    FloatArray,
)
from heli_common.vehicle import rotor
from heli_common.vehicle.airframe import PlantConstants


@njit
def rotor_loads(theta_m: float, theta_t: float, c: PlantConstants) -> tuple[float, float, float, float]:
    """(Tm, Qm, Tt, Qt): main and tail thrust [N] and reaction torque [N m] at the given pitches."""
    tc_m = rotor.thrust_coeff(theta_m, c.a_m, c.s_m)
    tc_t = rotor.thrust_coeff(theta_t, c.a_t, c.s_t)
    tm = tc_m * c.thrust_scale_m
    qm = rotor.torque_coeff(tc_m, c.s_m, c.delta) * c.torque_scale_m
    tt = tc_t * c.thrust_scale_t
    qt = rotor.torque_coeff(tc_t, c.s_t, c.delta) * c.torque_scale_t
    return tm, qm, tt, qt


@njit
def forces_torques(x: FloatArray, u: FloatArray, c: PlantConstants) -> tuple[FloatArray, FloatArray]:
    """Body-frame force F [N] (gravity included) and torque Q [N m], eqs 12-13."""
    tm, qm, tt, qt = rotor_loads(u[THETA_M], u[THETA_T], c)
    return forces_from_loads(x, u, c, tm, qm, tt, qt)


@njit
def gravity_flu(x: FloatArray, c: PlantConstants) -> FloatArray:
    """Weight in body FLU [N]: ``m R^T (0, 0, -g)``."""
    return gravity_at(c, math.cos(x[PHI]), math.sin(x[PHI]), math.cos(x[THETA]), math.sin(x[THETA]))


@njit
def gravity_at(c: PlantConstants, cph: float, sph: float, cth: float, sth: float) -> FloatArray:
    f = np.empty(3)
    gravity_into(f, c, cph, sph, cth, sth)
    return f


@njit
def gravity_into(f: FloatArray, c: PlantConstants, cph: float, sph: float, cth: float, sth: float) -> None:
    """:func:`gravity_at` written into ``f``: the integrator's stages reuse one buffer."""
    mg = c.mass_kg * c.gravity_m_s2
    f[0] = mg * sth
    f[1] = -mg * cth * sph
    f[2] = -mg * cth * cph


@njit
def forces_from_loads(
    x: FloatArray, u: FloatArray, c: PlantConstants, tm: float, qm: float, tt: float, qt: float
) -> tuple[FloatArray, FloatArray]:
    """Eqs 12-13 for given rotor thrusts and torques (the hover maps', or the inflow
    model's in a relative wind): body force with gravity, and torque."""
    return forces_from_loads_at(u, c, tm, qm, tt, qt, gravity_flu(x, c))


@njit
def forces_from_loads_at(
    u: FloatArray, c: PlantConstants, tm: float, qm: float, tt: float, qt: float, f: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """:func:`forces_from_loads` with the weight ``f`` [N, FLU] given (and added to in place):
    a caller that has the attitude's sines and cosines already passes :func:`gravity_at`."""
    q = np.empty(3)
    forces_from_loads_into(u, c, tm, qm, tt, qt, f, q)
    return f, q


@njit
def forces_from_loads_into(
    u: FloatArray, c: PlantConstants, tm: float, qm: float, tt: float, qt: float, f: FloatArray, q: FloatArray
) -> None:
    """:func:`forces_from_loads_at` with the torque written into ``q`` (no array made)."""
    eps, eta = u[EPS], u[ETA]
    seps, ceps, seta, ceta = math.sin(eps), math.cos(eps), math.sin(eta), math.cos(eta)
    d = math.sqrt(1.0 - seps * seps * seta * seta)
    f[0] = f[0] + tm * seps * ceta / d
    f[1] = f[1] - tm * ceps * seta / d - tt
    f[2] = f[2] + tm * ceps * ceta / d
    q[0] = tm * c.hm * seta + tt * c.ht + qm * seps
    q[1] = tm * c.lm + tm * c.hm * seps + qt - qm * seta
    q[2] = -tm * c.lm * seta + tt * c.lt - qm * ceps * ceta


@njit
def rigid_body(x: FloatArray, f: FloatArray, q: FloatArray, c: PlantConstants) -> FloatArray:
    """Newton-Euler: dP = Rt V, m dV = -w x mV + F, dgamma = E^-1 w, J dw = -w x Jw + Q."""
    cph, sph = math.cos(x[PHI]), math.sin(x[PHI])
    cth, sth = math.cos(x[THETA]), math.sin(x[THETA])
    cps, sps = math.cos(x[PSI]), math.sin(x[PSI])
    return rigid_body_at(x, f, q, c, cph, sph, cth, sth, cps, sps)


@njit
def rigid_body_at(
    x: FloatArray, f: FloatArray, q: FloatArray, c: PlantConstants, cph: float, sph: float,
    cth: float, sth: float, cps: float, sps: float,
) -> FloatArray:  # fmt: skip
    """:func:`rigid_body` with the attitude's cosines and sines given (a derivative needs
    them for the weight and the air too: taken once, the same bits)."""
    dx = np.empty(N_STATE)
    rigid_body_into(dx, x, f, q, c, cph, sph, cth, sth, cps, sps)
    return dx


@njit
def rigid_body_into(
    dx: FloatArray, x: FloatArray, f: FloatArray, q: FloatArray, c: PlantConstants, cph: float, sph: float,
    cth: float, sth: float, cps: float, sps: float,
) -> None:  # fmt: skip
    """:func:`rigid_body_at` written into ``dx[:N_STATE]`` (``dx`` may be longer: the
    integrator's buffers hold the rotor plant's states after the rigid body's); ``dx`` must
    not be ``x`` (the attitude is read after the first derivatives are written)."""
    u, v, w = x[U_F], x[V_L], x[W_U]
    p, qr, r = x[P_X], x[Q_Y], x[R_Z]
    # Rt and E^-1 written out: the same expressions as rot_body_to_earth and euler_rates (so
    # the same bits), without their two arrays; a derivative is evaluated four times a step.
    dx[X_N] = (cth * cps) * u + (sph * sth * cps - cph * sps) * v + (cph * sth * cps + sph * sps) * w
    dx[X_N + 1] = (cth * sps) * u + (sph * sth * sps + cph * cps) * v + (cph * sth * sps - sph * cps) * w
    dx[X_N + 2] = (-sth) * u + (sph * cth) * v + (cph * cth) * w
    inv_m = 1.0 / c.mass_kg
    dx[U_F] = -(qr * w - r * v) + f[0] * inv_m
    dx[V_L] = -(r * u - p * w) + f[1] * inv_m
    dx[W_U] = -(p * v - qr * u) + f[2] * inv_m
    qs_rc = qr * sph + r * cph
    dx[PHI] = p + qs_rc * math.tan(x[THETA])
    dx[THETA] = qr * cph - r * sph
    dx[PSI] = qs_rc / cth
    # J w with J = [[Ixx,0,-Ixz],[0,Iyy,0],[-Ixz,0,Izz]]
    hx = c.ixx * p - c.ixz * r
    hy = c.iyy * qr
    hz = -c.ixz * p + c.izz * r
    mx = q[0] - (qr * hz - r * hy)
    my = q[1] - (r * hx - p * hz)
    mz = q[2] - (p * hy - qr * hx)
    dx[P_X] = c.inv_ixx * mx + c.inv_ixz * mz
    dx[Q_Y] = c.inv_iyy * my
    dx[R_Z] = c.inv_ixz * mx + c.inv_izz * mz


@njit
def derivative(t: float, x: FloatArray, u: FloatArray, c: PlantConstants) -> FloatArray:
    """dx/dt of the full model: f(t, x, u, params). ``t`` is unused (time-invariant plant)."""
    f, q = forces_torques(x, u, c)
    return rigid_body(x, f, q, c)
