"""The world in the plant's step: servos, wind, air loads and disturbances, compiled.

:class:`WorldModel` turns a configured :class:`heli_common.world.config.World` into flat arrays
(named offsets below) and :func:`world_plant_step` advances the vehicle through one hold
interval with them, sub-step by sub-step (step ``h = dt / n_sub``):

1. the servos (delay, quantum, dead band, rate limit, lag, limits) move toward the held
   command by one step of ``h``: the blade pitches the rotors see;
2. the air velocity ``W`` (earth NWU) is evaluated at the sub-step's start: steady wind,
   the 1-cosine gust, and the Dryden filters advanced by one step with noise drawn from
   ``(seed, stream, step counter)``, so the same seed gives the same air in any process;
3. one RK4 step of the rigid body with ``W``, the pitches and the disturbance held, the
   loads in :func:`derivative_in_air` (the paper's loads where the air is off).

Counter-based noise and a step counter in the state make the world a pure function of
(seed, step sequence): in-process and lockstep processes step the same way and fly the
same flight. With the world off, the plant does not call any of this.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from heli_common.jit import njit
from heli_common.kinematics import earth_to_body_at, rot_body_to_earth
from heli_common.layout import Layout
from heli_common.state import N_PITCH, N_STATE, P_X, PHI, PSI, Q_Y, R_Z, THETA, U_F, V_L, W_U, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.plant_model import RotorPlant
from heli_common.world import servo_model as servos
from heli_common.world.config import World
from heli_common.world.gusts import gust_factor, mean_wind_nwu
from heli_plant import rotor
from heli_plant.contact import apply_ground_contact
from heli_plant.dynamics import forces_from_loads_into, gravity_into, rigid_body_into, rotor_loads
from heli_plant.rotor import N_ROTOR, RotorConstants
from heli_plant.world import air, wind


class AirConstants(NamedTuple):
    """The air loads' switches and constants, flat for the compiled step."""

    fuselage: bool
    inflow: bool
    rho: float
    s_x: float
    s_y: float
    s_z: float
    tip_speed_main: float  # Omega R [m/s]
    tip_speed_tail: float
    wake_factor: float


# world parameters (float64 array), set by WorldModel, read by the compiled step
WORLD_PARAMS = Layout(
    "world parameters",
    ("wind_nwu_m_s", 3),  # steady wind, earth NWU [m/s]
    ("gust_nwu_m_s", 3),  # gust at full amplitude, earth NWU [m/s]
    ("gust_start_s", 1),
    ("gust_rise_s", 1),
    ("gust_hold_s", 1),  # inf: holds for ever
    ("gust_fall_s", 1),
    ("turb_on", 1),
    ("turb_psi_from_rad", 1),  # mean-wind heading the turbulence axes follow [rad]
    ("turb_calm", 1),  # 1: no mean wind, the axes are north/west/up
    ("seed", 1),
    ("dist_force_n", 3),
    ("dist_torque_n_m", 3),
    ("dist_body", 1),  # 1: body frame, 0: earth frame
    ("dist_kind", 1),  # 0 constant, 1 step, 2 sine
    ("dist_start_s", 1),
    ("dist_freq_hz", 1),
    ("servos_on", 1),
)
WP_WIND = WORLD_PARAMS.offset("wind_nwu_m_s")
WP_GUST = WORLD_PARAMS.offset("gust_nwu_m_s")
WP_GUST_START = WORLD_PARAMS.offset("gust_start_s")
WP_GUST_RISE = WORLD_PARAMS.offset("gust_rise_s")
WP_GUST_HOLD = WORLD_PARAMS.offset("gust_hold_s")
WP_GUST_FALL = WORLD_PARAMS.offset("gust_fall_s")
WP_TURB_ON = WORLD_PARAMS.offset("turb_on")
WP_TURB_PSI_FROM = WORLD_PARAMS.offset("turb_psi_from_rad")
WP_TURB_CALM = WORLD_PARAMS.offset("turb_calm")
WP_SEED = WORLD_PARAMS.offset("seed")
WP_DIST_FORCE = WORLD_PARAMS.offset("dist_force_n")
WP_DIST_TORQUE = WORLD_PARAMS.offset("dist_torque_n_m")
WP_DIST_BODY = WORLD_PARAMS.offset("dist_body")
WP_DIST_KIND = WORLD_PARAMS.offset("dist_kind")
WP_DIST_START = WORLD_PARAMS.offset("dist_start_s")
WP_DIST_FREQ = WORLD_PARAMS.offset("dist_freq_hz")
WP_SERVOS_ON = WORLD_PARAMS.offset("servos_on")
N_WP = WORLD_PARAMS.size
DIST_KINDS = {"constant": 0.0, "step": 1.0, "sine": 2.0}
DIST_NONE = -1.0  # no disturbance: nothing added (not even a zero)

