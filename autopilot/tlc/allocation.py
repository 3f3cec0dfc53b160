"""Step 6: thrust and torque command -> the four blade pitches (eqs 34-37), with saturation."""

from __future__ import annotations

import numpy as np

from heli_common.jit import njit
from heli_common.state import N_PITCH, FloatArray
from heli_common.vehicle import rotor
from heli_common.vehicle.airframe import PlantConstants


@njit
def main_rotor_torque(tm: float, c: PlantConstants) -> float:
    """Qm for thrust Tm through the rotor maps (eq. 35)."""
    tc_m = tm / c.thrust_scale_m
    return rotor.torque_coeff(tc_m, c.s_m, c.delta) * c.torque_scale_m


@njit
def solve_cyclic_tail(
    qc: FloatArray, tm: float, qm: float, c: PlantConstants, k_hub: float
) -> tuple[float, float, float]:
    """:func:`solve_cyclic_tail3` of the torque as an array."""
    return solve_cyclic_tail3(qc[0], qc[1], qc[2], tm, qm, c, k_hub)


@njit
def solve_cyclic_tail3(
    q0: float, q1: float, q2: float, tm: float, qm: float, c: PlantConstants, k_hub: float
) -> tuple[float, float, float]:
    """[Tt, eps, eta] = QA^-1 (Qc - QB) for the design torque model (15), by Cramer's rule.

    QA = [[ht, Qm, Tm hm], [0, Tm hm, -Qm], [lt, 0, -Tm lm]], QB = [0, Tm lm, -Qm];
    det QA = -(ht hm lm + lt hm^2) Tm^2 - lt Qm^2 < 0 whenever Qm > 0 (always: qc >= delta/8).

    With a hub spring ``k_hub`` [N m/rad] (the rotor-aware TLC; 0 in the paper's model) the
    disc's tilt (eps, eta are then the flapping a1, b1) moments by ``Tm hm + k_hub`` per rad.
    """
    lever = tm * c.hm + k_hub
    a11, a12, a13 = c.ht, qm, lever
    a21, a22, a23 = 0.0, lever, -qm
    a31, a32, a33 = c.lt, 0.0, -tm * c.lm
    b1, b2, b3 = q0, q1 - tm * c.lm, q2 + qm
    det = a11 * (a22 * a33 - a23 * a32) - a12 * (a21 * a33 - a23 * a31) + a13 * (a21 * a32 - a22 * a31)
    d1 = b1 * (a22 * a33 - a23 * a32) - a12 * (b2 * a33 - a23 * b3) + a13 * (b2 * a32 - a22 * b3)
    d2 = a11 * (b2 * a33 - a23 * b3) - b1 * (a21 * a33 - a23 * a31) + a13 * (a21 * b3 - b2 * a31)
    d3 = a11 * (a22 * b3 - b2 * a32) - a12 * (a21 * b3 - b2 * a31) + b1 * (a21 * a32 - a22 * a31)
    return d1 / det, d2 / det, d3 / det


@njit
def clip(v: float, lo: float, hi: float) -> tuple[float, bool]:
    if v < lo:
        return lo, True
    if v > hi:
        return hi, True
    return v, False


@njit
def collective_tail_tilt(
    qc: FloatArray, tm: float, c: PlantConstants, lim: FloatArray, k_hub: float
) -> tuple[FloatArray, float, int]:
    """:func:`collective_tail_tilt3` of the torque as an array, into a new array."""
    u = np.empty(N_PITCH)
    tm, mask = collective_tail_tilt3(qc[0], qc[1], qc[2], tm, c, lim, k_hub, u)
    return u, tm, mask


@njit
def collective_tail_tilt3(
    q0: float, q1: float, q2: float, tm: float, c: PlantConstants, lim: FloatArray, k_hub: float,
    u: FloatArray,
) -> tuple[float, int]:  # fmt: skip
    """Thrust ``tm`` and body torque ``(q0, q1, q2)`` -> (theta_m, theta_t, the disc's tilt
    forward and to the right), the two pitches clipped to ``lim``, into ``u``. Returns (the thrust the
    clipped collective really gives, saturation mask: 1 theta_m, 2 theta_t)."""
    theta_m, sat_m = clip(
        rotor.pitch_from_thrust_coeff(tm / c.thrust_scale_m, c.a_m, c.s_m), lim[0, 0], lim[0, 1]
    )
    if sat_m:  # recompute the thrust the clipped collective really gives
        tm = rotor.thrust_coeff(theta_m, c.a_m, c.s_m) * c.thrust_scale_m
    qm = main_rotor_torque(tm, c)
    tt, tilt_x, tilt_y = solve_cyclic_tail3(q0, q1, q2, tm, qm, c, k_hub)
    theta_t, sat_t = clip(
        rotor.pitch_from_thrust_coeff(tt / c.thrust_scale_t, c.a_t, c.s_t), lim[1, 0], lim[1, 1]
    )
    u[0], u[1], u[2], u[3] = theta_m, theta_t, tilt_x, tilt_y
    return tm, sat_m * 1 + sat_t * 2


@njit
def allocate(qc: FloatArray, tm: float, c: PlantConstants, lim: FloatArray) -> tuple[FloatArray, float, int]:
    """Thrust ``tm`` and body torque ``qc`` -> the four pitches (theta_m, theta_t, eps, eta),
    each clipped to ``lim`` (4 x 2). Returns (pitches, the thrust the clipped collective
    really gives, saturation mask: 1 theta_m, 2 theta_t, 4 eps, 8 eta)."""
    u = np.empty(N_PITCH)
    tm, mask = allocate3(qc[0], qc[1], qc[2], tm, c, lim, u)
    return u, tm, mask


@njit
def allocate3(
    q0: float, q1: float, q2: float, tm: float, c: PlantConstants, lim: FloatArray, u: FloatArray
) -> tuple[float, int]:
    """:func:`allocate` of the torque as values, the pitches into ``u``: (the thrust, the
    saturation mask)."""
    tm, mask = collective_tail_tilt3(q0, q1, q2, tm, c, lim, 0.0, u)
    eps, sat_e = clip(u[2], lim[2, 0], lim[2, 1])
    eta, sat_n = clip(u[3], lim[3, 0], lim[3, 1])
    u[2], u[3] = eps, eta
    return tm, mask + sat_e * 4 + sat_n * 8
