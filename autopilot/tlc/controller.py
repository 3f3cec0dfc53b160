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
    register_law,
)
from autopilot.reference import ACC_0 as REF_ACC
from autopilot.reference import POS_0 as REF_POS
from autopilot.reference import VEL_0 as REF_VEL
from autopilot.tlc.allocation import allocate3, collective_tail_tilt
from autopilot.tlc.differentiator import DiffCoeffs, diff_channel, diff_reset3, discretize
from autopilot.tlc.gains import Gains
from autopilot.tlc.inversion import force_to_thrust_attitude3, limit_tilt2, yaw_rate_command
from autopilot.tlc.loops import a3_times, a4_times3, cross3, euler_rate_times, mat_vec3, rot3
from autopilot.tlc.rotor_aware import (
    SERVO_STATE_SIZE,
    RotorAwareConstants,
    command_filter,
    correct_flapping,
    flapping_inversion,
    observe_flapping,
    predict_rates_and_flapping,
    rotor_aware_constants,
)
from heli_common.jit import njit
from heli_common.kinematics import wrap_pi
from heli_common.layout import Layout
from heli_common.state import (
    N_PITCH,
    OMEGA,
    P_X,
    PHI,
    PSI,
    Q_Y,
    R_Z,
    THETA,
    U_F,
    V_L,
    W_U,
    X_N,
    Y_W,
    Z_U,
    FloatArray,
)
from heli_common.vehicle.airframe import Airframe, PlantConstants

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
    ("rate_hat", 2),  # rotor-aware, rate-corrected observer: its estimate of p, q
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
S_RATE_HAT = STATE.offset("rate_hat")
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
    if r.correct:  # the flapping estimate corrected from the gyro before loop 5 reads it
        correct_flapping(r, s, S_FLAP_HAT, S_RATE_HAT, om[0], om[1], first)
    # nominal rates (loop 3's command) in the inversion: the rotor's own rate damping then
    # acts on the rate error, as the paper's nominal-plus-regulator split intends
    eps, eta = flapping_inversion(r, s, S_D_FLAP, S_FLAP_HAT, tilt[2:4], wc[0], wc[1], first)
    desired = tilt.copy()
    desired[2], desired[3] = eps, eta
    achieved = np.empty(N_PITCH)
    u, clipped, _slowed = command_filter(r, s, S_SENT, S_SERVO, desired, k.limits, first, achieved)
    if r.correct:
        predict_rates_and_flapping(r, k.plant, k.j, k.j_inv, s, S_FLAP_HAT, S_RATE_HAT, achieved, om[2])
    else:
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

    The law's vectors are values, not arrays (``*3`` helpers: the same arithmetic,
    operation for operation, as the array forms the tests check): a tick makes two arrays,
    the working copy of the state and the pitches, instead of some sixty temporaries at
    ~15 ns each.
    """
    c = k.plant
    mg = c.mass_kg * c.gravity_m_s2
    if not (all_finite(x) and _finite3(ref, REF_POS)):
        return refuse(st, S_LAST_U, out, diag, BAD_INPUT)
    s = st.copy()
    dt = k.dt_s
    w2, zw2, d = k.w2, k.zw2, k.diff
    pos = (x[X_N], x[Y_W], x[Z_U])
    vel = (x[U_F], x[V_L], x[W_U])
    gam = (x[PHI], x[THETA], x[PSI])
    om = (x[P_X], x[Q_Y], x[R_Z])
    pc = (ref[REF_POS], ref[REF_POS + 1], ref[REF_POS + 2])
    first = s[S_STARTED] == 0.0
    if first:
        for i in range(12):
            s[i] = 0.0
        diff_reset3(s, S_D_POS, pc[0], pc[1], pc[2])
        vx0, vy0 = ref[REF_VEL], ref[REF_VEL + 1]
        if math.isfinite(vx0) and math.isfinite(vy0) and math.hypot(vx0, vy0) > k.yaw_hold_speed_m_s:
            s[S_PSI_C] = math.atan2(vy0, vx0)  # initial path tangent
        else:
            s[S_PSI_C] = gam[2]

    # --- loop 1: position kinematics -> earth-frame velocity command a = Rt Vc
    dpc0, d2pc0 = diff_channel(s, S_D_POS, 0, pc[0], d)
    dpc1, d2pc1 = diff_channel(s, S_D_POS, 1, pc[1], d)
    dpc2, _ = diff_channel(s, S_D_POS, 2, pc[2], d)  # the yaw needs no vertical d2
    if k.exact_ff:
        dpc0, dpc1, dpc2 = ref[REF_VEL], ref[REF_VEL + 1], ref[REF_VEL + 2]
        d2pc0, d2pc1 = ref[REF_ACC], ref[REF_ACC + 1]
    pe = (pc[0] - pos[0], pc[1] - pos[1], pc[2] - pos[2])
    i1 = (s[S_I1], s[S_I1 + 1], s[S_I1 + 2])
    speed_limited = False
    if k.max_speed_m_s > 0.0:  # the correction's horizontal speed held (the trajectory's is not)
        fb0 = w2[0, 0] * i1[0] + zw2[0, 0] * pe[0]
        fb1 = w2[0, 1] * i1[1] + zw2[0, 1] * pe[1]
        fb2 = w2[0, 2] * i1[2] + zw2[0, 2] * pe[2]
        h = math.hypot(fb0, fb1)
        if h > k.max_speed_m_s:
            fb0 *= k.max_speed_m_s / h
            fb1 *= k.max_speed_m_s / h
            speed_limited = True
        a = (dpc0 + fb0, dpc1 + fb1, dpc2 + fb2)
    else:
        a = (dpc0 + w2[0, 0] * i1[0] + zw2[0, 0] * pe[0], dpc1 + w2[0, 1] * i1[1] + zw2[0, 1] * pe[1],
             dpc2 + w2[0, 2] * i1[2] + zw2[0, 2] * pe[2])  # fmt: skip
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot3(gam[0], gam[1], gam[2])
    # Vc = Rt^T a
    vc = (r00 * a[0] + r10 * a[1] + r20 * a[2], r01 * a[0] + r11 * a[1] + r21 * a[2],
          r02 * a[0] + r12 * a[1] + r22 * a[2])  # fmt: skip

    # --- loop 2: position dynamics (dVc/dt differentiated in the earth frame)
    ve = (vc[0] - vel[0], vc[1] - vel[1], vc[2] - vel[2])
    if first:
        diff_reset3(s, S_D_A, a[0], a[1], a[2])
    da0, _ = diff_channel(s, S_D_A, 0, a[0], d)
    da1, _ = diff_channel(s, S_D_A, 1, a[1], d)
    da2, _ = diff_channel(s, S_D_A, 2, a[2], d)
    m = c.mass_kg
    oxv = cross3(om, ve)
    fx = m * (r00 * da0 + r10 * da1 + r20 * da2) + m * (w2[1, 0] * s[S_I2] + zw2[1, 0] * ve[0] - oxv[0])
    fy = m * (r01 * da0 + r11 * da1 + r21 * da2) + m * (w2[1, 1] * s[S_I2 + 1] + zw2[1, 1] * ve[1] - oxv[1])
    fz = m * (r02 * da0 + r12 * da1 + r22 * da2) + m * (w2[1, 2] * s[S_I2 + 2] + zw2[1, 2] * ve[2] - oxv[2])
    fx, fy, tilt_limited = limit_tilt2(fx, fy, mg, k.tilt_max_rad)
    tm, phi_c, theta_c = force_to_thrust_attitude3(fx, fy, fz, mg)

    # --- yaw augmentation: nose along the path tangent
    dpsi_c = yaw_rate_command(dpc0, dpc1, d2pc0, d2pc1, k.yaw_hold_speed_m_s)
    gc = (phi_c, theta_c, s[S_PSI_C])

    # --- loop 3: attitude kinematics -> body-rate command
    ge = (gc[0] - gam[0], gc[1] - gam[1], wrap_pi(gc[2] - gam[2]))
    if first:
        diff_reset3(s, S_D_GAMMA, gc[0], gc[1], gc[2])
    dgc0, _ = diff_channel(s, S_D_GAMMA, 0, gc[0], d)
    dgc1, _ = diff_channel(s, S_D_GAMMA, 1, gc[1], d)
    dgc2, _ = diff_channel(s, S_D_GAMMA, 2, gc[2], d)
    cph, sph = math.cos(gc[0]), math.sin(gc[0])
    cth, sth, tth = math.cos(gc[1]), math.sin(gc[1]), math.tan(gc[1])
    a3ge = a3_times(cph, sph, cth, tth, om[1], om[2], ge)
    wc = euler_rate_times(cph, sph, cth, sth, (
        dgc0 + w2[2, 0] * s[S_I3] + zw2[2, 0] * ge[0] + a3ge[0],
        dgc1 + w2[2, 1] * s[S_I3 + 1] + zw2[2, 1] * ge[1] + a3ge[1],
        dgc2 + w2[2, 2] * s[S_I3 + 2] + zw2[2, 2] * ge[2] + a3ge[2],
    ))  # fmt: skip

    # --- loop 4: attitude dynamics -> torque command
    we = (wc[0] - om[0], wc[1] - om[1], wc[2] - om[2])
    if first:
        diff_reset3(s, S_D_OMEGA, wc[0], wc[1], wc[2])
    dwc0, _ = diff_channel(s, S_D_OMEGA, 0, wc[0], d)
    dwc1, _ = diff_channel(s, S_D_OMEGA, 1, wc[1], d)
    dwc2, _ = diff_channel(s, S_D_OMEGA, 2, wc[2], d)
    j = k.j
    jd = mat_vec3(j, (dwc0, dwc1, dwc2))
    gyro = cross3(wc, mat_vec3(j, wc))
    a4we = a4_times3(wc, j, k.j_inv, we)
    reg = mat_vec3(j, (
        w2[3, 0] * s[S_I4] + zw2[3, 0] * we[0] + a4we[0],
        w2[3, 1] * s[S_I4 + 1] + zw2[3, 1] * we[1] + a4we[1],
        w2[3, 2] * s[S_I4 + 2] + zw2[3, 2] * we[2] + a4we[2],
    ))  # fmt: skip
    qc = (jd[0] + gyro[0] + reg[0], jd[1] + gyro[1] + reg[1], jd[2] + gyro[2] + reg[2])

    # --- allocation with saturation (the rotor-aware TLC: to the disc's tilt, then loop 5)
    if k.rotor.on:
        u, tm, sat_mask = flapping_loop(k, s, x[OMEGA], np.array(wc), np.array(qc), tm, first)
    else:  # written where the working copy keeps its last command (commit copies it there)
        u = s[S_LAST_U : S_LAST_U + N_PITCH]
        tm, sat_mask = allocate3(qc[0], qc[1], qc[2], tm, c, k.limits, u)
    if not all_finite(u) or not all_finite(s):
        return refuse(st, S_LAST_U, out, diag, BAD_OUTPUT)

    # --- integrators: conditional integration (frozen while any output saturates)
    saturated = sat_mask != 0
    if not hold_integrators:
        if not (saturated or tilt_limited):
            if not speed_limited:
                for i in range(3):
                    s[S_I1 + i] += dt * pe[i]
            for i in range(3):
                s[S_I2 + i] += dt * ve[i]
        if not saturated:
            for i in range(3):
                s[S_I3 + i] += dt * ge[i]
                s[S_I4 + i] += dt * we[i]
    s[S_PSI_C] += dt * dpsi_c
    s[S_STARTED] = 1.0
    return commit(st, s, S_LAST_U, u, out, diag, gc[0], gc[1], gc[2], tm, sat_mask, tilt_limited)


@njit
def _finite3(v: FloatArray, at: int) -> bool:
    return math.isfinite(v[at]) and math.isfinite(v[at + 1]) and math.isfinite(v[at + 2])


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


register_law(TLCConstants, tlc_kernel)  # the compiled loop's dispatch (autopilot.control.control_law)


__all__ = ["BAD_INPUT", "BAD_OUTPUT", "D_PHI_C", "D_PSI_C", "D_SAT_MASK", "D_STATUS", "D_THETA_C",
           "D_TILT_LIMITED", "D_TM", "N_DIAG", "OK", "Feedforward", "TLController", "tlc_kernel"]  # fmt: skip