# the integrator's work rows (each the augmented state's length): one stage's state, then
# the four slopes
RK_WORK = Layout("RK4 work rows", ("stage", 1), ("k1", 1), ("k2", 1), ("k3", 1), ("k4", 1))
RK_STAGE = RK_WORK.offset("stage")
RK_K1 = RK_WORK.offset("k1")
RK_K2 = RK_WORK.offset("k2")
RK_K3 = RK_WORK.offset("k3")
RK_K4 = RK_WORK.offset("k4")
N_RK_WORK = RK_WORK.size

# the step's small buffers
STEP_SCRATCH = Layout(
    "plant-step scratch",
    ("pitch_rad", N_PITCH),  # the servos' output: the pitches the rotors see
    ("air_nwu_m_s", 3),  # the sub-step's air velocity
    ("force_n", 3),  # a derivative's body force and torque
    ("torque_n_m", 3),
    ("rotor_rate", N_ROTOR),  # the rotor plant's derivative, unused, when only its inflow is wanted
)
SC_PITCH = STEP_SCRATCH.offset("pitch_rad")
SC_AIR = STEP_SCRATCH.offset("air_nwu_m_s")
SC_FORCE = STEP_SCRATCH.offset("force_n")
SC_TORQUE = STEP_SCRATCH.offset("torque_n_m")
SC_ROTOR_RATE = STEP_SCRATCH.offset("rotor_rate")
N_STEP_SCRATCH = STEP_SCRATCH.size
N_AUG = N_STATE + N_ROTOR  # the longest state a step integrates (the rotor plant's)

# the world state's work area: no state, every part written before it is read. The step's
# state, its RK4 rows and buffers, and the accelerometer's derivative live here, so a tick
# makes no array but the next state it returns.
WORK = Layout(
    "plant-step work",
    ("y", N_AUG),  # the state being integrated (augmented with the rotor plant's)
    ("rk", N_RK_WORK * N_AUG),  # RK_WORK's rows, each as long as the state integrated
    ("scratch", N_STEP_SCRATCH),
)
WK_Y = WORK.offset("y")
WK_RK = WORK.offset("rk")
WK_SCRATCH = WORK.offset("scratch")

# world state (float64 array), advanced by the compiled step
WORLD_STATE = Layout(
    "world state",
    ("step", 1),  # sub-steps taken (the noise counter)
    ("lam_main", 1),  # last inflow ratios: the next solve starts there
    ("lam_tail", 1),
    ("air_nwu_m_s", 3),  # the air velocity of the last sub-step, earth NWU [m/s]
    ("pitch_rad", N_PITCH),  # the blade pitches of the last sub-step [rad]
    ("turb", wind.N_DRYDEN_STATE),  # the Dryden filters' state
    ("rotor", rotor.N_ROTOR),  # the rotor plant's own states
    ("throttle", 1),  # the governor's throttle of the last sub-step [0, 1]
    ("governor_setpoint_rad_s", 1),  # the rotor plant's governor set point (<= 0: engine off)
    ("work", WORK.size),  # not state: the step's and the accelerometer's buffers (WORK)
)
WS_STEP = WORLD_STATE.offset("step")
WS_LAM_MAIN = WORLD_STATE.offset("lam_main")
WS_LAM_TAIL = WORLD_STATE.offset("lam_tail")
WS_AIR = WORLD_STATE.offset("air_nwu_m_s")
WS_PITCH = WORLD_STATE.offset("pitch_rad")
WS_TURB = WORLD_STATE.offset("turb")
WS_ROTOR = WORLD_STATE.offset("rotor")
WS_THROTTLE = WORLD_STATE.offset("throttle")
WS_GOVERNOR_SET = WORLD_STATE.offset("governor_setpoint_rad_s")
WS_WORK = WORLD_STATE.offset("work")
N_WS = WORLD_STATE.size


