"""Gavrilets' X-Cell 60 with its rotor: flapping, hub spring, governed rotor speed (compiled).

The loads of the nonlinear model of Gavrilets, Mettler & Feron (AIAA GNC 2001) in this
project's frames (earth NWU, body FLU), for the rigid body of
:func:`heli_plant.dynamics.rigid_body`. The derivation, the signs and the sources are
in ``docs/rotor-plant.md``; the constants come from a plant file
(:class:`heli_common.vehicle.plant_model.RotorPlant`). Four states join the rigid body's twelve,
kept by the world step after them (layout :data:`ROTOR_STATE`):

* ``a1``, ``b1`` [rad]: the tip-path plane's tilt relative to the shaft, forward and to the
  right (the directions the paper's ``eps``, ``eta`` tilt the thrust). First order with the
  stabilizer bar's time constant ``tau_e = 16 / (gamma_fb Omega)``::

      a1' = -q - a1/tau_e + (A_lon eps - da1/dmu u_h/(Omega R)) / tau_e
      b1' = -p - b1/tau_e + (B_lat eta + db1/dmu_v v_h/(Omega R)) / tau_e
      da1/dmu = db1/dmu_v = 2 K_mu (4 theta_m / 3 - lambda)

  (a nose-down pitch rate ``q`` leaves the disc behind: it tilts aft relative to the shaft;
  flying forward blows it back, sideslip to the left blows it to the right).
* ``Omega`` [rad/s]: main-rotor speed relative to the fuselage,
  ``Omega' = (Q_e - Q_mr - n_tr Q_tr) / I_rot - s r'`` with ``Q_e = P_max delta_t / Omega``, the
  tail rotor geared at ``n_tr`` (the engine's torque acts between fuselage and rotor, so the
  fuselage feels ``-s Q_e`` and a yaw acceleration changes the relative speed);
* the governor's integral of ``Omega_c - Omega`` [rad]: ``delta_t = kp e + ki int e`` in [0, 1].

The governor's set point ``Omega_c`` is an input (the world state's, :meth:`heli_plant.model.
Plant.set_rotor_speed_command`): the plant file's speed unless a rotor-speed controller moves
it (ArduPilot's HeliRSC channel, :mod:`heli_plant.ardupilot_backend`); ``Omega_c <= 0`` is the
engine off (no throttle, the integral held). Two additions to Gavrilets' model, which holds
near the design speed only, make a run-up and a wind-down well posed: the engine's torque
``P_max delta_t / max(Omega, Omega_clutch)`` is held at its value at half the design speed
below it (a slipping centrifugal clutch, not a torque that grows without bound as the rotor
stops), and a stopped rotor (``Omega <= 1 rad/s``) that nothing drives stays stopped.

Loads (each from its own relative air velocity, ``V_a + omega x r``):

* main rotor: thrust and torque from uniform-inflow momentum theory solved each step
  (:mod:`heli_plant.world.air`, wake factor ``eta_w``) at the current ``Omega``, ground
  effect ``1 / (1 - (R / 4 z)^2)`` (Cheeseman & Bennett), thrust along the tip-path plane's
  normal, the hub spring ``K_beta (b1, a1)`` plus the thrust's moment about the c.g., the
  engine's reaction torque ``-s Q_e`` about the shaft (``s = +1`` counter-clockwise seen from above,
  the paper's mirror; ``-1`` clockwise, the real X-Cell);
* tail rotor: the same inflow model on its side velocity, thrust ``-s T_tr`` along body y;
* vertical fin with the tail rotor's wake on part of it (blockage), horizontal stabilizer
  in the main rotor's wake while the wake's skew puts it there, fuselage flat plates in the
  downwash.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import EPS, ETA, P_X, PHI, Q_Y, R_Z, THETA, THETA_M, THETA_T, Z_U, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.plant_model import RotorPlant
from heli_plant.dynamics import gravity_into
from heli_plant.world import air

ROTOR_STATE = Layout("rotor state", ("a1_rad", 1), ("b1_rad", 1), ("omega_rad_s", 1), ("governor_int_rad", 1))
A1 = ROTOR_STATE.offset("a1_rad")
B1 = ROTOR_STATE.offset("b1_rad")
OMEGA_R = ROTOR_STATE.offset("omega_rad_s")
GOV_INT = ROTOR_STATE.offset("governor_int_rad")
N_ROTOR = ROTOR_STATE.size
OMEGA_MIN_RAD_S = 1.0  # below this the rotor has stopped: the numbers stay finite, the loads ~ 0
CLUTCH_FRACTION = 0.5  # the engine's torque is held below this fraction of the design speed
GROUND_EFFECT_MIN_Z_OVER_R = 0.5  # the formula's own limit of validity; closer, held there


class RotorConstants(NamedTuple):
    """Everything :func:`rotor_loads` needs, flat for the compiled code. ``on`` False is the
    paper's plant (the rest unused)."""

    on: bool
    rot: float  # rotation sense: +1 counter-clockwise seen from above, -1 clockwise
    rho: float
    cd0: float
    eta_w: float
    r_m: float
    a_m: float
    s_m: float
    k_thrust_m: float  # rho s A R^2: thrust = (C_T / s) k Omega^2
    r_t: float
    a_t: float
    s_t: float
    k_thrust_t: float
    gear_tail: float  # n_tr
    lock: float  # gamma_fb
    a_lon: float
    b_lat: float
    k_beta: float
    k_mu: float
    p_max: float
    i_rot: float
    omega_c: float  # the design speed: the governor's set point unless a command moves it
    omega_clutch: float  # below it the engine's torque is held (the clutch slips)
    kp: float
    ki: float
    s_x: float
    s_y: float
    s_z: float
    ground_effect: bool
    fin_area: float
    fin_slope: float
    fin_l: float
    fin_h: float
    fin_block: float
    ht_area: float
    ht_slope: float
    ht_l: float


