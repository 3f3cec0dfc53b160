"""The cascaded PID baseline, built as ArduPilot's helicopter stack (AC_PosControl over
AC_AttitudeControl_Heli): position P -> velocity PI (the trajectory's velocity and
acceleration as feed-forward; the vertical channel sets the collective's thrust) -> thrust
vector with a tilt limit -> attitude set point plus the hover roll trim (ATC_HOVR_ROL_TRM)
-> attitude P (the path's yaw rate as feed-forward) -> body-rate PID with the set point's
feed-forward (RAT_*_FF; derivative on the filtered measurement, clamped integrators frozen
while an output saturates) -> torque -> the four blade pitches through the inverse rotor maps
of the spec, the very allocation the TLC uses (autopilot/tlc/allocation.py, inversion.py).

Same contract as the TLC: ``update(t, state, reference) -> pitches``, no I/O, no clock; the
whole law is one compiled kernel (:func:`pid_kernel`) over a flat state with named offsets.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from autopilot.control import (
    BAD_INPUT,
    BAD_OUTPUT,
    Kernel,
    KernelController,
    all_finite,
    commit,
    refuse,
    register_law,
)
from autopilot.pid.gains import PidGains
from autopilot.reference import ACC_0 as REF_ACC
from autopilot.reference import POS_0 as REF_POS
from autopilot.reference import VEL_0 as REF_VEL
from autopilot.tlc.allocation import allocate
from autopilot.tlc.inversion import force_to_thrust_attitude, limit_tilt, yaw_rate_command
from heli_common.jit import njit
from heli_common.kinematics import cross, euler_rate_matrix, mat_t_vec, mat_vec, rot_body_to_earth, wrap_pi
from heli_common.layout import Layout
from heli_common.state import EULER, N_PITCH, OMEGA, POS, VEL, FloatArray
from heli_common.vehicle.airframe import Airframe, PlantConstants

# controller state layout
PID_STATE = Layout(
    "PID state",
    ("i_vel", 3),  # velocity-error integral, earth NWU
    ("i_rate", 3),  # body-rate-error integral
    ("d_rate", 3),  # filtered derivative of the measured body rates
    ("last_rate", 3),  # the previous measured body rates
    ("psi_c", 1),  # yaw command
    ("started", 1),  # 0 until the first update initialised the filters
    ("last_u", N_PITCH),  # last valid output
)
P_I_VEL = PID_STATE.offset("i_vel")
P_I_RATE = PID_STATE.offset("i_rate")
P_D_RATE = PID_STATE.offset("d_rate")
P_LAST_RATE = PID_STATE.offset("last_rate")
P_PSI_C = PID_STATE.offset("psi_c")
P_STARTED = PID_STATE.offset("started")
P_LAST_U = PID_STATE.offset("last_u")
N_PID_STATE = PID_STATE.size


class PIDConstants(NamedTuple):
    plant: PlantConstants
    limits: FloatArray  # (4, 2) pitch limits [rad]
    j: FloatArray  # (3, 3) inertia
    dt_s: float
    kp_pos: FloatArray  # (3,)
    max_speed: float
    kp_vel: FloatArray
    ki_vel: FloatArray
    i_max_vel: float
    accel_max_z: float
    kp_att: FloatArray
    max_rate: FloatArray
    hover_roll_trim_rad: float
    kp_rate: FloatArray
    ki_rate: FloatArray
    kd_rate: FloatArray
    ff_rate: FloatArray
    d_alpha: float  # derivative filter: first order at d_filter_hz, discretised
    i_max_rate: float
    tilt_max_rad: float
    yaw_hold_speed_m_s: float


def make_pid_constants(airframe: Airframe, gains: PidGains, rate_hz: float) -> PIDConstants:
    if not 50.0 <= rate_hz <= 1000.0:
        raise ValueError(f"control rate must be in [50, 1000] Hz, got {rate_hz}")
    c = airframe.constants()
    dt = 1.0 / rate_hz
    tau_d = 1.0 / (2.0 * math.pi * gains.rate.d_filter_hz)
    a = np.asarray
    return PIDConstants(
        plant=c, limits=a(airframe.limits.as_tuple(), dtype=float),
        j=a([[c.ixx, 0.0, -c.ixz], [0.0, c.iyy, 0.0], [-c.ixz, 0.0, c.izz]]), dt_s=dt,
        kp_pos=a(gains.position.kp, dtype=float), max_speed=gains.position.max_speed_m_s,
        kp_vel=a(gains.velocity.kp, dtype=float), ki_vel=a(gains.velocity.ki, dtype=float),
        i_max_vel=gains.velocity.i_max_m_s2, accel_max_z=gains.velocity.accel_max_z_m_s2,
        kp_att=a(gains.attitude.kp, dtype=float),
        max_rate=a(gains.attitude.max_rate_rad_s, dtype=float),
        hover_roll_trim_rad=gains.attitude.hover_roll_trim_rad, kp_rate=a(gains.rate.kp, dtype=float),
        ki_rate=a(gains.rate.ki, dtype=float), kd_rate=a(gains.rate.kd, dtype=float),
        ff_rate=a(gains.rate.ff, dtype=float),
        d_alpha=dt / (tau_d + dt), i_max_rate=gains.rate.i_max_rad_s2,
        tilt_max_rad=gains.limits.tilt_max_rad, yaw_hold_speed_m_s=gains.limits.yaw_hold_speed_m_s,
    )  # fmt: skip


@njit
def _or0(v: float) -> float:
    return v if math.isfinite(v) else 0.0


@njit
def rate_loop(k: PIDConstants, s: FloatArray, om: FloatArray, wc: FloatArray, first: bool) -> FloatArray:
    """Body-rate PID with feed-forward: the angular acceleration command for rate set point
    ``wc`` and measured rates ``om`` (integrators are advanced by the caller, who knows
    saturation). The feed-forward ``ff wc`` acts outside the loop: a rotor whose cyclic sets a
    rate gets the command that holds ``wc`` at once, not after the integrator has wound."""
    if first:
        s[P_LAST_RATE : P_LAST_RATE + 3] = om
        s[P_D_RATE : P_D_RATE + 3] = 0.0
    alpha = np.empty(3)
    for i in range(3):
        raw = (om[i] - s[P_LAST_RATE + i]) / k.dt_s
        s[P_D_RATE + i] += k.d_alpha * (raw - s[P_D_RATE + i])
        e = wc[i] - om[i]
        alpha[i] = (k.ff_rate[i] * wc[i] + k.kp_rate[i] * e + k.ki_rate[i] * s[P_I_RATE + i]
                    - k.kd_rate[i] * s[P_D_RATE + i])  # fmt: skip
    s[P_LAST_RATE : P_LAST_RATE + 3] = om
    return alpha


@njit
def pid_kernel(
    k: PIDConstants, st: FloatArray, x: FloatArray, ref: FloatArray, hold_integrators: bool,
    out: FloatArray, diag: FloatArray,
) -> int:  # fmt: skip
    """One control tick (the TLC kernel's contract): pitches into ``out``, diagnostics into
    ``diag`` (same layout as the TLC's), a status code returned; ``st`` changes only when
    the command is finite."""
    c = k.plant
    mg = c.mass_kg * c.gravity_m_s2
    if not (all_finite(x) and all_finite(ref[REF_POS : REF_POS + 3])):
        return refuse(st, P_LAST_U, out, diag, BAD_INPUT)
    s = st.copy()
    dt = k.dt_s
    pos, vel, gam, om = x[POS], x[VEL], x[EULER], x[OMEGA]
    first = s[P_STARTED] == 0.0
    vr = np.empty(3)
    ar = np.empty(3)
    for i in range(3):
        vr[i] = _or0(ref[REF_VEL + i])
        ar[i] = _or0(ref[REF_ACC + i])
    if first:
        s[:] = 0.0
        s[P_PSI_C] = math.atan2(vr[1], vr[0]) if math.hypot(vr[0], vr[1]) > k.yaw_hold_speed_m_s else gam[2]

    # --- position P -> velocity set point (trajectory velocity as feed-forward); the
    # correction's horizontal speed limited, the trajectory's own speed not: the TLC's
    # limit (TLC_MAX_SPEED), so that both contenders fly under the same command limits
    fb = k.kp_pos * (ref[REF_POS : REF_POS + 3] - pos)
    h = math.hypot(fb[0], fb[1])
    if h > k.max_speed:
        fb[0] *= k.max_speed / h
        fb[1] *= k.max_speed / h
    vsp = vr + fb
    # --- velocity PI (earth) -> acceleration set point (trajectory acceleration as feed-forward)
    rt = rot_body_to_earth(gam[0], gam[1], gam[2])
    ve = vsp - mat_vec(rt, vel)
    asp = ar + k.kp_vel * ve + k.ki_vel * s[P_I_VEL : P_I_VEL + 3]
    z_limited = abs(asp[2]) > k.accel_max_z
    asp[2] = min(max(asp[2], -k.accel_max_z), k.accel_max_z)
    # --- thrust vector with a tilt limit -> thrust and roll/pitch set point (the TLC's inversion)
    fc = c.mass_kg * mat_t_vec(rt, asp)
    tilt_limited = limit_tilt(fc, mg, k.tilt_max_rad)
    tm, phi_c, theta_c = force_to_thrust_attitude(fc, mg)
    # the bank that holds the tail rotor's side force, which the force model above leaves out
    phi_c += k.hover_roll_trim_rad
    # --- yaw set point: nose along the path, as the TLC
    dpsi_c = yaw_rate_command(vr[0], vr[1], ar[0], ar[1], k.yaw_hold_speed_m_s)
    # --- attitude P -> body-rate set point (yaw rate feed-forward), limited
    ge = np.empty(3)
    ge[0], ge[1], ge[2] = phi_c - gam[0], theta_c - gam[1], wrap_pi(s[P_PSI_C] - gam[2])
    de = k.kp_att * ge
    de[2] += dpsi_c
    wc = mat_vec(euler_rate_matrix(gam[0], gam[1]), de)
    for i in range(3):
        wc[i] = min(max(wc[i], -k.max_rate[i]), k.max_rate[i])
    # --- body-rate PID with the set point's feed-forward -> torque (rigid-body omega x J omega)
    alpha = rate_loop(k, s, om, wc, first)
    qc = mat_vec(k.j, alpha) + cross(om, mat_vec(k.j, om))

    # --- allocation with saturation (the TLC's)
    u, tm, sat_mask = allocate(qc, tm, c, k.limits)
    if not all_finite(u) or not all_finite(s):
        return refuse(st, P_LAST_U, out, diag, BAD_OUTPUT)

    # --- integrators: frozen while an output saturates (velocity also while tilt-limited), clamped
    saturated = sat_mask != 0
    if not hold_integrators:
        if not (saturated or tilt_limited):
            for i in range(3):
                if i == 2 and z_limited:
                    continue
                v = s[P_I_VEL + i] + dt * ve[i]
                lim_v = k.i_max_vel / max(k.ki_vel[i], 1e-9)
                s[P_I_VEL + i] = min(max(v, -lim_v), lim_v)
        if not saturated:
            for i in range(3):
                v = s[P_I_RATE + i] + dt * (wc[i] - om[i])
                lim_r = k.i_max_rate / max(k.ki_rate[i], 1e-9)
                s[P_I_RATE + i] = min(max(v, -lim_r), lim_r)
    s[P_PSI_C] += dt * dpsi_c
    s[P_STARTED] = 1.0
    return commit(st, s, P_LAST_U, u, out, diag, phi_c, theta_c, s[P_PSI_C], tm, sat_mask, tilt_limited)


class PIDController(KernelController[PidGains]):
    """The cascaded PID baseline with its state; one ``update`` per control tick."""

    kind = "pid"
    n_state = N_PID_STATE

    def _make_constants(self) -> PIDConstants:
        return make_pid_constants(self.airframe, self.gains, self.rate_hz)

    @staticmethod
    def kernel() -> Kernel:
        return pid_kernel  # type: ignore[no-any-return]


register_law(PIDConstants, pid_kernel)  # the compiled loop's dispatch (autopilot.control.control_law)