@njit
def air_relative_flu(x: FloatArray, rt: FloatArray, w_nwu: FloatArray) -> tuple[float, float, float]:
    """The c.g.'s velocity relative to the air, body FLU: V - R^T W."""
    return (
        x[U_F] - (rt[0, 0] * w_nwu[0] + rt[1, 0] * w_nwu[1] + rt[2, 0] * w_nwu[2]),
        x[V_L] - (rt[0, 1] * w_nwu[0] + rt[1, 1] * w_nwu[1] + rt[2, 1] * w_nwu[2]),
        x[W_U] - (rt[0, 2] * w_nwu[0] + rt[1, 2] * w_nwu[1] + rt[2, 2] * w_nwu[2]),
    )


@njit
def air_velocity_nwu(
    t: float, wp: FloatArray, ws: FloatArray, dryden: FloatArray
) -> tuple[float, float, float]:
    """W at ``t``: steady wind + gust + turbulence (advancing the Dryden filters one step)."""
    g = gust_factor(t, wp[WP_GUST_START], wp[WP_GUST_RISE], wp[WP_GUST_HOLD], wp[WP_GUST_FALL])
    wx = wp[WP_WIND] + g * wp[WP_GUST]
    wy = wp[WP_WIND + 1] + g * wp[WP_GUST + 1]
    wz = wp[WP_WIND + 2] + g * wp[WP_GUST + 2]
    if wp[WP_TURB_ON] != 0.0:
        turb = ws[WS_TURB : WS_TURB + wind.N_DRYDEN_STATE]
        wind.dryden_step(dryden, turb, int(wp[WP_SEED]), int(ws[WS_STEP]))
        ug, vg, wg = wind.dryden_output(dryden, turb)
        tx, ty, tz = wind.turbulence_nwu(ug, vg, wg, wp[WP_TURB_PSI_FROM], wp[WP_TURB_CALM] != 0.0)
        wx, wy, wz = wx + tx, wy + ty, wz + tz
    return wx, wy, wz


@njit
def disturbance_scale(t: float, wp: FloatArray) -> float:
    kind, t0 = wp[WP_DIST_KIND], wp[WP_DIST_START]
    if kind == DIST_NONE:
        return 0.0
    if kind == 0.0:
        return 1.0
    if t < t0:
        return 0.0
    if kind == 1.0:
        return 1.0
    return math.sin(2.0 * math.pi * wp[WP_DIST_FREQ] * (t - t0))


@njit
def derivative_in_air(
    t: float, x: FloatArray, u: FloatArray, c: PlantConstants, a: AirConstants,
    w_nwu: FloatArray, wp: FloatArray, ws: FloatArray, g: RotorConstants,
) -> FloatArray:  # fmt: skip
    """dx/dt with the air ``w_nwu`` held. The paper's plant (``g.on`` False): rotor loads
    with inflow (or the hover maps), fuselage drag on the air-relative velocity; the rotor
    plant (:mod:`heli_plant.rotor`): its own loads and its rotor states after the rigid
    body's in ``x``. Then the injected disturbance. The ideal world (nothing of the air on)
    computes no air-relative velocity: it is the paper's plant, at the paper plant's cost.
    The inflow solves start from ``ws``' last inflow ratios."""
    dx = np.empty(N_STATE + N_ROTOR if g.on else N_STATE)
    _derivative_into(dx, t, x, u, c, a, w_nwu, wp, ws, g, ws[WS_LAM_MAIN], ws[WS_LAM_TAIL], np.empty(3),
                     np.empty(3))  # fmt: skip
    return dx