OFF = RotorConstants._make((False, *([0.0] * 27), False, *([0.0] * 8)))


def rotor_constants(rp: RotorPlant, af: Airframe) -> RotorConstants:
    """The compiled constants of ``rp`` on airframe ``af`` (the plant file's airframe, or it
    with the world's mismatch applied: its main rotor speed is the governor's set point and
    the tail's over it the gear ratio)."""
    rho = af.air.density_kg_m3
    m, t = af.main_rotor, af.tail_rotor
    fl, ae = rp.flapping, rp.aero
    return RotorConstants(
        on=True, rot=rp.rotation_sign, rho=rho, cd0=af.air.profile_drag_coeff, eta_w=ae.wake_factor,
        r_m=m.radius_m, a_m=m.lift_slope_per_rad, s_m=m.solidity,
        k_thrust_m=rho * m.solidity * m.disc_area_m2 * m.radius_m**2,
        r_t=t.radius_m, a_t=t.lift_slope_per_rad, s_t=t.solidity,
        k_thrust_t=rho * t.solidity * t.disc_area_m2 * t.radius_m**2,
        gear_tail=t.speed_rad_s / m.speed_rad_s, lock=fl.stabilizer_bar_lock_number,
        a_lon=fl.lon_gain_rad_per_rad, b_lat=fl.lat_gain_rad_per_rad, k_beta=fl.hub_stiffness_n_m_per_rad,
        k_mu=fl.blowback_k_mu, p_max=rp.engine.max_power_w, i_rot=rp.engine.rotating_inertia_kg_m2,
        omega_c=m.speed_rad_s, omega_clutch=CLUTCH_FRACTION * m.speed_rad_s,
        kp=rp.governor.kp_per_rad_s, ki=rp.governor.ki_per_rad,
        s_x=ae.fuselage_areas_m2[0], s_y=ae.fuselage_areas_m2[1], s_z=ae.fuselage_areas_m2[2],
        ground_effect=ae.ground_effect, fin_area=rp.fin.area_m2, fin_slope=rp.fin.lift_slope_per_rad,
        fin_l=rp.fin.behind_cg_m, fin_h=rp.fin.above_cg_m, fin_block=rp.fin.tail_rotor_blockage,
        ht_area=rp.stabilizer.area_m2, ht_slope=rp.stabilizer.lift_slope_per_rad,
        ht_l=rp.stabilizer.behind_cg_m,
    )  # fmt: skip


