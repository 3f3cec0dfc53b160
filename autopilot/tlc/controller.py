"""The TLC controller: ``update(t, state, reference) -> pitches``. No I/O, no clock.

The whole law is one compiled kernel (:func:`tlc_kernel`) over a flat state vector with
named offsets; :class:`TLController` owns that vector and the constants. The caller owns
time and must call ``update`` once per control period (zero-order hold on the output).
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

import numpy as np

from autopilot.control import (
    BAD_INPUT,
    BAD_OUTPUT,
    D_PHI_C,
    D_PSI_C,
    D_SAT_MASK,
    D_STATUS,
    D_THETA_C,
    D_TILT_LIMITED,
    D_TM,
    N_DIAG,
    OK,
    Kernel,
    KernelController,
    all_finite,
    commit,
    refuse,
)
from autopilot.reference import ACC_0 as REF_ACC
from autopilot.reference import POS_0 as REF_POS
from autopilot.reference import VEL_0 as REF_VEL
from autopilot.tlc.allocation import allocate, collective_tail_tilt
from autopilot.tlc.differentiator import DiffCoeffs, diff_reset, diff_step, discretize
from autopilot.tlc.gains import Gains
from autopilot.tlc.inversion import force_to_thrust_attitude, limit_tilt, yaw_rate_command
from autopilot.tlc.loops import a3_matrix, a4_times
from autopilot.tlc.rotor_aware import (
    SERVO_STATE_SIZE,
    RotorAwareConstants,
    command_filter,
    flapping_inversion,
    observe_flapping,
    rotor_aware_constants,
)
from heli_common.airframe import Airframe, PlantConstants
from heli_common.jit import njit
from heli_common.kinematics import cross, euler_rate_matrix, mat_t_vec, mat_vec, rot_body_to_earth, wrap_pi
from heli_common.layout import Layout
from heli_common.state import EULER, N_PITCH, OMEGA, POS, VEL, FloatArray

# reference vector (earth NWU): commanded position and, where known, its derivatives

# controller state layout: the paper's TLC, then what the rotor-aware TLC adds (unused by
# the paper's, which never reads or writes past its own blocks)
STATE = Layout(
    "TLC state",
    ("i1", 3), ("i2", 3), ("i3", 3), ("i4", 3),  # error integrals of loops 1-4
    ("d_pos", 6),  # pseudo-differentiator of Pc (x1[3], x2[3]), feedforward "pseudo" only
    ("d_a", 6),  # of a = Rt Vc (loop 2, earth frame)
    ("d_gamma", 6),  # of gamma_c
    ("d_omega", 6),  # of omega_c
    ("psi_c", 1),  # yaw command integral
    ("started", 1),  # 0 until the first update initialised the filters
    ("last_u", N_PITCH),  # last valid output
    ("sent", N_PITCH),  # rotor-aware: the command filter's last command sent
    ("flap_hat", 2),  # rotor-aware: the flapping observer's a1^, b1^
    ("d_flap", 6),  # rotor-aware: pseudo-differentiator of (a1_c, b1_c, 0)
    ("servo", SERVO_STATE_SIZE),  # rotor-aware: the command filter's servo model
)  # fmt: skip
S_I1, S_I2, S_I3, S_I4 = (STATE.offset(n) for n in ("i1", "i2", "i3", "i4"))
S_D_POS, S_D_A, S_D_GAMMA, S_D_OMEGA = (STATE.offset(n) for n in ("d_pos", "d_a", "d_gamma", "d_omega"))
S_PSI_C = STATE.offset("psi_c")
S_STARTED = STATE.offset("started")
S_LAST_U = STATE.offset("last_u")
S_SENT = STATE.offset("sent")
S_FLAP_HAT = STATE.offset("flap_hat")
S_D_FLAP = STATE.offset("d_flap")
S_SERVO = STATE.offset("servo")
N_CTRL_STATE = STATE.size


class Feedforward(enum.Enum):
    PSEUDO = "pseudo"  # pseudo-differentiators everywhere, as the paper
    EXACT = "exact"  # trajectory derivatives for dPc/dt and the yaw augmentation


class TLCConstants(NamedTuple):
    plant: PlantConstants  # the design model uses the same airframe numbers
    w2: FloatArray  # (4, 3) omega^2 per loop and channel
    zw2: FloatArray  # (4, 3) 2 zeta omega
    limits: FloatArray  # (4, 2) pitch limits [rad]: theta_m, theta_t, eps, eta
    j: FloatArray  # (3, 3) inertia
    j_inv: FloatArray
    diff: DiffCoeffs
    dt_s: float
    tilt_max_rad: float
    yaw_hold_speed_m_s: float
    max_speed_m_s: float  # loop 1's horizontal speed command limit (0: none)
    exact_ff: bool
    rotor: RotorAwareConstants  # loop 5 and the command filter (``on`` False: the paper's TLC)


def make_constants(airframe: Airframe, gains: Gains, rate_hz: float, ff: Feedforward) -> TLCConstants:
    if not 50.0 <= rate_hz <= 1000.0:
        raise ValueError(f"control rate must be in [50, 1000] Hz, got {rate_hz}")
    c = airframe.constants()
    loops = gains.loops()
    w = np.array([lg.omega_rad_s for lg in loops], dtype=float)
    z = np.array([lg.zeta for lg in loops], dtype=float)
    j = np.array([[c.ixx, 0.0, -c.ixz], [0.0, c.iyy, 0.0], [-c.ixz, 0.0, c.izz]])
    dt = 1.0 / rate_hz
    return TLCConstants(
        plant=c,
        w2=w**2,
        zw2=2.0 * z * w,
        limits=np.array(airframe.limits.as_tuple(), dtype=float),
        j=j,
        j_inv=np.linalg.inv(j),
        diff=discretize(gains.differentiator.omega_rad_s, gains.differentiator.zeta, dt),
        dt_s=dt,
        tilt_max_rad=gains.limits.tilt_max_rad,
        yaw_hold_speed_m_s=gains.limits.yaw_hold_speed_m_s,
        max_speed_m_s=gains.limits.max_speed_m_s,
        exact_ff=ff is Feedforward.EXACT,
        rotor=rotor_aware_constants(gains.rotor, airframe, dt),
    )


@njit
def flapping_loop(
    k: TLCConstants, s: FloatArray, om: FloatArray, wc: FloatArray, qc: FloatArray, tm: float, first: bool
) -> tuple[FloatArray, float, int]:
    """The rotor-aware TLC's allocation: torque ``qc`` and thrust ``tm`` -> collective, tail and
    the disc's tilt (with the hub spring), loop 5 -> cyclic, the command filter -> the pitches
    to send; the observer then takes what the servos achieved. Returns (pitches, thrust,
    mask of the channels clipped at a position limit)."""
    r = k.rotor
    tilt, tm, mask = collective_tail_tilt(qc, tm, k.plant, k.limits, r.k_hub_n_m)
    # nominal rates (loop 3's command) in the inversion: the rotor's own rate damping then
    # acts on the rate error, as the paper's nominal-plus-regulator split intends
    eps, eta = flapping_inversion(r, s, S_D_FLAP, S_FLAP_HAT, tilt[2:4], wc[0], wc[1], first)
    desired = tilt.copy()
    desired[2], desired[3] = eps, eta
    achieved = np.empty(N_PITCH)
    u, clipped, _slowed = command_filter(r, s, S_SENT, S_SERVO, desired, k.limits, first, achieved)
    observe_flapping(r, s, S_FLAP_HAT, achieved, om[0], om[1])
    return u, tm, mask | clipped


@njit
def tlc_kernel(
    k: TLCConstants,
    st: FloatArray,
    x: FloatArray,
    ref: FloatArray,
    hold_integrators: bool,
    out: FloatArray,
    diag: FloatArray,
) -> int:
    """One control tick. Reads the measured state ``x`` and reference ``ref``, writes the four
    pitches to ``out`` and diagnostics to ``diag``; returns a status code.

    ``st`` is updated only when the tick produced a finite command; otherwise ``out`` holds
    the last valid command (zero pitch before the first) and ``st`` is untouched.
    """
    c = k.plant
    mg = c.mass_kg * c.gravity_m_s2
    if not (all_finite(x) and all_finite(ref[REF_POS : REF_POS + 3])):
        return refuse(st, S_LAST_U, out, diag, BAD_INPUT)
    s = st.copy()
    dt = k.dt_s
    pos, vel, gam, om = x[POS], x[VEL], x[EULER], x[OMEGA]
    pc = ref[REF_POS : REF_POS + 3]
    first = s[S_STARTED] == 0.0
    if first:
        s[0:12] = 0.0
        diff_reset(s, S_D_POS, pc)
        vx0, vy0 = ref[REF_VEL], ref[REF_VEL + 1]
        if math.isfinite(vx0) and math.isfinite(vy0) and math.hypot(vx0, vy0) > k.yaw_hold_speed_m_s:
            s[S_PSI_C] = math.atan2(vy0, vx0)  # initial path tangent
        else:
            s[S_PSI_C] = gam[2]

    # the differentiators' outputs: rows of one array (one allocation, not six, a tick)
    rates = np.empty((6, 3))
    dpc, d2pc, da, unused, dgc, dwc = rates[0], rates[1], rates[2], rates[3], rates[4], rates[5]

    # --- loop 1: position kinematics -> earth-frame velocity command a = Rt Vc
    diff_step(s, S_D_POS, pc, k.diff, dpc, d2pc)
    if k.exact_ff:
        dpc[:] = ref[REF_VEL : REF_VEL + 3]
        d2pc[:] = ref[REF_ACC : REF_ACC + 3]
    pe = pc - pos
    speed_limited = False
    if k.max_speed_m_s > 0.0:  # the correction's horizontal speed held (the trajectory's is not)
        fb = k.w2[0] * s[S_I1 : S_I1 + 3] + k.zw2[0] * pe
        h = math.hypot(fb[0], fb[1])
        if h > k.max_speed_m_s:
            fb[0] *= k.max_speed_m_s / h
            fb[1] *= k.max_speed_m_s / h
            speed_limited = True
        a = dpc + fb
    else:
        a = dpc + k.w2[0] * s[S_I1 : S_I1 + 3] + k.zw2[0] * pe
    rt = rot_body_to_earth(gam[0], gam[1], gam[2])
    vc = mat_t_vec(rt, a)

    # --- loop 2: position dynamics (dVc/dt differentiated in the earth frame)
    ve = vc - vel
    if first:
        diff_reset(s, S_D_A, a)
    diff_step(s, S_D_A, a, k.diff, da, unused)
    fc = c.mass_kg * mat_t_vec(rt, da) + c.mass_kg * (
        k.w2[1] * s[S_I2 : S_I2 + 3] + k.zw2[1] * ve - cross(om, ve)
    )
    tilt_limited = limit_tilt(fc, mg, k.tilt_max_rad)
    tm, phi_c, theta_c = force_to_thrust_attitude(fc, mg)

    # --- yaw augmentation: nose along the path tangent
    dpsi_c = yaw_rate_command(dpc[0], dpc[1], d2pc[0], d2pc[1], k.yaw_hold_speed_m_s)
    gc = np.empty(3)
    gc[0], gc[1], gc[2] = phi_c, theta_c, s[S_PSI_C]

    # --- loop 3: attitude kinematics -> body-rate command
    ge = gc - gam
    ge[2] = wrap_pi(ge[2])
    if first:
        diff_reset(s, S_D_GAMMA, gc)
    diff_step(s, S_D_GAMMA, gc, k.diff, dgc, unused)
    ec = euler_rate_matrix(gc[0], gc[1])
    a3 = a3_matrix(gc[0], gc[1], om[0], om[1], om[2])
    wc = mat_vec(ec, dgc + k.w2[2] * s[S_I3 : S_I3 + 3] + k.zw2[2] * ge + mat_vec(a3, ge))

    # --- loop 4: attitude dynamics -> torque command
    we = wc - om
    if first:
        diff_reset(s, S_D_OMEGA, wc)
    diff_step(s, S_D_OMEGA, wc, k.diff, dwc, unused)
    qc = mat_vec(k.j, dwc) + cross(wc, mat_vec(k.j, wc)) + mat_vec(
        k.j, k.w2[3] * s[S_I4 : S_I4 + 3] + k.zw2[3] * we + a4_times(wc, k.j, k.j_inv, we)
    )

    # --- allocation with saturation (the rotor-aware TLC: to the disc's tilt, then loop 5)
    if k.rotor.on:
        u, tm, sat_mask = flapping_loop(k, s, om, wc, qc, tm, first)
    else:
        u, tm, sat_mask = allocate(qc, tm, c, k.limits)
    if not all_finite(u) or not all_finite(s):
        return refuse(st, S_LAST_U, out, diag, BAD_OUTPUT)

    # --- integrators: conditional integration (frozen while any output saturates)
    saturated = sat_mask != 0
    if not hold_integrators:
        if not (saturated or tilt_limited):
            if not speed_limited:
                s[S_I1 : S_I1 + 3] += dt * pe
            s[S_I2 : S_I2 + 3] += dt * ve
        if not saturated:
            s[S_I3 : S_I3 + 3] += dt * ge
            s[S_I4 : S_I4 + 3] += dt * we
    s[S_PSI_C] += dt * dpsi_c
    s[S_STARTED] = 1.0
    return commit(st, s, S_LAST_U, u, out, diag, gc[0], gc[1], gc[2], tm, sat_mask, tilt_limited)


class TLController(KernelController[Gains]):
    """The trajectory linearization controller with its state; one ``update`` per control tick."""

    kind = "tlc"
    n_state = N_CTRL_STATE

    def __init__(
        self,
        airframe: Airframe,
        gains: Gains,
        rate_hz: float = 100.0,
        feedforward: Feedforward | str = Feedforward.PSEUDO,
    ) -> None:
        self.feedforward = Feedforward(feedforward)
        super().__init__(airframe, gains, rate_hz)

    def _make_constants(self) -> TLCConstants:
        return make_constants(self.airframe, self.gains, self.rate_hz, self.feedforward)

    @staticmethod
    def kernel() -> Kernel:
        return tlc_kernel  # type: ignore[no-any-return]


__all__ = ["BAD_INPUT", "BAD_OUTPUT", "D_PHI_C", "D_PSI_C", "D_SAT_MASK", "D_STATUS", "D_THETA_C",
           "D_TILT_LIMITED", "D_TM", "N_DIAG", "OK", "Feedforward", "TLController", "tlc_kernel"]  # fmt: skip