@njit
def _derivative_into(
    dx: FloatArray, t: float, x: FloatArray, u: FloatArray, c: PlantConstants, a: AirConstants,
    w_nwu: FloatArray, wp: FloatArray, ws: FloatArray, g: RotorConstants, lam_m0: float,
    lam_t0: float, f: FloatArray, q: FloatArray,
) -> tuple[float, float]:  # fmt: skip
    """:func:`derivative_in_air` written into ``dx`` (not ``x``), with the paper plant's
    inflow solves started from ``(lam_m0, lam_t0)``; returns the inflow ratios it found (the
    guesses back where none is solved): the integrator hands each RK4 stage the previous
    stage's inflow, so a solve starts half a step away instead of a whole one (and no extra
    solve per step is needed). ``f``, ``q`` (3 each) are scratch for the force and torque:
    the integrator's four stages reuse its buffers instead of making arrays."""
    # the attitude's cosines and sines, once for the weight, the air and the rigid body
    cph, sph = math.cos(x[PHI]), math.sin(x[PHI])
    cth, sth = math.cos(x[THETA]), math.sin(x[THETA])
    cps, sps = math.cos(x[PSI]), math.sin(x[PSI])
    trig = (cph, sph, cth, sth, cps, sps)
    if not (g.on or a.inflow or a.fuselage):
        tm, qm, tt, qt = rotor_loads(u[0], u[1], c)
        gravity_into(f, c, cph, sph, cth, sth)
        forces_from_loads_into(u, c, tm, qm, tt, qt, f, q)
        _with_disturbance_into(dx, t, x, f, q, c, wp, False, 0.0, trig)
        return lam_m0, lam_t0
    u_a, v_a, w_a = _air_relative_at(x, trig, w_nwu)
    if g.on:  # the rotor states' derivatives go straight after the rigid body's
        rotor.rotor_loads_into(x, u, c, g, u_a, v_a, w_a, ws[WS_LAM_MAIN], ws[WS_LAM_TAIL], N_STATE,
                               ws[WS_GOVERNOR_SET], cph, sph, cth, sth, f, q, dx[N_STATE:])  # fmt: skip
        _with_disturbance_into(dx, t, x, f, q, c, wp, True, g.rot, trig)
        return lam_m0, lam_t0
    lam_m, lam_t = lam_m0, lam_t0
    if a.inflow:
        tm, qm, tt, qt, lam_m, lam_t = air.rotor_loads_in_air(
            u[0], u[1], u_a, v_a, w_a, x[P_X], x[Q_Y], x[R_Z], c, a.tip_speed_main,
            a.tip_speed_tail, a.wake_factor, lam_m0, lam_t0,
        )  # fmt: skip
        v_i = lam_m * a.tip_speed_main
    else:
        tm, qm, tt, qt = rotor_loads(u[0], u[1], c)
        v_i = 0.0
    gravity_into(f, c, cph, sph, cth, sth)
    forces_from_loads_into(u, c, tm, qm, tt, qt, f, q)
    if a.fuselage:
        fx, fy, fz = air.fuselage_force_flu(u_a, v_a, w_a, v_i, a.s_x, a.s_y, a.s_z, a.rho)
        f[0] += fx
        f[1] += fy
        f[2] += fz
    _with_disturbance_into(dx, t, x, f, q, c, wp, False, 0.0, trig)
    return lam_m, lam_t


@njit
def _air_relative_at(
    x: FloatArray, trig: tuple[float, float, float, float, float, float], w_nwu: FloatArray
) -> tuple[float, float, float]:
    """:func:`air_relative_flu` from the attitude's cosines and sines (no rotation matrix made)."""
    cph, sph, cth, sth, cps, sps = trig
    wx, wy, wz = earth_to_body_at(cph, sph, cth, sth, cps, sps, w_nwu[0], w_nwu[1], w_nwu[2])
    return x[U_F] - wx, x[V_L] - wy, x[W_U] - wz


@njit
def _with_disturbance_into(
    dx: FloatArray, t: float, x: FloatArray, f: FloatArray, q: FloatArray, c: PlantConstants,
    wp: FloatArray, rotor_on: bool, rot: float, trig: tuple[float, float, float, float, float, float],
) -> None:  # fmt: skip
    """The injected disturbance added to ``f``, ``q``; the rigid body's derivative into
    ``dx[:N_STATE]``. With the rotor plant (``rotor_on``) its states' derivatives are in
    ``dx[N_STATE:]`` already: the rotor speed's is made relative to a fuselage yawing at
    ``r'`` (``- rot r'``)."""
    s = disturbance_scale(t, wp)
    if s != 0.0:
        df, dq = wp[WP_DIST_FORCE : WP_DIST_FORCE + 3], wp[WP_DIST_TORQUE : WP_DIST_TORQUE + 3]
        if wp[WP_DIST_BODY] != 0.0:
            for i in range(3):
                f[i] += s * df[i]
                q[i] += s * dq[i]
        else:  # earth -> body: R^T
            cph, sph, cth, sth, cps, sps = trig
            bf = earth_to_body_at(cph, sph, cth, sth, cps, sps, df[0], df[1], df[2])
            bq = earth_to_body_at(cph, sph, cth, sth, cps, sps, dq[0], dq[1], dq[2])
            for i in range(3):
                f[i] += s * bf[i]
                q[i] += s * bq[i]
    rigid_body_into(dx, x, f, q, c, *trig)
    if rotor_on:
        dx[N_STATE + rotor.OMEGA_R] -= rot * dx[R_Z]