@njit
def ground_effect_factor(hub_height_m: float, radius_m: float) -> float:
    """Thrust in ground effect over thrust out of it at constant power, Cheeseman & Bennett
    (1955): ``1 / (1 - (R / 4 z)^2)``, ``z`` held at >= R/2 (1.33 there); 1 below ground."""
    if hub_height_m <= 0.0:
        return 1.0
    zr = max(hub_height_m / radius_m, GROUND_EFFECT_MIN_Z_OVER_R)
    k = 1.0 / (4.0 * zr)
    return 1.0 / (1.0 - k * k)


@njit
def in_main_wake(u_a: float, w_a: float, v_i: float, l_ht: float, r_m: float, h_m: float) -> bool:
    """Is the horizontal stabilizer (``l_ht`` behind the c.g., ``h_m`` below the hub) in the
    main rotor's wake? The wake leaves the disc at ``v_i + w_a`` downward and ``u_a`` aft
    relative to the body; its skew ``tan chi = u_a / (v_i + w_a)`` carries the disc's
    column over the stabilizer for ``(l_ht - R)/h <= tan chi <= (l_ht + R)/h`` (Gavrilets'
    K_lambda switch, here from the geometry)."""
    down = v_i + w_a
    if down <= 0.0 or h_m <= 0.0:
        return False
    tan_chi = u_a / down
    return (l_ht - r_m) / h_m <= tan_chi <= (l_ht + r_m) / h_m


@njit
def rotor_loads(
    y: FloatArray, u: FloatArray, c: PlantConstants, g: RotorConstants, u_a: float, v_a: float, w_a: float,
    lam_m_guess: float, lam_t_guess: float, n_state: int, omega_c: float,
) -> tuple[FloatArray, FloatArray, FloatArray, float, float, float]:  # fmt: skip
    """(F [N], Q [N m] body FLU, rotor-state derivative, lam_m, lam_t, throttle) at the
    augmented state ``y`` (rigid body, then the rotor state at ``n_state``), blade pitches
    ``u``, c.g. air-relative velocity ``(u_a, v_a, w_a)`` [m/s FLU] and the governor's set
    point ``omega_c`` [rad/s] (``<= 0``: the engine off)."""
    f, mom, dr = np.empty(3), np.empty(3), np.empty(N_ROTOR)
    cph, sph, cth, sth = math.cos(y[PHI]), math.sin(y[PHI]), math.cos(y[THETA]), math.sin(y[THETA])
    lam_m, lam_t, throttle = rotor_loads_into(y, u, c, g, u_a, v_a, w_a, lam_m_guess, lam_t_guess, n_state,
                                              omega_c, cph, sph, cth, sth, f, mom, dr)  # fmt: skip
    return f, mom, dr, lam_m, lam_t, throttle


