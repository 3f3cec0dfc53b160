"""The inertial navigation filter: an error-state extended Kalman filter, compiled.

Nominal state: the attitude quaternion (body FLU to earth NWU), velocity and position in
earth NWU, the gyro and accelerometer biases (body FLU) and a GPS position wander (earth
NWU, first-order Gauss-Markov). The error state (18) is the local attitude error
``d_theta`` (``R_true = R Exp(d_theta)``), and the additive errors of the rest (Sola 2017,
"Quaternion kinematics for the error-state Kalman filter", s. 5 and 7, local angular
error). The IMU is mechanised every tick; GPS position and velocity, barometric height and
magnetometer heading are fused at their time of validity, late measurements by re-running
the filter from a buffer of past ticks (the replay of :mod:`autopilot.estimation.kf`).
docs/estimator.md, "The navigation filter", derives the Jacobians; tests/test_ins.py checks
them against finite differences.

Layouts (all ``float64``; only names index them):

* ``params`` (``N_PARAMS``, ``K_*``) from :func:`make_params`;
* ``state`` (:func:`state_size`): the filter (``E_*``) then a ring buffer of ``n_buf``
  records (``R_*``), each one tick interval: the filter at its start, the IMU sample over
  it, and the GPS fix, baro height and magnetometer sample valid inside it;
* the error state ``ERR`` (``D_*``) orders the covariance, ``NOMINAL`` (``N_*``) the
  nominal state.

No I/O and no clock: time is an argument.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.log import (
    L_ACCEL_BIAS,
    L_BIAS,
    L_DIVERGED,
    L_GPS_STATUS,
    L_GYRO_BIAS,
    L_INNOV,
    L_MAG_INNOV,
    L_MAG_NIS,
    L_NEES,
    L_NIS,
    L_SD_ACCEL_BIAS,
    L_SD_ATT,
    L_SD_GYRO_BIAS,
    L_SD_POS,
    L_SD_VEL,
    L_SINCE_FIX,
)
from heli_common.jit import njit
from heli_common.kinematics import (
    euler_from_rot,
    quat_from_euler,
    quat_from_rotvec,
    quat_mul,
    rot_body_to_earth,
    rot_from_quat,
    wrap_pi,
)
from heli_common.layout import Layout
from heli_common.measurements import (
    NEW_BARO,
    NEW_GPS,
    NEW_MAG,
    OUT_ACCEL,
    OUT_BARO_ALT,
    OUT_BARO_T,
    OUT_GPS_POS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_MAG,
    OUT_MAG_T,
)
from heli_common.state import PHI, PSI, THETA, U_F, V_L, W_U, X_N, FloatArray

# --- the error state: the covariance's order
ERR = Layout(
    "navigation error state",
    ("att", 3),  # local attitude error d_theta, body FLU [rad]
    ("vel", 3),  # earth NWU [m/s]
    ("pos", 3),  # earth NWU [m]
    ("gyro_bias", 3),  # body FLU [rad/s]
    ("accel_bias", 3),  # body FLU [m/s^2]
    ("gps_wander", 3),  # earth NWU [m]
    ("mag_bias", 3),  # magnetometer offset left by the calibration, body FLU [gauss]
)
D_ATT = ERR.offset("att")
D_VEL = ERR.offset("vel")
D_POS = ERR.offset("pos")
D_BG = ERR.offset("gyro_bias")
D_BA = ERR.offset("accel_bias")
D_GW = ERR.offset("gps_wander")
D_BM = ERR.offset("mag_bias")
N_ERR = ERR.size
N_NAV = D_GW  # the navigation states (attitude to accelerometer bias): what NEES is taken on
N_COV = N_ERR * N_ERR

# --- the nominal state
NOMINAL = Layout(
    "navigation nominal state",
    ("q", 4), ("vel", 3), ("pos", 3), ("gyro_bias", 3), ("accel_bias", 3), ("gps_wander", 3),
    ("mag_bias", 3),
)  # fmt: skip
N_Q = NOMINAL.offset("q")
N_VEL = NOMINAL.offset("vel")
N_POS = NOMINAL.offset("pos")
N_BG = NOMINAL.offset("gyro_bias")
N_BA = NOMINAL.offset("accel_bias")
N_GW = NOMINAL.offset("gps_wander")
N_BM = NOMINAL.offset("mag_bias")
N_NOM = NOMINAL.size

# --- params (K_*)
PARAMS = Layout(
    "navigation filter parameters",
    ("g", 1),  # gravity [m/s^2]
    ("q_gyro", 1),  # gyro white-noise PSD [(rad/s)^2/Hz]
    ("q_accel", 1),  # accelerometer white-noise PSD [(m/s^2)^2/Hz]
    ("q_gyro_walk", 1),  # bias random-walk PSDs
    ("q_accel_walk", 1),
    ("q_mag_walk", 1),
    ("p0", N_ERR),  # initial variances
    ("r_gps_pos", 3),  # white GPS position variance per axis [m^2]
    ("r_gps_vel", 3),
    ("wander_var", 3),  # Gauss-Markov wander variance per axis [m^2]; 0: not modelled
    ("wander_tau", 1),  # [s]
    ("use_vel", 1),
    ("use_baro", 1),
    ("use_mag", 1),
    ("gate_1", 1),  # chi-square thresholds, 1, 3 and 6 degrees of freedom
    ("gate_3", 1),
    ("gate_6", 1),
    ("max_rejects", 1),
    ("gps_timeout", 1),  # [s]
    ("r_baro", 1),  # [m^2]
    ("r_mag", 1),  # heading variance [rad^2]
    ("mag_offsets", 3),  # calibration subtracted from the body field [gauss]
    ("declination", 1),  # east of true north [rad]
    ("mag_field", 3),  # the earth's field at home, NWU [gauss]
    ("divergence_s", 1),
    ("n_buf", 1),
    ("t_tol", 1),  # a validity time up to this far after "now" is taken as now [s]
)
K_G = PARAMS.offset("g")
K_Q_GYRO = PARAMS.offset("q_gyro")
K_Q_ACCEL = PARAMS.offset("q_accel")
K_Q_GYRO_WALK = PARAMS.offset("q_gyro_walk")
K_Q_ACCEL_WALK = PARAMS.offset("q_accel_walk")
K_Q_MAG_WALK = PARAMS.offset("q_mag_walk")
K_P0 = PARAMS.offset("p0")
K_R_GPS_POS = PARAMS.offset("r_gps_pos")
K_R_GPS_VEL = PARAMS.offset("r_gps_vel")
K_WANDER_VAR = PARAMS.offset("wander_var")
K_WANDER_TAU = PARAMS.offset("wander_tau")
K_USE_VEL = PARAMS.offset("use_vel")
K_USE_BARO = PARAMS.offset("use_baro")
K_USE_MAG = PARAMS.offset("use_mag")
K_GATE_1 = PARAMS.offset("gate_1")
K_GATE_3 = PARAMS.offset("gate_3")
K_GATE_6 = PARAMS.offset("gate_6")
K_MAX_REJECTS = PARAMS.offset("max_rejects")
K_GPS_TIMEOUT = PARAMS.offset("gps_timeout")
K_R_BARO = PARAMS.offset("r_baro")
K_R_MAG = PARAMS.offset("r_mag")
K_MAG_OFFSETS = PARAMS.offset("mag_offsets")
K_DECLINATION = PARAMS.offset("declination")
K_MAG_FIELD = PARAMS.offset("mag_field")
K_DIVERGENCE_S = PARAMS.offset("divergence_s")
K_N_BUF = PARAMS.offset("n_buf")
K_T_TOL = PARAMS.offset("t_tol")
N_PARAMS = PARAMS.size

# --- the filter (E_*); the ring buffer follows at E_HIST
FILTER = Layout(
    "navigation filter",
    ("t", 1),  # time of the estimate [s]; NaN until the first predict
    ("nom", N_NOM),
    ("cov", N_COV),  # error-state covariance, row-major
    ("gyro", 3),  # the IMU sample in use (held when a sample is bad)
    ("accel", 3),
    ("gyro_prev", 3),  # the one before: the interval between them is integrated
    ("accel_prev", 3),
    ("t_fix", 1),  # validity time of the newest accepted GPS fix (the first tick before any)
    ("t_fix_seen", 1),  # validity time of the newest GPS fix received, accepted or not
    ("t_fix_gated", 1),  # validity time of the newest fix that passed the gate (not a reset)
    ("t_mag_ok", 1),  # time of the newest accepted magnetometer heading
    ("t_mag_seen", 1),
    ("n_fix", 1),
    ("n_reject", 1),
    ("n_consec", 1),
    ("n_reset", 1),
    ("n_too_old", 1),
    ("n_bad", 1),
    ("n_baro", 1),
    ("n_baro_reject", 1),
    ("n_baro_consec", 1),
    ("n_mag", 1),
    ("n_mag_reject", 1),
    ("n_mag_consec", 1),
    ("n_mag_reset", 1),
    ("n_bad_imu", 1),
    ("nis", 1),  # the last GPS fix's normalised innovation squared
    ("t_innov", 1),
    ("innov_pos", 3),
    ("innov_vel", 3),
    ("s_pos", 3),  # innovation variances (diagonal of S)
    ("s_vel", 3),
    ("baro_innov", 1),
    ("baro_s", 1),
    ("baro_nis", 1),
    ("mag_innov", 1),  # heading innovation [rad]
    ("mag_s", 1),
    ("mag_nis", 1),
    ("diverged", 1),  # 1 once diverged (latched until a reset)
    ("head", 1),
    ("count", 1),
)
E_T = FILTER.offset("t")
E_NOM = FILTER.offset("nom")
E_COV = FILTER.offset("cov")
E_GYRO = FILTER.offset("gyro")
E_ACCEL = FILTER.offset("accel")
E_GYRO_PREV = FILTER.offset("gyro_prev")
E_ACCEL_PREV = FILTER.offset("accel_prev")
E_T_FIX = FILTER.offset("t_fix")
E_T_FIX_SEEN = FILTER.offset("t_fix_seen")
E_T_FIX_GATED = FILTER.offset("t_fix_gated")
E_T_MAG_OK = FILTER.offset("t_mag_ok")
E_T_MAG_SEEN = FILTER.offset("t_mag_seen")
E_N_FIX = FILTER.offset("n_fix")
E_N_REJECT = FILTER.offset("n_reject")
E_N_CONSEC = FILTER.offset("n_consec")
E_N_RESET = FILTER.offset("n_reset")
E_N_TOO_OLD = FILTER.offset("n_too_old")
E_N_BAD = FILTER.offset("n_bad")
E_N_BARO = FILTER.offset("n_baro")
E_N_BARO_REJECT = FILTER.offset("n_baro_reject")
E_N_BARO_CONSEC = FILTER.offset("n_baro_consec")
E_N_MAG = FILTER.offset("n_mag")
E_N_MAG_REJECT = FILTER.offset("n_mag_reject")
E_N_MAG_CONSEC = FILTER.offset("n_mag_consec")
E_N_MAG_RESET = FILTER.offset("n_mag_reset")
E_N_BAD_IMU = FILTER.offset("n_bad_imu")
E_NIS = FILTER.offset("nis")
E_T_INNOV = FILTER.offset("t_innov")
E_INNOV_POS = FILTER.offset("innov_pos")
E_INNOV_VEL = FILTER.offset("innov_vel")
E_S_POS = FILTER.offset("s_pos")
E_S_VEL = FILTER.offset("s_vel")
E_BARO_INNOV = FILTER.offset("baro_innov")
E_BARO_S = FILTER.offset("baro_s")
E_BARO_NIS = FILTER.offset("baro_nis")
E_MAG_INNOV = FILTER.offset("mag_innov")
E_MAG_S = FILTER.offset("mag_s")
E_MAG_NIS = FILTER.offset("mag_nis")
E_DIVERGED = FILTER.offset("diverged")
E_HEAD = FILTER.offset("head")
E_COUNT = FILTER.offset("count")
E_HIST = FILTER.end
N_FILTER = FILTER.size

# --- one record of the ring buffer (R_*), relative to its start
RECORD = Layout(
    "navigation record",
    ("t0", 1),
    ("dt", 1),
    ("gyro", 3),  # the IMU sample over the interval
    ("accel", 3),
    ("nom0", N_NOM),  # the filter at t0
    ("cov0", N_COV),
    ("gps_flag", 1),  # M_* below
    ("gps_tau", 1),  # validity time - t0
    ("gps_pos", 3),
    ("gps_vel", 3),  # NaN: position only
    ("baro_flag", 1),
    ("baro_tau", 1),
    ("baro_z", 1),
    ("mag_flag", 1),
    ("mag_tau", 1),
    ("mag_field", 3),  # body FLU [gauss], as measured
)
R_T0 = RECORD.offset("t0")
R_DT = RECORD.offset("dt")
R_GYRO = RECORD.offset("gyro")
R_ACCEL = RECORD.offset("accel")
R_NOM0 = RECORD.offset("nom0")
R_COV0 = RECORD.offset("cov0")
R_GPS_FLAG = RECORD.offset("gps_flag")
R_GPS_TAU = RECORD.offset("gps_tau")
R_GPS_POS = RECORD.offset("gps_pos")
R_GPS_VEL = RECORD.offset("gps_vel")
R_BARO_FLAG = RECORD.offset("baro_flag")
R_BARO_TAU = RECORD.offset("baro_tau")
R_BARO_Z = RECORD.offset("baro_z")
R_MAG_FLAG = RECORD.offset("mag_flag")
R_MAG_TAU = RECORD.offset("mag_tau")
R_MAG_FIELD = RECORD.offset("mag_field")
N_REC = RECORD.size

# measurement flags in a record
M_NONE, M_PENDING, M_ACCEPTED, M_RESET = 0.0, 1.0, 2.0, 3.0
# which measurement of a record
_GPS, _BARO, _MAG = 0, 1, 2

# status codes (the same numbers as autopilot.estimation.kf's)
ACCEPTED, REJECTED, RESET, TOO_OLD, BAD_INPUT, NOT_STARTED = 0, 1, 2, 3, 4, 5
NO_FIX = -1
P_OK, P_FIRST, P_NO_ADVANCE, P_BAD_IMU = 0, 1, 2, 3


def state_size(n_buf: int) -> int:
    return N_FILTER + n_buf * N_REC


def make_params(
    config: EstimatorConfig, rate_hz: float, field_nwu_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> FloatArray:
    """The flat parameter vector for ``config`` at tick rate ``rate_hz``; the earth's
    magnetic field at home (earth NWU; :mod:`heli_common.magnetic`), what the magnetometer
    is compared with (all zero: no magnetometer fusion)."""
    declination_rad = math.atan2(-field_nwu_gauss[1], field_nwu_gauss[0])
    if not 10.0 <= rate_hz <= 2000.0:
        raise ValueError(f"estimator rate must be in [10, 2000] Hz, got {rate_hz}")
    if not all(math.isfinite(v) and abs(v) < 10.0 for v in field_nwu_gauss):
        raise ValueError(f"the earth's field must be finite and below 10 gauss, got {field_nwu_gauss}")
    c = config.ins
    k = np.zeros(N_PARAMS)
    k[K_G] = config.gravity_m_s2
    k[K_Q_GYRO] = c.gyro_noise_density**2
    k[K_Q_ACCEL] = c.accel_noise_density**2
    k[K_Q_GYRO_WALK] = c.gyro_bias_walk**2
    k[K_Q_ACCEL_WALK] = c.accel_bias_walk**2
    k[K_Q_MAG_WALK] = c.mag_bias_walk**2
    p0 = k[K_P0 : K_P0 + N_ERR]
    p0[D_ATT : D_ATT + 3] = c.init_att_sigma_rad**2
    p0[D_VEL : D_VEL + 3] = c.init_vel_sigma_m_s**2
    p0[D_POS : D_POS + 3] = c.init_pos_sigma_m**2
    p0[D_BG : D_BG + 3] = c.init_gyro_bias_sigma**2
    p0[D_BA : D_BA + 3] = c.init_accel_bias_sigma**2
    p0[D_GW : D_GW + 3] = np.square(c.gps_wander_sigma_m)
    p0[D_BM : D_BM + 3] = c.init_mag_bias_sigma_gauss**2
    k[K_R_GPS_POS : K_R_GPS_POS + 3] = np.square(c.gps_white_sigma_m)
    k[K_R_GPS_VEL : K_R_GPS_VEL + 3] = np.square(config.gps_vel_sigma_m_s)
    k[K_WANDER_VAR : K_WANDER_VAR + 3] = np.square(c.gps_wander_sigma_m)
    k[K_WANDER_TAU] = c.gps_wander_tau_s
    k[K_USE_VEL] = 1.0 if config.use_gps_velocity else 0.0
    k[K_USE_BARO] = 1.0 if config.use_baro else 0.0
    k[K_USE_MAG] = 1.0 if c.use_mag else 0.0
    k[K_GATE_1] = float(chi2.ppf(config.gate_probability, 1))
    k[K_GATE_3] = float(chi2.ppf(config.gate_probability, 3))
    k[K_GATE_6] = float(chi2.ppf(config.gate_probability, 6))
    k[K_MAX_REJECTS] = config.max_consecutive_rejects
    k[K_GPS_TIMEOUT] = config.gps_timeout_s
    k[K_R_BARO] = config.baro_sigma_m**2
    k[K_R_MAG] = c.mag_sigma_gauss**2
    k[K_MAG_OFFSETS : K_MAG_OFFSETS + 3] = c.mag_offsets_gauss
    k[K_DECLINATION] = declination_rad
    k[K_MAG_FIELD : K_MAG_FIELD + 3] = field_nwu_gauss
    if not any(field_nwu_gauss):
        k[K_USE_MAG] = 0.0
    k[K_DIVERGENCE_S] = c.divergence_s
    k[K_N_BUF] = math.ceil(config.buffer_s * rate_hz) + 2
    k[K_T_TOL] = 0.5 / rate_hz
    return k


# ------------------------------------------------------------------ small pieces


@njit
def _finite3(v: FloatArray) -> bool:
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


@njit
def _cov(st: FloatArray) -> FloatArray:
    """The covariance as an (N_ERR, N_ERR) view of the state array."""
    return st[E_COV : E_COV + N_COV].reshape((N_ERR, N_ERR))


@njit
def _rec(params: FloatArray, st: FloatArray, age: int) -> int:
    """Offset of the record ``age`` ticks before the newest (0: newest)."""
    n = int(params[K_N_BUF])
    return E_HIST + ((int(st[E_HEAD]) - age) % n) * N_REC


@njit
def mag_heading(field_flu: FloatArray, phi: float, theta: float, declination: float) -> float:
    """True heading (ZYX yaw, NWU: positive toward west) from a body field and the roll
    and pitch: the field levelled, ``m_h = Ry(theta) Rx(phi) m_b``, has the azimuth
    ``atan2(m_W, m_N) - psi`` and ``atan2(m_W, m_N) = -declination``."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    mx, my, mz = field_flu[0], field_flu[1], field_flu[2]
    hx = cth * mx + sth * (sph * my + cph * mz)
    hy = cph * my - sph * mz
    return wrap_pi(-declination - math.atan2(hy, hx))