@njit
def world_plant_step(
    t: float, x: FloatArray, u_cmd: FloatArray, c: PlantConstants, a: AirConstants, dt: float,
    n_sub: int, contact: bool, wp: FloatArray, ws: FloatArray, servo_p: FloatArray,
    servo_s: FloatArray, dryden: FloatArray, g: RotorConstants,
) -> tuple[FloatArray, bool]:  # fmt: skip
    """The plant's one step (the only RK4): over one hold interval of the command ``u_cmd``
    in ``n_sub`` sub-steps, servos, air and disturbance advanced per sub-step (the air and
    pitches held within one), then ground contact. With the rotor plant (``g.on``) its
    states (``ws[WS_ROTOR:]``) are integrated with the rigid body's; with every effect off
    this is the paper's plant alone.

    The stages and the update are written element by element into ``ws``' work area
    (WORK: no array made but the returned state), each sum in the order numpy's ``y + 0.5 * h * k1`` and
    ``y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)`` evaluate it (the same bits)."""
    h = dt / n_sub
    n = N_AUG if g.on else N_STATE
    y = ws[WS_WORK + WK_Y : WS_WORK + WK_Y + n]
    y[:N_STATE] = x
    if g.on:
        y[N_STATE:] = ws[WS_ROTOR : WS_ROTOR + N_ROTOR]
    ys, k1, k2, k3, k4 = (
        _rk_row(ws, RK_STAGE, n),
        _rk_row(ws, RK_K1, n),
        _rk_row(ws, RK_K2, n),
        _rk_row(ws, RK_K3, n),
        _rk_row(ws, RK_K4, n),
    )
    sc = ws[WS_WORK + WK_SCRATCH : WS_WORK + WK_SCRATCH + N_STEP_SCRATCH]
    u = sc[SC_PITCH : SC_PITCH + N_PITCH]
    u[:] = u_cmd
    w_nwu = sc[SC_AIR : SC_AIR + 3]
    w_nwu[:] = 0.0
    f, q = sc[SC_FORCE : SC_FORCE + 3], sc[SC_TORQUE : SC_TORQUE + 3]
    half, sixth = 0.5 * h, h / 6.0
    for k in range(n_sub):
        tk = t + k * h
        if wp[WP_SERVOS_ON] != 0.0:
            servos.servo_step(servo_p, servo_s, u_cmd, u)
        w_nwu[0], w_nwu[1], w_nwu[2] = air_velocity_nwu(tk, wp, ws, dryden)
        lm, lt = ws[WS_LAM_MAIN], ws[WS_LAM_TAIL]
        lm, lt = _derivative_into(k1, tk, y, u, c, a, w_nwu, wp, ws, g, lm, lt, f, q)
        for j in range(n):
            ys[j] = y[j] + half * k1[j]
        lm, lt = _derivative_into(k2, tk + 0.5 * h, ys, u, c, a, w_nwu, wp, ws, g, lm, lt, f, q)
        for j in range(n):
            ys[j] = y[j] + half * k2[j]
        lm, lt = _derivative_into(k3, tk + 0.5 * h, ys, u, c, a, w_nwu, wp, ws, g, lm, lt, f, q)
        for j in range(n):
            ys[j] = y[j] + h * k3[j]
        lm, lt = _derivative_into(k4, tk + h, ys, u, c, a, w_nwu, wp, ws, g, lm, lt, f, q)
        for j in range(n):
            y[j] = y[j] + sixth * (((k1[j] + 2.0 * k2[j]) + 2.0 * k3[j]) + k4[j])
        if g.on:  # the next solves start from this step's inflow; the throttle, for the record
            cph, sph = math.cos(y[PHI]), math.sin(y[PHI])
            cth, sth = math.cos(y[THETA]), math.sin(y[THETA])
            trig = (cph, sph, cth, sth, math.cos(y[PSI]), math.sin(y[PSI]))
            u_a, v_a, w_a = _air_relative_at(y, trig, w_nwu)
            lam_m0, lam_t0 = ws[WS_LAM_MAIN], ws[WS_LAM_TAIL]
            lam_m, lam_t, thr = rotor.rotor_loads_into(
                y, u, c, g, u_a, v_a, w_a, lam_m0, lam_t0, N_STATE, ws[WS_GOVERNOR_SET], cph, sph, cth, sth,
                f, q, sc[SC_ROTOR_RATE : SC_ROTOR_RATE + N_ROTOR],
            )  # fmt: skip
            ws[WS_LAM_MAIN], ws[WS_LAM_TAIL], ws[WS_THROTTLE] = lam_m, lam_t, thr
        elif a.inflow:  # the next solves start from the last stage's inflow (near the new state)
            ws[WS_LAM_MAIN], ws[WS_LAM_TAIL] = lm, lt
        ws[WS_STEP] += 1.0
    ws[WS_AIR : WS_AIR + 3] = w_nwu
    ws[WS_PITCH : WS_PITCH + N_PITCH] = u
    if g.on:
        ws[WS_ROTOR : WS_ROTOR + N_ROTOR] = y[N_STATE:]
    x_next = y[:N_STATE].copy()  # the one array a step makes: the state it returns
    on_ground = apply_ground_contact(x_next, x) if contact else False
    return x_next, on_ground