@njit
def rotor_loads_into(
    y: FloatArray, u: FloatArray, c: PlantConstants, g: RotorConstants, u_a: float, v_a: float, w_a: float,
    lam_m_guess: float, lam_t_guess: float, n_state: int, omega_c: float, cph: float, sph: float,
    cth: float, sth: float, f: FloatArray, mom: FloatArray, dr: FloatArray,
) -> tuple[float, float, float]:  # fmt: skip
    """:func:`rotor_loads` written into ``f``, ``mom``, ``dr`` (the integrator's buffers, no
    array made), with the roll and pitch angles' cosines and sines given (the caller's, for
    the rigid body too); returns (lam_m, lam_t, throttle)."""
    p, q, r = y[P_X], y[Q_Y], y[R_Z]
    a1, b1 = y[n_state + A1], y[n_state + B1]
    om = max(y[n_state + OMEGA_R], OMEGA_MIN_RAD_S)
    # main rotor
    tip_m = om * g.r_m
    um, vm, wm = air.hub_velocity_flu(u_a, v_a, w_a, p, q, r, c.lm, 0.0, c.hm)
    mu, mu_z = air.advance_ratios(um, vm, wm, tip_m)
    sq = g.k_thrust_m * om * om
    tm, qm, lam_m, vi_m = air.rotor_loads_from_ratios(
        u[THETA_M], mu, mu_z, g.a_m, g.s_m, g.cd0, sq, sq * g.r_m, tip_m, g.eta_w, lam_m_guess
    )
    if g.ground_effect:
        tm *= ground_effect_factor(y[Z_U] + c.hm, g.r_m)
    sa, ca, sb, cb = math.sin(a1), math.cos(a1), math.sin(b1), math.cos(b1)
    d = math.sqrt(1.0 - sa * sa * sb * sb)
    fx, fy, fz = tm * sa * cb / d, -tm * ca * sb / d, tm * ca * cb / d
    # tail rotor: thrust along -s y body, so its axial (climb) speed is -s v at the hub
    om_t = g.gear_tail * om
    tip_t = om_t * g.r_t
    ut, vt, wt = air.hub_velocity_flu(u_a, v_a, w_a, p, q, r, -c.lt, 0.0, c.ht)
    mu_t, mu_zt = air.advance_ratios(ut, wt, -g.rot * vt, tip_t)
    sq_t = g.k_thrust_t * om_t * om_t
    tt, qt, lam_t, vi_t = air.rotor_loads_from_ratios(
        u[THETA_T], mu_t, mu_zt, g.a_t, g.s_t, g.cd0, sq_t, sq_t * g.r_t, tip_t, g.eta_w, lam_t_guess
    )
    fy_tr = -g.rot * tt
    # vertical fin: part of it in the tail rotor's wake, which moves opposite to its thrust
    uf, vf, wf = air.hub_velocity_flu(u_a, v_a, w_a, p, q, r, -g.fin_l, 0.0, g.fin_h)
    v_vf = vf - g.rot * g.fin_block * vi_t
    # the fin's airspeed by its square root, not hypot (a library call, ~4x the latency)
    fy_vf = -0.5 * g.rho * g.fin_area * (g.fin_slope * math.sqrt(uf * uf + wf * wf) + abs(v_vf)) * v_vf
    # horizontal stabilizer, in the main rotor's downwash while the wake is over it
    uh, _, wh = air.hub_velocity_flu(u_a, v_a, w_a, p, q, r, -g.ht_l, 0.0, 0.0)
    w_ht = wh + (vi_m if in_main_wake(u_a, w_a, vi_m, g.ht_l, g.r_m, c.hm) else 0.0)
    fz_ht = -0.5 * g.rho * g.ht_area * (g.ht_slope * abs(uh) * w_ht + abs(w_ht) * w_ht)
    fux, fuy, fuz = air.fuselage_force_flu(u_a, v_a, w_a, vi_m, g.s_x, g.s_y, g.s_z, g.rho)
    gravity_into(f, c, cph, sph, cth, sth)
    f[0] += fx + fux
    f[1] += fy + fy_tr + fy_vf + fuy
    f[2] += fz + fz_ht + fuz
    # the governor's throttle and the engine's torque, whose reaction the fuselage takes
    engine_on = omega_c > 0.0
    e = omega_c - om
    raw = g.kp * e + g.ki * y[n_state + GOV_INT] if engine_on else 0.0
    throttle = min(max(raw, 0.0), 1.0)
    q_e = g.p_max * throttle / max(om, g.omega_clutch)
    # hub spring + thrust at the hub (r x F), tail rotor and fin at the tail, stabilizer
    mom[0] = g.k_beta * b1 - c.hm * fy - c.ht * fy_tr - g.fin_h * fy_vf
    mom[1] = g.k_beta * a1 + c.hm * fx - c.lm * fz + qt + g.ht_l * fz_ht
    mom[2] = c.lm * fy - g.rot * q_e - c.lt * fy_tr - g.fin_l * fy_vf
    # flapping, rotor speed (relative to the fuselage: the caller adds -s r'), governor
    inv_tau = g.lock * om / 16.0
    dmu = 2.0 * g.k_mu * (4.0 * u[THETA_M] / 3.0 - lam_m)
    dr[A1] = -q - a1 * inv_tau + inv_tau * (g.a_lon * u[EPS] - dmu * um / tip_m)
    dr[B1] = -p - b1 * inv_tau + inv_tau * (g.b_lat * u[ETA] + dmu * vm / tip_m)
    dr[OMEGA_R] = (q_e - qm - g.gear_tail * qt) / g.i_rot
    if y[n_state + OMEGA_R] <= OMEGA_MIN_RAD_S and dr[OMEGA_R] < 0.0:
        dr[OMEGA_R] = 0.0  # stopped: the drag that is left cannot turn it backwards
    winding = (raw >= 1.0 and e > 0.0) or (raw <= 0.0 and e < 0.0)
    dr[GOV_INT] = 0.0 if winding or not engine_on else e
    return lam_m, lam_t, throttle