# ------------------------------------------------------------------ prediction


@njit
def _velocity_blocks(
    q: FloatArray, w: FloatArray, a: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The velocity rows of F for the mechanisation ``v += R Exp(w dt / 2) a dt``:
    ``dv/d d_theta = -R_mid [a]x Exp(w dt / 2)^T dt`` (R Exp(d) Exp(h) = R Exp(h) Exp(Exp(h)^T d))
    ``dv/d b_a = -R_mid dt``, and through the half-tick rotation ``dv/d b_g =
    R_mid [a]x dt^2 / 2``, with ``R_mid = R Exp(w dt / 2)``."""
    half = quat_from_rotvec(0.5 * w[0] * dt, 0.5 * w[1] * dt, 0.5 * w[2] * dt)
    rh = rot_from_quat(half)
    r_mid = rot_from_quat(quat_mul(q, half))
    ra = np.empty((3, 3))  # R_mid [a]x: column j is R_mid (e_j x a)
    for i in range(3):
        ra[i, 0] = r_mid[i, 1] * a[2] - r_mid[i, 2] * a[1]
        ra[i, 1] = r_mid[i, 2] * a[0] - r_mid[i, 0] * a[2]
        ra[i, 2] = r_mid[i, 0] * a[1] - r_mid[i, 1] * a[0]
    m_va = np.empty((3, 3))
    r_dt = np.empty((3, 3))
    m_vg = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            m_va[i, j] = -(ra[i, 0] * rh[j, 0] + ra[i, 1] * rh[j, 1] + ra[i, 2] * rh[j, 2]) * dt
            r_dt[i, j] = r_mid[i, j] * dt
            m_vg[i, j] = 0.5 * dt * dt * ra[i, j]
    return m_va, r_dt, m_vg


@njit
def error_transition(
    q: FloatArray, gyro: FloatArray, accel: FloatArray, nom: FloatArray, dt: float, tau_w: float
) -> FloatArray:
    """The error-state transition matrix ``F`` over ``dt`` (Sola 2017 eq. 269, local angle
    error) with the IMU sample held: dense, for the tests and the docs; the kernel applies
    the same blocks without forming it."""
    f = np.eye(N_ERR)
    w = np.empty(3)
    a = np.empty(3)
    for i in range(3):
        w[i] = gyro[i] - nom[N_BG + i]
        a[i] = accel[i] - nom[N_BA + i]
    rw = rot_from_quat(quat_from_rotvec(w[0] * dt, w[1] * dt, w[2] * dt))
    m_va, r_dt, m_vg = _velocity_blocks(q, w, a, dt)
    for i in range(3):
        for j in range(3):
            f[D_ATT + i, D_ATT + j] = rw[j, i]  # R{w dt}^T
            f[D_VEL + i, D_ATT + j] = m_va[i, j]
            f[D_VEL + i, D_BA + j] = -r_dt[i, j]
            f[D_VEL + i, D_BG + j] = m_vg[i, j]
            f[D_POS + i, D_BG + j] = 0.5 * dt * m_vg[i, j]
            f[D_POS + i, D_ATT + j] = 0.5 * dt * m_va[i, j]
            f[D_POS + i, D_BA + j] = -0.5 * dt * r_dt[i, j]
        f[D_ATT + i, D_BG + i] = -dt
        f[D_POS + i, D_VEL + i] = dt
        f[D_GW + i, D_GW + i] = math.exp(-dt / tau_w)
    return f


@njit
def _apply_f(src: FloatArray, dst: FloatArray, rw: FloatArray, m_va: FloatArray, r_dt: FloatArray,
             m_vg: FloatArray, dt: float, decay: float) -> None:  # fmt: skip
    """``dst = F src`` for the block structure of :func:`error_transition` (``rw`` =
    R{w dt}, ``m_va`` = -R [a]x dt, ``r_dt`` = R dt): about 30 flops a column instead of
    the dense product's 18 x 18."""
    for j in range(N_ERR):
        for i in range(3):
            dst[D_ATT + i, j] = (rw[0, i] * src[D_ATT, j] + rw[1, i] * src[D_ATT + 1, j]
                                 + rw[2, i] * src[D_ATT + 2, j] - dt * src[D_BG + i, j])  # fmt: skip
            inc = (m_va[i, 0] * src[D_ATT, j] + m_va[i, 1] * src[D_ATT + 1, j]
                   + m_va[i, 2] * src[D_ATT + 2, j]
                   - r_dt[i, 0] * src[D_BA, j] - r_dt[i, 1] * src[D_BA + 1, j]
                   - r_dt[i, 2] * src[D_BA + 2, j]
                   + m_vg[i, 0] * src[D_BG, j] + m_vg[i, 1] * src[D_BG + 1, j]
                   + m_vg[i, 2] * src[D_BG + 2, j])  # fmt: skip
            dst[D_VEL + i, j] = src[D_VEL + i, j] + inc
            # the position takes half the tick's velocity change (p += v dt + a dt^2 / 2)
            dst[D_POS + i, j] = src[D_POS + i, j] + dt * src[D_VEL + i, j] + 0.5 * dt * inc
            dst[D_BG + i, j] = src[D_BG + i, j]
            dst[D_BA + i, j] = src[D_BA + i, j]
            dst[D_GW + i, j] = decay * src[D_GW + i, j]
            dst[D_BM + i, j] = src[D_BM + i, j]


@njit
def _propagate(params: FloatArray, st: FloatArray, gyro: FloatArray, accel: FloatArray, dt: float) -> None:
    """Nominal mechanisation and covariance over ``dt`` with the IMU sample held:
    ``p += v dt + a_E dt^2 / 2``, ``v += a_E dt`` with ``a_E = R (f - b_a) + g_E``,
    ``q = q (x) Exp((w - b_g) dt)``; ``P = F P F^T + Q``."""
    if dt <= 0.0:
        return
    nom = st[E_NOM : E_NOM + N_NOM]
    q = nom[N_Q : N_Q + 4]
    w = np.empty(3)
    a = np.empty(3)
    for i in range(3):
        w[i] = gyro[i] - nom[N_BG + i]
        a[i] = accel[i] - nom[N_BA + i]
    # the specific force rotated with the attitude at the interval's middle: the error of
    # rotating it with the start attitude grows with the rate (a 45 deg/s pitch rate tilts
    # it by 0.2 deg over a 10 ms tick, which the filter would take for a bias)
    q_start = q.copy()
    r_mid = rot_from_quat(quat_mul(q, quat_from_rotvec(0.5 * w[0] * dt, 0.5 * w[1] * dt, 0.5 * w[2] * dt)))
    ae = np.empty(3)
    for i in range(3):
        ae[i] = r_mid[i, 0] * a[0] + r_mid[i, 1] * a[1] + r_mid[i, 2] * a[2]
    ae[2] -= params[K_G]
    decay = math.exp(-dt / params[K_WANDER_TAU])
    for i in range(3):
        nom[N_POS + i] += dt * nom[N_VEL + i] + 0.5 * dt * dt * ae[i]
        nom[N_VEL + i] += dt * ae[i]
        nom[N_GW + i] *= decay  # the Gauss-Markov wander's mean decays toward zero
    dq = quat_from_rotvec(w[0] * dt, w[1] * dt, w[2] * dt)
    qn = quat_mul(q, dq)
    norm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for i in range(4):
        q[i] = qn[i] / norm
    # covariance: P <- F (F P)^T (P symmetric), then Q on the diagonal
    rw = rot_from_quat(dq)
    m_va, r_dt, m_vg = _velocity_blocks(q_start, w, a, dt)
    p = _cov(st)
    tmp = np.empty((N_ERR, N_ERR))
    _apply_f(p, tmp, rw, m_va, r_dt, m_vg, dt, decay)
    _apply_f(tmp.T, p, rw, m_va, r_dt, m_vg, dt, decay)
    for i in range(3):
        p[D_ATT + i, D_ATT + i] += params[K_Q_GYRO] * dt
        p[D_VEL + i, D_VEL + i] += params[K_Q_ACCEL] * dt
        p[D_BG + i, D_BG + i] += params[K_Q_GYRO_WALK] * dt
        p[D_BA + i, D_BA + i] += params[K_Q_ACCEL_WALK] * dt
        p[D_GW + i, D_GW + i] += params[K_WANDER_VAR + i] * (1.0 - decay * decay)
        p[D_BM + i, D_BM + i] += params[K_Q_MAG_WALK] * dt
    for i in range(N_ERR):  # hold the symmetry round-off would break
        for j in range(i + 1, N_ERR):
            m = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = m
            p[j, i] = m


# ------------------------------------------------------------------ corrections


@njit
def _scalar_update(p: FloatArray, dx: FloatArray, h: FloatArray, y: float, r: float) -> None:
    """One scalar measurement ``y = h dx + v`` (``v ~ N(0, r)``) into the error mean ``dx``
    and ``p``: ``K = P h / S``, ``dx += K (y - h dx)``, ``P -= K (P h)^T``. A vector with
    uncorrelated components fused one component at a time equals the batch update."""
    ph = np.zeros(N_ERR)
    hph = 0.0
    innov = y
    for j in range(N_ERR):
        if h[j] != 0.0:  # H rows are sparse: a few ones or a heading Jacobian
            innov -= h[j] * dx[j]
            for i in range(N_ERR):
                ph[i] += p[i, j] * h[j]
    for j in range(N_ERR):
        hph += h[j] * ph[j]
    s = hph + r
    for i in range(N_ERR):
        k = ph[i] / s
        dx[i] += k * innov
        for j in range(N_ERR):
            p[i, j] -= k * ph[j]


@njit
def _inject(st: FloatArray, dx: FloatArray) -> None:
    """Fold the error mean into the nominal state (the reset Jacobian taken as identity,
    Sola 2017 s. 6.3: its effect is second order in d_theta)."""
    nom = st[E_NOM : E_NOM + N_NOM]
    dq = quat_from_rotvec(dx[D_ATT], dx[D_ATT + 1], dx[D_ATT + 2])
    qn = quat_mul(nom[N_Q : N_Q + 4], dq)
    norm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for i in range(4):
        nom[N_Q + i] = qn[i] / norm
    for i in range(3):
        nom[N_VEL + i] += dx[D_VEL + i]
        nom[N_POS + i] += dx[D_POS + i]
        nom[N_BG + i] += dx[D_BG + i]
        nom[N_BA + i] += dx[D_BA + i]
        nom[N_GW + i] += dx[D_GW + i]
        nom[N_BM + i] += dx[D_BM + i]


@njit
def _cholesky_nis(s: FloatArray, y: FloatArray, m: int) -> float:
    """``y^T S^-1 y`` of the leading ``m`` x ``m`` block (Cholesky; inf if not positive)."""
    low = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            v = s[i, j]
            for k in range(j):
                v -= low[i, k] * low[j, k]
            if i == j:
                if v <= 0.0:
                    return math.inf
                low[i, i] = math.sqrt(v)
            else:
                low[i, j] = v / low[j, j]
    z = np.empty(m)
    for i in range(m):
        v = y[i]
        for k in range(i):
            v -= low[i, k] * z[k]
        z[i] = v / low[i, i]
    return float(z @ z)


@njit
def _gps_rows(params: FloatArray, use_vel: bool) -> tuple[FloatArray, FloatArray, int]:
    """``H`` (rows: position N, W, U, then velocity) and the white variances."""
    m = 6 if use_vel else 3
    h = np.zeros((m, N_ERR))
    r = np.empty(m)
    for i in range(3):
        h[i, D_POS + i] = 1.0
        if params[K_WANDER_VAR + i] > 0.0:
            h[i, D_GW + i] = 1.0
        r[i] = params[K_R_GPS_POS + i]
        if use_vel:
            h[3 + i, D_VEL + i] = 1.0
            r[3 + i] = params[K_R_GPS_VEL + i]
    return h, r, m


@njit
def _reset_gps(params: FloatArray, st: FloatArray, pos: FloatArray, vel: FloatArray, use_vel: bool) -> None:
    """Position (and velocity) set to the fix, the wander zeroed, their covariance rows
    cleared and their variances set to the fix's: a receiver that jumped is believed."""
    nom = st[E_NOM : E_NOM + N_NOM]
    p = _cov(st)
    for i in range(3):
        nom[N_POS + i] = pos[i]
        nom[N_GW + i] = 0.0
        if use_vel:
            nom[N_VEL + i] = vel[i]
    for i in range(3):
        rows = (D_POS + i, D_GW + i, D_VEL + i) if use_vel else (D_POS + i, D_GW + i, -1)
        for row in rows:
            if row < 0:
                continue
            for j in range(N_ERR):
                p[row, j] = 0.0
                p[j, row] = 0.0
        p[D_POS + i, D_POS + i] = params[K_R_GPS_POS + i]
        p[D_GW + i, D_GW + i] = params[K_WANDER_VAR + i]
        if use_vel:
            p[D_VEL + i, D_VEL + i] = params[K_R_GPS_VEL + i]


@njit
def _apply_gps(params: FloatArray, st: FloatArray, flag: float, t_fix: float, pos: FloatArray,
               vel: FloatArray) -> float:  # fmt: skip
    """Fuse one fix into the filter as it is now (its validity time). A pending fix is
    gated on the NIS of the whole fix and logged; returns the flag it ends with."""
    use_vel = _finite3(vel)
    nom = st[E_NOM : E_NOM + N_NOM]
    p = _cov(st)
    h, r, m = _gps_rows(params, use_vel)
    y = np.empty(m)
    for i in range(3):
        y[i] = pos[i] - nom[N_POS + i] - nom[N_GW + i]
        if use_vel:
            y[3 + i] = vel[i] - nom[N_VEL + i]
    if flag == M_PENDING:
        s = np.empty((m, m))  # H P H^T + R
        for i in range(m):
            for j in range(m):
                v = 0.0
                for a in range(N_ERR):
                    if h[i, a] != 0.0:
                        for b in range(N_ERR):
                            v += h[i, a] * p[a, b] * h[j, b]
                s[i, j] = v
            s[i, i] += r[i]
        nis = _cholesky_nis(s, y, m)
        st[E_NIS] = nis
        st[E_T_INNOV] = t_fix
        for i in range(3):
            st[E_INNOV_POS + i], st[E_S_POS + i] = y[i], s[i, i]
            st[E_INNOV_VEL + i] = y[3 + i] if use_vel else math.nan
            st[E_S_VEL + i] = s[3 + i, 3 + i] if use_vel else math.nan
        st[E_T_FIX_SEEN] = max(st[E_T_FIX_SEEN], t_fix)
        gate = params[K_GATE_6] if use_vel else params[K_GATE_3]
        if nis <= gate:
            flag = M_ACCEPTED
            st[E_N_FIX] += 1.0
            st[E_N_CONSEC] = 0.0
            st[E_T_FIX_GATED] = max(st[E_T_FIX_GATED], t_fix)
        elif st[E_N_CONSEC] >= params[K_MAX_REJECTS]:
            flag = M_RESET
            st[E_N_RESET] += 1.0
            st[E_N_CONSEC] = 0.0
        else:
            st[E_N_REJECT] += 1.0
            st[E_N_CONSEC] += 1.0
            return M_NONE
        st[E_T_FIX] = max(st[E_T_FIX], t_fix)
    if flag == M_RESET:
        _reset_gps(params, st, pos, vel, use_vel)
        return flag
    dx = np.zeros(N_ERR)
    for i in range(m):
        _scalar_update(p, dx, h[i], y[i], r[i])
    _inject(st, dx)
    return flag


@njit
def _apply_baro(params: FloatArray, st: FloatArray, flag: float, z: float) -> float:
    p = _cov(st)
    h = np.zeros(N_ERR)
    h[D_POS + 2] = 1.0
    y = z - st[E_NOM + N_POS + 2]
    if flag == M_PENDING:
        s = p[D_POS + 2, D_POS + 2] + params[K_R_BARO]
        nis = y * y / s
        st[E_BARO_INNOV], st[E_BARO_S], st[E_BARO_NIS] = y, s, nis
        if nis > params[K_GATE_1] and st[E_N_BARO_CONSEC] < params[K_MAX_REJECTS]:
            st[E_N_BARO_REJECT] += 1.0
            st[E_N_BARO_CONSEC] += 1.0
            return M_NONE
        # after max_rejects in a row the height is fused anyway: the baro is the only
        # height reference in a GPS outage, and a persistent offset is a real one
        flag = M_ACCEPTED
        st[E_N_BARO] += 1.0
        st[E_N_BARO_CONSEC] = 0.0
    dx = np.zeros(N_ERR)
    _scalar_update(p, dx, h, y, params[K_R_BARO])
    _inject(st, dx)
    return flag


@njit
def _euler(st: FloatArray) -> tuple[float, float, float]:
    return euler_from_rot(rot_from_quat(st[E_NOM + N_Q : E_NOM + N_Q + 4]))


@njit
def _realign(params: FloatArray, st: FloatArray, field_flu: FloatArray) -> None:
    """Attitude realigned as at a start (:func:`align`, from the latest specific force and
    the body field): roll and pitch from gravity, yaw from the compass; the attitude error's
    cross-covariance cleared and its variance the initial one. What a compass rejected
    for long means: the attitude itself is wrong (a touchdown levels the vehicle in one
    step, which no gyro sees), not the compass."""
    m_e = params[K_MAG_FIELD : K_MAG_FIELD + 3].copy()
    phi, theta, psi = align(st[E_ACCEL : E_ACCEL + 3].copy(), field_flu, m_e)
    st[E_NOM + N_Q : E_NOM + N_Q + 4] = quat_from_euler(phi, theta, psi)
    p = _cov(st)
    for i in range(3):
        for j in range(N_ERR):
            p[D_ATT + i, j] = 0.0
            p[j, D_ATT + i] = 0.0
        p[D_ATT + i, D_ATT + i] = params[K_P0 + D_ATT + i]


@njit
def mag_jacobian(r: FloatArray, field_nwu: FloatArray) -> FloatArray:
    """d(R^T m)/d d_theta = [R^T m]x for the local attitude error (R_true = R Exp(d_theta):
    Exp(d_theta)^T R^T m = R^T m + [R^T m]x d_theta to first order; docs/estimator.md)."""
    mb = np.empty(3)
    for i in range(3):
        mb[i] = r[0, i] * field_nwu[0] + r[1, i] * field_nwu[1] + r[2, i] * field_nwu[2]
    j = np.zeros((3, 3))
    j[0, 1], j[0, 2] = -mb[2], mb[1]
    j[1, 0], j[1, 2] = mb[2], -mb[0]
    j[2, 0], j[2, 1] = -mb[1], mb[0]
    return j


@njit
def _apply_mag(params: FloatArray, st: FloatArray, flag: float, t_meas: float, field: FloatArray) -> float:
    """Fuse a magnetometer sample as the three components of the body field: the
    measurement less the calibration offsets against ``R^T m`` of the earth's field at
    home. A 3-axis fusion and not a heading: where the field is steep (68 deg of
    inclination at the default home) a heading levelled with a roll error of 1 deg is off
    by up to 2.5 deg, which a heading fusion would book as a yaw error."""
    nom = st[E_NOM : E_NOM + N_NOM]
    r = rot_from_quat(nom[N_Q : N_Q + 4])
    m_e = params[K_MAG_FIELD : K_MAG_FIELD + 3]
    jac = mag_jacobian(r, m_e)
    y = np.empty(3)
    for i in range(3):
        pred = r[0, i] * m_e[0] + r[1, i] * m_e[1] + r[2, i] * m_e[2]
        y[i] = field[i] - params[K_MAG_OFFSETS + i] - nom[N_BM + i] - pred
    p = _cov(st)
    rm = params[K_R_MAG]
    if flag == M_PENDING:
        s = np.empty((3, 3))  # H P H^T + R with H = [J 0 ... I]
        for i in range(3):
            for j in range(3):
                v = (rm if i == j else 0.0) + p[D_BM + i, D_BM + j]
                for a in range(3):
                    v += jac[i, a] * p[D_ATT + a, D_BM + j] + p[D_BM + i, D_ATT + a] * jac[j, a]
                    for b in range(3):
                        v += jac[i, a] * p[D_ATT + a, D_ATT + b] * jac[j, b]
                s[i, j] = v
        nis = _cholesky_nis(s, y, 3)
        st[E_MAG_NIS] = nis
        st[E_MAG_S] = s[0, 0] + s[1, 1] + s[2, 2]
        st[E_MAG_INNOV] = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
        st[E_T_MAG_SEEN] = max(st[E_T_MAG_SEEN], t_meas)
        if nis <= params[K_GATE_3]:
            flag = M_ACCEPTED
            st[E_N_MAG] += 1.0
            st[E_N_MAG_CONSEC] = 0.0
            st[E_T_MAG_OK] = max(st[E_T_MAG_OK], t_meas)
        elif st[E_N_MAG_CONSEC] >= params[K_MAX_REJECTS] * 10.0:
            # a field persistently away from the prediction (an attitude that drifted while
            # the compass was off, a touchdown, a bad start) is believed: realigned
            flag = M_RESET
            st[E_N_MAG_RESET] += 1.0
            st[E_N_MAG_CONSEC] = 0.0
        else:
            st[E_N_MAG_REJECT] += 1.0
            st[E_N_MAG_CONSEC] += 1.0
            return M_NONE
    if flag == M_RESET:
        m = np.empty(3)
        for i in range(3):
            m[i] = field[i] - params[K_MAG_OFFSETS + i] - st[E_NOM + N_BM + i]
        _realign(params, st, m)
        return flag
    dx = np.zeros(N_ERR)
    h = np.zeros(N_ERR)
    for i in range(3):
        for a in range(3):
            h[D_ATT + a] = jac[i, a]
            h[D_BM + a] = 1.0 if a == i else 0.0
        _scalar_update(p, dx, h, y[i], rm)
    _inject(st, dx)
    return flag


@njit
def _apply(params: FloatArray, st: FloatArray, rec: int, kind: int, flag: float) -> float:
    t_meas = st[rec + R_T0]
    if kind == _GPS:
        pos = st[rec + R_GPS_POS : rec + R_GPS_POS + 3]
        vel = st[rec + R_GPS_VEL : rec + R_GPS_VEL + 3]
        return _apply_gps(params, st, flag, t_meas + st[rec + R_GPS_TAU], pos, vel)
    if kind == _BARO:
        return _apply_baro(params, st, flag, st[rec + R_BARO_Z])
    field = st[rec + R_MAG_FIELD : rec + R_MAG_FIELD + 3]
    return _apply_mag(params, st, flag, t_meas + st[rec + R_MAG_TAU], field)


# ------------------------------------------------------------------ the buffer


_FLAG = (R_GPS_FLAG, R_BARO_FLAG, R_MAG_FLAG)
_TAU = (R_GPS_TAU, R_BARO_TAU, R_MAG_TAU)


@njit
def _replay_record(params: FloatArray, st: FloatArray, rec: int) -> float:
    """Propagate the filter over record ``rec``'s interval, fusing its measurements at their
    validity times in time order; returns the final flag of a pending one (M_NONE if none)."""
    result = M_NONE
    done = 0.0
    gyro = st[rec + R_GYRO : rec + R_GYRO + 3]
    accel = st[rec + R_ACCEL : rec + R_ACCEL + 3]
    pending = np.zeros(3, dtype=np.bool_)
    for k in range(3):
        pending[k] = st[rec + _FLAG[k]] != M_NONE
    for _ in range(3):
        kind = -1
        for k in range(3):
            if pending[k] and (kind < 0 or st[rec + _TAU[k]] < st[rec + _TAU[kind]]):
                kind = k
        if kind < 0:
            break
        tau = st[rec + _TAU[kind]]
        _propagate(params, st, gyro, accel, tau - done)
        done = tau
        old = st[rec + _FLAG[kind]]
        new = _apply(params, st, rec, kind, old)
        st[rec + _FLAG[kind]] = new
        pending[kind] = False
        if old == M_PENDING:
            result = new
    _propagate(params, st, gyro, accel, st[rec + R_DT] - done)
    return result


@njit
def _replay(params: FloatArray, st: FloatArray, age_from: int) -> float:
    """Re-run the filter from the start of record ``age_from`` to now, rewriting the later
    records' start states; the flag the pending measurement ends with."""
    result = M_NONE
    for age in range(age_from, -1, -1):
        rec = _rec(params, st, age)
        if age == age_from:
            st[E_NOM : E_NOM + N_NOM] = st[rec + R_NOM0 : rec + R_NOM0 + N_NOM]
            st[E_COV : E_COV + N_COV] = st[rec + R_COV0 : rec + R_COV0 + N_COV]
        else:
            st[rec + R_NOM0 : rec + R_NOM0 + N_NOM] = st[E_NOM : E_NOM + N_NOM]
            st[rec + R_COV0 : rec + R_COV0 + N_COV] = st[E_COV : E_COV + N_COV]
        flag = _replay_record(params, st, rec)
        if flag != M_NONE:
            result = flag
    return result


@njit
def _locate(params: FloatArray, st: FloatArray, t_meas: float) -> tuple[int, float]:
    for age in range(int(st[E_COUNT])):
        rec = _rec(params, st, age)
        tau = t_meas - st[rec + R_T0]
        if tau >= 0.0:
            return age, min(tau, st[rec + R_DT])
    return -1, 0.0


@njit
def _validity(params: FloatArray, st: FloatArray, t_meas: float) -> float:
    if math.isnan(st[E_T]) or not math.isfinite(t_meas) or t_meas > st[E_T] + params[K_T_TOL]:
        return math.nan
    return float(min(t_meas, st[E_T]))


@njit
def _measure(
    params: FloatArray, st: FloatArray, kind: int, t_meas: float, a: FloatArray, b: FloatArray
) -> int:
    """Fuse a measurement of ``kind`` valid at ``t_meas``: ``a`` the GPS position, the baro
    height (``a[0]``) or the body field; ``b`` the GPS velocity (NaN: none)."""
    if math.isnan(st[E_T]):
        return NOT_STARTED
    t = _validity(params, st, t_meas)
    if math.isnan(t) or not _finite3(a):
        st[E_N_BAD] += 1.0
        return BAD_INPUT
    if st[E_COUNT] == 0.0:
        return NOT_STARTED  # the first tick: the filter was aligned at this very time
    age, tau = _locate(params, st, t)
    if age < 0:
        st[E_N_TOO_OLD] += 1.0
        return TOO_OLD
    rec = _rec(params, st, age)
    st[rec + _FLAG[kind]] = M_PENDING
    st[rec + _TAU[kind]] = tau
    if kind == _GPS:
        use_vel = params[K_USE_VEL] > 0.5 and _finite3(b)
        for i in range(3):
            st[rec + R_GPS_POS + i] = a[i]
            st[rec + R_GPS_VEL + i] = b[i] if use_vel else math.nan
    elif kind == _BARO:
        st[rec + R_BARO_Z] = a[0]
    else:
        st[rec + R_MAG_FIELD : rec + R_MAG_FIELD + 3] = a
    if age == 0 and tau >= st[rec + R_DT]:
        # valid at the end of the newest interval, which is now: fuse into the present
        flag = _apply(params, st, rec, kind, M_PENDING)
        st[rec + _FLAG[kind]] = flag
    else:
        flag = _replay(params, st, age)
    if flag == M_ACCEPTED:
        return ACCEPTED
    return RESET if flag == M_RESET else REJECTED


# ------------------------------------------------------------------ the kernels


@njit
def est_init(params: FloatArray, st: FloatArray, x0: FloatArray) -> None:
    """Start from the 12-state ``x0`` (NWU position, FLU velocity, Euler, rates): attitude,
    velocity and position aligned there, biases and wander zero, the configured initial
    covariance; counters cleared; time unset until the first predict."""
    st[:] = 0.0
    st[E_T] = math.nan
    nom = st[E_NOM : E_NOM + N_NOM]
    nom[N_Q : N_Q + 4] = quat_from_euler(x0[PHI], x0[THETA], x0[PSI])
    r = rot_body_to_earth(x0[PHI], x0[THETA], x0[PSI])
    for i in range(3):
        nom[N_POS + i] = x0[X_N + i]
        nom[N_VEL + i] = r[i, 0] * x0[U_F] + r[i, 1] * x0[V_L] + r[i, 2] * x0[W_U]
    p = _cov(st)
    for i in range(N_ERR):
        p[i, i] = params[K_P0 + i]
    st[E_ACCEL + 2] = params[K_G]
    st[E_ACCEL_PREV + 2] = params[K_G]
    for i in (E_NIS, E_T_INNOV, E_BARO_INNOV, E_BARO_S, E_BARO_NIS, E_MAG_INNOV, E_MAG_S, E_MAG_NIS):
        st[i] = math.nan
    for i in range(3):
        st[E_INNOV_POS + i] = math.nan
        st[E_INNOV_VEL + i] = math.nan
        st[E_S_POS + i] = math.nan
        st[E_S_VEL + i] = math.nan
    st[E_T_FIX_SEEN] = -math.inf
    st[E_T_MAG_SEEN] = -math.inf
    st[E_HEAD] = -1.0


@njit
def est_predict(params: FloatArray, st: FloatArray, t_s: float, gyro: FloatArray, accel: FloatArray) -> int:
    """One IMU tick to ``t_s``: the sample is taken as valid over (t, t_s]; a bad sample
    holds the last good one. The first call only sets the time."""
    status = P_OK
    if _finite3(gyro) and _finite3(accel):
        st[E_GYRO_PREV : E_GYRO_PREV + 3] = st[E_GYRO : E_GYRO + 3]
        st[E_ACCEL_PREV : E_ACCEL_PREV + 3] = st[E_ACCEL : E_ACCEL + 3]
        st[E_GYRO : E_GYRO + 3] = gyro
        st[E_ACCEL : E_ACCEL + 3] = accel
    else:
        status = P_BAD_IMU
        st[E_N_BAD_IMU] += 1.0
    if math.isnan(st[E_T]):
        st[E_T] = t_s
        st[E_T_FIX] = t_s
        st[E_T_FIX_GATED] = t_s
        st[E_T_MAG_OK] = t_s
        st[E_GYRO_PREV : E_GYRO_PREV + 3] = st[E_GYRO : E_GYRO + 3]
        st[E_ACCEL_PREV : E_ACCEL_PREV + 3] = st[E_ACCEL : E_ACCEL + 3]
        return P_FIRST
    dt = t_s - st[E_T]
    if not dt > 0.0:
        return P_NO_ADVANCE
    n = int(params[K_N_BUF])
    head = (int(st[E_HEAD]) + 1) % n
    st[E_HEAD] = head
    st[E_COUNT] = min(st[E_COUNT] + 1.0, n)
    rec = E_HIST + head * N_REC
    st[rec + R_T0] = st[E_T]
    st[rec + R_DT] = dt
    # the samples at both ends of the interval averaged (trapezoid): second order in dt
    for i in range(3):
        st[rec + R_GYRO + i] = 0.5 * (st[E_GYRO_PREV + i] + st[E_GYRO + i])
        st[rec + R_ACCEL + i] = 0.5 * (st[E_ACCEL_PREV + i] + st[E_ACCEL + i])
    st[rec + R_NOM0 : rec + R_NOM0 + N_NOM] = st[E_NOM : E_NOM + N_NOM]
    st[rec + R_COV0 : rec + R_COV0 + N_COV] = st[E_COV : E_COV + N_COV]
    st[rec + R_GPS_FLAG] = M_NONE
    st[rec + R_BARO_FLAG] = M_NONE
    st[rec + R_MAG_FLAG] = M_NONE
    _propagate(params, st, st[rec + R_GYRO : rec + R_GYRO + 3], st[rec + R_ACCEL : rec + R_ACCEL + 3],
               dt)  # fmt: skip
    st[E_T] = t_s
    return status


@njit
def est_gps(params: FloatArray, st: FloatArray, t_fix: float, pos: FloatArray, vel: FloatArray) -> int:
    """Fuse a GPS fix valid at ``t_fix`` (<= now) at its validity time."""
    return _measure(params, st, _GPS, t_fix, pos, vel)


@njit
def est_baro(params: FloatArray, st: FloatArray, t_meas: float, alt_m: float) -> int:
    """Fuse a barometric height above home valid at ``t_meas``."""
    a = np.full(3, alt_m)
    return _measure(params, st, _BARO, t_meas, a, a)


@njit
def est_mag(params: FloatArray, st: FloatArray, t_meas: float, field_flu: FloatArray) -> int:
    """Fuse a magnetometer sample (body FLU, gauss) valid at ``t_meas`` as a heading."""
    return _measure(params, st, _MAG, t_meas, field_flu, field_flu)


@njit
def _check_divergence(params: FloatArray, st: FloatArray) -> None:
    """Latch ``diverged`` when the state or covariance is not finite, or when a sensor that
    is delivering has had no measurement inside its gate for ``divergence_s``."""
    t = st[E_T]
    lim = params[K_DIVERGENCE_S]
    bad = not np.all(np.isfinite(st[E_NOM : E_COV + N_COV]))  # the nominal state and the covariance
    delivering = t - st[E_T_FIX_SEEN] <= params[K_GPS_TIMEOUT]
    if delivering and t - st[E_T_FIX_GATED] > lim:  # resets are not health
        bad = True
    if t - st[E_T_MAG_SEEN] <= lim and t - st[E_T_MAG_OK] > lim:
        bad = True
    if bad:
        st[E_DIVERGED] = 1.0


@njit
def est_output(st: FloatArray, x_out: FloatArray) -> None:
    """The 12-state estimate: position, body FLU velocity ``R^T v``, Euler angles, and the
    body rates as the gyro less its estimated bias."""
    nom = st[E_NOM : E_NOM + N_NOM]
    r = rot_from_quat(nom[N_Q : N_Q + 4])
    for i in range(3):
        x_out[X_N + i] = nom[N_POS + i]
        x_out[U_F + i] = r[0, i] * nom[N_VEL] + r[1, i] * nom[N_VEL + 1] + r[2, i] * nom[N_VEL + 2]
        x_out[PHI + 3 + i] = st[E_GYRO + i] - nom[N_BG + i]
    x_out[PHI], x_out[THETA], x_out[PSI] = euler_from_rot(r)


@njit
def est_tick(
    params: FloatArray, st: FloatArray, t_s: float, meas: FloatArray, mask: int, x_out: FloatArray
) -> int:
    """One control tick on the measurement layout (latest sample of each sensor, ``mask``
    the new ones): predict with the IMU sample, fuse a new GPS fix, baro height and
    magnetometer heading at their validity times, write the estimate. Returns the GPS
    status (``NO_FIX`` when none was new)."""
    est_predict(params, st, t_s, meas[OUT_GYRO : OUT_GYRO + 3], meas[OUT_ACCEL : OUT_ACCEL + 3])
    if params[K_USE_MAG] > 0.5 and mask & NEW_MAG:
        est_mag(params, st, meas[OUT_MAG_T], meas[OUT_MAG : OUT_MAG + 3])
    if params[K_USE_BARO] > 0.5 and mask & NEW_BARO:
        est_baro(params, st, meas[OUT_BARO_T], meas[OUT_BARO_ALT])
    status = NO_FIX
    if mask & NEW_GPS:
        status = est_gps(params, st, meas[OUT_GPS_T], meas[OUT_GPS_POS : OUT_GPS_POS + 3],
                         meas[OUT_GPS_VEL : OUT_GPS_VEL + 3])  # fmt: skip
    _check_divergence(params, st)
    est_output(st, x_out)
    return status


@njit
def log_tick(st: FloatArray, gps_status: int, row: FloatArray) -> None:
    """One row of :data:`~autopilot.estimation.log.EST_LOG_COLUMNS` for the tick just
    estimated."""
    nom = st[E_NOM : E_NOM + N_NOM]
    p = _cov(st)
    r = rot_from_quat(nom[N_Q : N_Q + 4])
    fix = gps_status != NO_FIX
    for i in range(3):
        row[L_SD_POS + i] = math.sqrt(max(p[D_POS + i, D_POS + i], 0.0))
        row[L_SD_VEL + i] = math.sqrt(max(p[D_VEL + i, D_VEL + i], 0.0))
        row[L_BIAS + i] = r[i, 0] * nom[N_BA] + r[i, 1] * nom[N_BA + 1] + r[i, 2] * nom[N_BA + 2]
        row[L_INNOV + i] = st[E_INNOV_POS + i] if fix else math.nan
        row[L_SD_ATT + i] = math.sqrt(max(p[D_ATT + i, D_ATT + i], 0.0))
        row[L_GYRO_BIAS + i] = nom[N_BG + i]
        row[L_SD_GYRO_BIAS + i] = math.sqrt(max(p[D_BG + i, D_BG + i], 0.0))
        row[L_ACCEL_BIAS + i] = nom[N_BA + i]
        row[L_SD_ACCEL_BIAS + i] = math.sqrt(max(p[D_BA + i, D_BA + i], 0.0))
    row[L_GPS_STATUS] = gps_status
    row[L_NIS] = st[E_NIS] if fix else math.nan
    row[L_SINCE_FIX] = st[E_T] - st[E_T_FIX]
    row[L_MAG_INNOV] = st[E_MAG_INNOV]
    row[L_MAG_NIS] = st[E_MAG_NIS]
    row[L_DIVERGED] = st[E_DIVERGED]
    row[L_NEES:] = math.nan  # the truth's columns: filled where a simulation knows it


@njit
def nav_error(st: FloatArray, x_true: FloatArray, gyro_bias_true: FloatArray, accel_bias_true: FloatArray,
              err: FloatArray) -> None:  # fmt: skip
    """The true error of the navigation states (the first ``N_NAV`` of the error state) from
    the truth: ``d_theta = Log(R^T R_true)``, the velocity and position errors in earth
    NWU, the bias errors. Only a simulation knows it: for NEES and tests."""
    nom = st[E_NOM : E_NOM + N_NOM]
    r = rot_from_quat(nom[N_Q : N_Q + 4])
    rt = rot_body_to_earth(x_true[PHI], x_true[THETA], x_true[PSI])
    d = r.T @ rt
    c = max(-1.0, min(1.0, 0.5 * (d[0, 0] + d[1, 1] + d[2, 2] - 1.0)))
    angle = math.acos(c)
    k = 0.5 if angle < 1e-8 else 0.5 * angle / math.sin(angle)
    err[D_ATT] = k * (d[2, 1] - d[1, 2])
    err[D_ATT + 1] = k * (d[0, 2] - d[2, 0])
    err[D_ATT + 2] = k * (d[1, 0] - d[0, 1])
    for i in range(3):
        v = rt[i, 0] * x_true[U_F] + rt[i, 1] * x_true[V_L] + rt[i, 2] * x_true[W_U]
        err[D_VEL + i] = v - nom[N_VEL + i]
        err[D_POS + i] = x_true[X_N + i] - nom[N_POS + i]
        err[D_BG + i] = gyro_bias_true[i] - nom[N_BG + i]
        err[D_BA + i] = accel_bias_true[i] - nom[N_BA + i]


@njit
def nees(st: FloatArray, err: FloatArray) -> float:
    """The normalised estimation error squared of the navigation states,
    ``e^T P_nav^-1 e`` with ``P_nav`` their block of the covariance (the marginal)."""
    p = _cov(st)
    return _cholesky_nis(p[:N_NAV, :N_NAV].copy(), err[:N_NAV].copy(), N_NAV)


@njit
def align(accel_flu: FloatArray, mag_flu: FloatArray, field_nwu: FloatArray) -> tuple[float, float, float]:
    """ZYX Euler angles of a vehicle at rest from its accelerometer and magnetometer (TRIAD,
    Shuster and Oh 1981): the specific force at rest is ``R^T (0, 0, g)``, the field
    ``R^T m``; the first pair fixes the tilt exactly, the second the heading."""
    b1 = accel_flu / math.sqrt(float(accel_flu @ accel_flu))
    r1 = np.array([0.0, 0.0, 1.0])
    b2 = np.cross(b1, mag_flu)
    b2 = b2 / math.sqrt(float(b2 @ b2))
    r2 = np.cross(r1, field_nwu)
    r2 = r2 / math.sqrt(float(r2 @ r2))
    mb = np.empty((3, 3))
    me = np.empty((3, 3))
    b3 = np.cross(b1, b2)
    r3 = np.cross(r1, r2)
    for i in range(3):
        mb[i, 0], mb[i, 1], mb[i, 2] = b1[i], b2[i], b3[i]
        me[i, 0], me[i, 1], me[i, 2] = r1[i], r2[i], r3[i]
    return euler_from_rot(me @ mb.T)  # R maps the body triad onto the earth triad