@njit
def _rk_row(ws: FloatArray, row: int, n: int) -> FloatArray:
    """RK_WORK's row ``row`` in ``ws``' work area, ``n`` long (a view)."""
    at = WS_WORK + WK_RK + row * n
    return ws[at : at + n]


@njit
def body_derivative_in_air(
    t: float, x: FloatArray, u: FloatArray, c: PlantConstants, a: AirConstants, w_nwu: FloatArray,
    wp: FloatArray, ws: FloatArray, g: RotorConstants,
) -> FloatArray:  # fmt: skip
    """The rigid body's 12 derivatives at ``x`` (the rotor plant's states taken from ``ws``):
    what an accelerometer on the body measures. A view of ``ws``' work area (no array
    made, a tick asks): read it before the next step."""
    n = N_AUG if g.on else N_STATE
    y = x
    if g.on:
        y = ws[WS_WORK + WK_Y : WS_WORK + WK_Y + n]
        y[:N_STATE] = x
        y[N_STATE:] = ws[WS_ROTOR : WS_ROTOR + N_ROTOR]
    dx = _rk_row(ws, RK_K1, n)
    sc = ws[WS_WORK + WK_SCRATCH : WS_WORK + WK_SCRATCH + N_STEP_SCRATCH]
    _derivative_into(dx, t, y, u, c, a, w_nwu, wp, ws, g, ws[WS_LAM_MAIN], ws[WS_LAM_TAIL],
                     sc[SC_FORCE : SC_FORCE + 3], sc[SC_TORQUE : SC_TORQUE + 3])  # fmt: skip
    return dx[:N_STATE]


def _unit_from(from_deg: float, elevation_deg: float) -> FloatArray:
    """The direction air moves for a wind FROM ``from_deg`` at ``elevation_deg``, NWU."""
    return np.asarray(mean_wind_nwu(1.0, from_deg, elevation_deg), dtype=float)


def world_parameters(world: World) -> FloatArray:
    """The compiled step's parameter array for ``world`` (layout: the WP_* offsets)."""
    wp = np.zeros(N_WP)
    w = world.wind
    wp[WP_WIND : WP_WIND + 3] = mean_wind_nwu(w.speed_m_s, w.from_deg, w.elevation_deg)
    g = world.gust
    wp[WP_GUST : WP_GUST + 3] = g.amplitude_m_s * _unit_from(g.from_deg, g.elevation_deg)
    wp[WP_GUST_START], wp[WP_GUST_RISE] = g.start_s, g.rise_s
    wp[WP_GUST_HOLD] = math.inf if g.hold_s < 0.0 else g.hold_s
    wp[WP_GUST_FALL] = g.fall_s
    wp[WP_TURB_ON] = 1.0 if world.turbulence.w20_m_s > 0.0 else 0.0
    wp[WP_TURB_PSI_FROM] = math.radians(w.from_deg)
    wp[WP_TURB_CALM] = 1.0 if w.speed_m_s == 0.0 else 0.0
    wp[WP_SEED] = float(world.seed)
    d = world.disturbance
    wp[WP_DIST_FORCE : WP_DIST_FORCE + 3] = d.force_n
    wp[WP_DIST_TORQUE : WP_DIST_TORQUE + 3] = d.torque_n_m
    wp[WP_DIST_BODY] = 1.0 if d.frame == "body" else 0.0
    wp[WP_DIST_KIND] = DIST_KINDS[d.kind] if d.on else DIST_NONE
    wp[WP_DIST_START], wp[WP_DIST_FREQ] = d.start_s, d.frequency_hz
    wp[WP_SERVOS_ON] = 1.0 if world.servos.on else 0.0
    return wp


CALM_AIR = AirConstants(False, False, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)


@dataclass(frozen=True)
class CalmArrays:
    """A world with every effect off, as the compiled step's arrays: the paper's ideal world
    is this path too (one plant step). ``ws`` is the caller's own (the step writes it)."""

    air: AirConstants = CALM_AIR
    wp: FloatArray = field(default_factory=lambda: world_parameters(World()))
    ws: FloatArray = field(default_factory=lambda: np.zeros(N_WS))
    servo_p: FloatArray = field(default_factory=lambda: np.zeros((N_PITCH, 1)))
    servo_s: FloatArray = field(default_factory=lambda: np.zeros(1))
    dryden: FloatArray = field(default_factory=lambda: np.zeros(1))


@dataclass
class WorldModel:
    """A configured world's arrays for one plant; ``step`` is :func:`world_plant_step`.

    ``design`` is the controller's airframe; the plant flies ``airframe`` (the mismatched
    one). Servo arrays are built for the sub-step of the first ``step`` call (and rebuilt,
    positions kept, if a caller changes its step)."""

    world: World
    airframe: Airframe
    constants: PlantConstants
    air: AirConstants
    wp: FloatArray
    ws: FloatArray
    dryden: FloatArray
    servo_p: FloatArray
    servo_s: FloatArray
    x0: FloatArray
    h_s: float = 0.0
    rotor: RotorConstants = rotor.OFF

    @classmethod
    def build(
        cls, world: World, design: Airframe, x0: FloatArray, rotor_plant: RotorPlant | None = None,
        rotor_state0: FloatArray | None = None,
    ) -> WorldModel:  # fmt: skip
        """The world's arrays about the plant: the paper's on ``design`` (mismatch applied),
        or the rotor plant on its own airframe (mismatch applied) starting from
        ``rotor_state0`` (layout :data:`heli_plant.rotor.ROTOR_STATE`)."""
        base = design if rotor_plant is None else rotor_plant.airframe()
        af = world.mismatch.apply(base, Path(world.source).parent if world.source else None)
        c = af.constants()
        ar = world.air
        a = AirConstants(
            fuselage=ar.fuselage, inflow=ar.rotor_inflow, rho=af.air.density_kg_m3,
            s_x=ar.fuselage_areas_m2[0], s_y=ar.fuselage_areas_m2[1], s_z=ar.fuselage_areas_m2[2],
            tip_speed_main=af.main_rotor.speed_rad_s * af.main_rotor.radius_m,
            tip_speed_tail=af.tail_rotor.speed_rad_s * af.tail_rotor.radius_m,
            wake_factor=ar.wake_factor,
        )  # fmt: skip
        wp = world_parameters(world)
        ws = np.zeros(N_WS)
        # the inflow solver's first guesses: about the hover inflow (it converges from anywhere)
        ws[WS_LAM_MAIN] = ws[WS_LAM_TAIL] = 0.05
        g = rotor.OFF
        if rotor_plant is not None:
            g = rotor.rotor_constants(rotor_plant, af)
            if rotor_state0 is None:
                raise ValueError("the rotor plant needs its initial rotor state")
            ws[WS_ROTOR : WS_ROTOR + N_ROTOR] = rotor_state0
            ws[WS_THROTTLE] = min(max(g.ki * rotor_state0[rotor.GOV_INT], 0.0), 1.0)  # at its set speed
            ws[WS_GOVERNOR_SET] = g.omega_c
        return cls(world, af, c, a, wp, ws, np.zeros(wind.N_DRYDEN_COEFFS), np.zeros((N_PITCH, 1)),
                   np.zeros(1), np.asarray(x0, dtype=float), rotor=g)  # fmt: skip

    def _dryden(self, h_s: float) -> None:
        """Dryden coefficients for step ``h_s``: scale lengths and intensities at the
        configured height (or the initial one), convected at max(|V - W_mean|, 1 m/s)."""
        t = self.world.turbulence
        if t.w20_m_s <= 0.0:
            return
        height = t.altitude_m if t.altitude_m > 0.0 else float(self.x0[2])
        lu, lv, lw, su, sv, sw = wind.dryden_low_altitude(max(height, wind.H_MIN_M), t.w20_m_s)
        rt = rot_body_to_earth(self.x0[PHI], self.x0[THETA], self.x0[PSI])
        v_earth = rt @ self.x0[U_F : W_U + 1]
        v_conv = max(float(np.linalg.norm(v_earth - self.wp[WP_WIND : WP_WIND + 3])), 1.0)
        self.dryden = wind.dryden_coefficients(lu, lv, lw, su, sv, sw, v_conv, h_s)
        if self.h_s == 0.0:  # the first build: a stationary start
            turb = self.ws[WS_TURB : WS_TURB + wind.N_DRYDEN_STATE]
            wind.dryden_init(self.dryden, turb, self.world.seed)

    def _servos(self, h_s: float, u0: FloatArray, limits: FloatArray) -> None:
        self.servo_p = servos.servo_table(self.world.servos, limits, h_s)
        held = self.ws[WS_PITCH : WS_PITCH + N_PITCH] if self.h_s else np.clip(u0, limits[:, 0], limits[:, 1])
        self.servo_s = servos.servo_state(self.servo_p, np.array(held))

    def update(self, world: World, limits: FloatArray) -> None:
        """Take new settings (live knobs) from the next step on: wind, gust, turbulence
        intensity and servos; the turbulence filters keep their state (the process stays
        continuous), the servos restart from where they are. Mismatch and air switches
        are fixed for a run."""
        old = self.world
        self.world = world
        self.wp = world_parameters(world)
        if self.h_s == 0.0:
            return  # not stepped yet: prepare() builds the rest
        if world.turbulence != old.turbulence or world.wind != old.wind:
            self._dryden(self.h_s)
        if world.servos != old.servos and world.servos.on:
            u = self.ws[WS_PITCH : WS_PITCH + N_PITCH].copy()
            h, self.h_s = self.h_s, 0.0  # rebuilt at rest where the servos are now
            self._servos(h, u, limits)
            self.h_s = h

    def prepare(self, h_s: float, u0: FloatArray, limits: FloatArray) -> None:
        """Arrays for sub-step ``h_s`` (the first call, or a changed step)."""
        if h_s == self.h_s:
            return
        self._dryden(h_s)
        if self.world.servos.on:
            self._servos(h_s, u0, limits)
        self.h_s = h_s

    @property
    def air_nwu_m_s(self) -> FloatArray:
        return self.ws[WS_AIR : WS_AIR + 3].copy()

    @property
    def pitches_rad(self) -> FloatArray:
        return self.ws[WS_PITCH : WS_PITCH + N_PITCH].copy()



    @property
    def rotor_truth(self) -> list[float]:
        """What the plant reports of its rotor: a1, b1 [rad], rotor speed [rad/s], throttle."""
        r = self.ws[WS_ROTOR : WS_ROTOR + N_ROTOR]
        return [float(r[rotor.A1]), float(r[rotor.B1]), float(r[rotor.OMEGA_R]), float(self.ws[WS_THROTTLE])]

    @property
    def rotor_state(self) -> FloatArray:
        """The rotor plant's states now (layout :data:`heli_plant.rotor.ROTOR_STATE`)."""
        return self.ws[WS_ROTOR : WS_ROTOR + N_ROTOR].copy()
