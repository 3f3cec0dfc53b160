"""The inertial navigation filter: an error-state extended Kalman filter, compiled.

Nominal state: the attitude quaternion (body FLU to earth NWU), velocity and position in
earth NWU, the gyro and accelerometer biases (body FLU), a GPS position wander (earth NWU,
first-order Gauss-Markov) and the magnetometer's offset (body FLU). The error state (21)
is the local attitude error ``d_theta`` (``R_true = R Exp(d_theta)``), and the additive
errors of the rest (Sola 2017, "Quaternion kinematics for the error-state Kalman filter",
s. 5 and 7, local angular error). The IMU is mechanised every tick; GPS position and
velocity, barometric height and the magnetometer's field are fused at their time of
validity: a late GPS fix when it arrives, through the cross-covariance of the present
state with the one it measures, carried from its time (:func:`_fuse_late_gps`); what that
cannot carry by re-running the filter from a buffer of past ticks (the replay of
:mod:`autopilot.estimation.kf`).
docs/estimator.md, "The navigation filter", derives the Jacobians and the late fusion;
tests/test_ins.py checks the Jacobians against finite differences, tests/test_ins_late_fixes.py
the late fusion against fixes on time.

Layouts (all ``float64``; only names index them):

* ``params`` (``N_PARAMS``, ``K_*``) from :func:`make_params`;
* ``state`` (:func:`state_size`): the filter (``E_*``, with the kernels' scratch: no array
  is made in a tick) then a ring buffer of ``n_buf`` records (``R_*``), each one tick
  interval: the filter at its start, the IMU sample over it, the GPS fix, baro height and
  magnetometer sample valid inside it, and its F and the scalar updates at its end (what
  a late fix is carried through);
* the error state ``ERR`` (``D_*``) orders the covariance, ``NOMINAL`` (``N_*``) the
  nominal state.

No I/O and no clock: time is an argument.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.gating import M_ACCEPTED, M_NONE, M_PENDING, M_RESET, chi2_quantile, gate_outcome
from autopilot.estimation.log import (
    L_ACCEL_BIAS,
    L_ATT_ERR,
    L_BIAS,
    L_DIVERGED,
    L_GPS_STATUS,
    L_GYRO_BIAS,
    L_GYRO_BIAS_ERR,
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
    quat_from_rotvec,  # noqa: F401 (the tests take Exp from here, as the filter's own)
    rot_body_to_earth,
    rot_from_quat,
)
from heli_common.layout import Layout
from heli_common.state import PHI, PSI, THETA, U_F, V_L, W_U, X_N, FloatArray
from heli_common.wire.measurements import (
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
COV_TRI = N_ERR * (N_ERR + 1) // 2  # its upper triangle: P is kept exactly symmetric

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

# --- the blocks of F (error_transition) a propagation applies, in its scratch (F_*)
F_BLOCKS = Layout(
    "error transition blocks",
    ("rw", 9),  # R{w dt}, row-major
    ("m_va", 9),  # dv/d d_theta = -R_mid [a]x Exp(w dt / 2)^T dt
    ("r_dt", 9),  # -dv/d b_a = R_mid dt
    ("m_vg", 9),  # dv/d b_g = R_mid [a]x dt^2 / 2
    ("decay", 1),  # exp(-dt / tau) of the GPS wander
)
F_RW = F_BLOCKS.offset("rw")
F_M_VA = F_BLOCKS.offset("m_va")
F_R_DT = F_BLOCKS.offset("r_dt")
F_M_VG = F_BLOCKS.offset("m_vg")
F_DECAY = F_BLOCKS.offset("decay")
FB_SIZE = F_BLOCKS.size
MAX_Y = 6  # the most components a measurement has (a GPS fix with velocity)

# --- one scalar update as a record keeps it (U_*), for a late fix's cross-covariance:
# h = (h_att at the attitude error) + (a 1 at h_unit), P h before it, S and the innovation
UPDATE = Layout(
    "logged scalar update",
    ("ph", N_ERR),
    ("h_att", 3),
    ("h_unit", 1),  # the error-state index of h's unit entry
    ("s", 1),
    ("nu", 1),
)
U_PH = UPDATE.offset("ph")
U_H_ATT = UPDATE.offset("h_att")
U_H_UNIT = UPDATE.offset("h_unit")
U_S = UPDATE.offset("s")
U_NU = UPDATE.offset("nu")
UPD_SIZE = UPDATE.size
MAX_UPD = 4  # a magnetometer sample's three components and a baro height in one tick
# the row length of a late fix's cross-covariance: its (up to) 6 columns and 2 of zeros,
# whole vector registers with no remainder to run apart
XC_W = 8
# a validity time this close to a tick is taken as the tick (the sim link's microseconds,
# the float round-off of a lag): no sliver of an interval to propagate over
T_SNAP_S = 1e-6

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
    # scratch of the kernels (no array is made in a tick; a late fix makes its own, five a
    # second): F's blocks of the interval being propagated, and the vectors and small
    # matrices of an update
    ("f_blocks", FB_SIZE),
    ("ph", MAX_Y * N_ERR),  # P h of each scalar update of a measurement (P before it)
    ("g", MAX_Y * N_ERR),  # P h / sqrt(S) of each: P loses g g^T
    ("unit", MAX_Y),  # where each row of H has its 1 besides the attitude (-1: elsewhere too)
    ("nz", MAX_Y * N_ERR),  # the columns where each row of H is not zero, in order
    ("nz_n", MAX_Y),  # how many
    ("dx", N_ERR),  # the error mean of an update
    ("hm", MAX_Y * N_ERR),  # the rows of H, row-major
    ("y", MAX_Y),  # the innovations of one measurement
    ("r", MAX_Y),  # their (white) variances
    ("s_upd", MAX_Y),  # S of each scalar update
    ("s_diag", MAX_Y),  # the diagonal of the measurement's S = H P H^T + R
    ("nu", MAX_Y),  # the innovation of each, against the state the ones before left
    ("s", MAX_Y * MAX_Y),  # a late fix's S = Var(H x_s) + R, row-major, for its gate
    ("chol", (N_NAV + 1) * (N_NAV + 1)),  # the factor of a NIS, the elimination of a NEES
    ("chol_z", N_NAV),
    ("baro_in", 3),  # the baro height as the 3-vector a measurement is handed over in
    ("err", N_ERR),  # the true error, where a simulation knows the truth (nav_error)
    ("cov_s", N_COV),  # a late fix's P at its validity time, out of its record
    ("imu_in", 6),  # an IMU sample handed over as arrays (_propagate)
    ("log_rec", 1),  # the record the scalar updates are logged into (-1: none)
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
E_F_BLOCKS = FILTER.offset("f_blocks")
E_PH = FILTER.offset("ph")
E_G = FILTER.offset("g")
E_UNIT = FILTER.offset("unit")
E_NZ = FILTER.offset("nz")
E_NZ_N = FILTER.offset("nz_n")
E_R = FILTER.offset("r")
E_S_UPD = FILTER.offset("s_upd")
E_S_DIAG = FILTER.offset("s_diag")
E_NU = FILTER.offset("nu")
E_DX = FILTER.offset("dx")
E_HM = FILTER.offset("hm")
E_Y = FILTER.offset("y")
E_S = FILTER.offset("s")
E_CHOL = FILTER.offset("chol")
E_CHOL_Z = FILTER.offset("chol_z")
E_BARO_IN = FILTER.offset("baro_in")
E_ERR = FILTER.offset("err")
E_COV_S = FILTER.offset("cov_s")
E_IMU_IN = FILTER.offset("imu_in")
E_LOG_REC = FILTER.offset("log_rec")
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
    ("cov0", COV_TRI),  # its upper triangle, row by row
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
    # what a late GPS fix needs to be fused now at its validity time (_fuse_late_gps)
    ("xc_ok", 1),  # 1: one propagation over the interval, then the logged updates only
    ("stale", 1),  # 1: the start state misses a late fix fused after it (no replay from here)
    ("fb", FB_SIZE),  # F of the propagation
    ("n_upd", 1),
    ("upd", MAX_UPD * UPD_SIZE),  # the scalar updates at its end, in order
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
R_XC_OK = RECORD.offset("xc_ok")
R_STALE = RECORD.offset("stale")
R_FB = RECORD.offset("fb")
R_N_UPD = RECORD.offset("n_upd")
R_UPD = RECORD.offset("upd")
N_REC = RECORD.size

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
    magnetic field at home (earth NWU; :mod:`heli_common.world.magnetic`), what the magnetometer
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
    k[K_GATE_1] = chi2_quantile(config.gate_probability, 1)
    k[K_GATE_3] = chi2_quantile(config.gate_probability, 3)
    k[K_GATE_6] = chi2_quantile(config.gate_probability, 6)
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
#
# The kernels index the one state array with the layouts' offsets and make no views of it:
# numba counts the references of every slice it makes (two atomic operations a view, a
# few nanoseconds each, dozens a tick), and a view of the array a loop writes keeps the
# compiler from running the loop wide (it cannot tell the two apart).


@njit
def _finite3(v: FloatArray, at: int = 0) -> bool:
    return math.isfinite(v[at]) and math.isfinite(v[at + 1]) and math.isfinite(v[at + 2])


@njit
def _cov(st: FloatArray) -> FloatArray:
    """The covariance as an (N_ERR, N_ERR) view of the state array."""
    return st[E_COV : E_COV + N_COV].reshape((N_ERR, N_ERR))


_MAX_OFFSET = 1 << 40


@njit
def _nn(i: int) -> int:
    """An offset into the state, with a range the compiler can see is not negative: an
    index it cannot prove so (a record's) gets a wrap-around check on every element, which
    keeps a loop from running wide (a covariance copies five times slower)."""
    return min(max(i, 0), _MAX_OFFSET)


@njit
def _copy(st: FloatArray, dst: int, src: int, n: int) -> None:
    """``st[dst : dst + n] = st[src : src + n]`` for blocks that do not overlap, without
    the temporary a slice assignment within one array makes."""
    d, s = _nn(dst), _nn(src)
    for i in range(_nn(n)):
        st[d + i] = st[s + i]


@njit
def _zero(st: FloatArray, at: int, n: int) -> None:
    for i in range(n):
        st[at + i] = 0.0


@njit
def _pack_cov(st: FloatArray, dst: int) -> None:
    """P's upper triangle, row by row, to ``st[dst:]`` (``COV_TRI``)."""
    d = _nn(dst)
    for i in range(N_ERR):
        row = E_COV + i * N_ERR
        for j in range(i, N_ERR):
            st[d] = st[row + j]
            d += 1


@njit
def _unpack_cov(st: FloatArray, src: int, dst: int = E_COV) -> None:
    """The symmetric matrix whose upper triangle :func:`_pack_cov` left at ``st[src:]``
    into ``st[dst:]`` (P by default)."""
    k, dst = _nn(src), _nn(dst)
    for i in range(N_ERR):
        for j in range(i, N_ERR):
            v = st[k]
            st[dst + i * N_ERR + j] = v
            st[dst + j * N_ERR + i] = v
            k += 1


@njit
def _rec(params: FloatArray, st: FloatArray, age: int) -> int:
    """Offset of the record ``age`` ticks before the newest (0: newest)."""
    n = int(params[K_N_BUF])
    return E_HIST + ((int(st[E_HEAD]) - age) % n) * N_REC


@njit
def _wide(st: FloatArray, n: int) -> int:
    """``n`` as a loop bound the compiler cannot see through (the state array is longer): a
    constant one has the loop unrolled into scalar code before it can run wide."""
    return min(n, st.size)


# ------------------------------------------------------------------ prediction


Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Rot = tuple[float, float, float, float, float, float, float, float, float]


@njit
def _qexp(vx: float, vy: float, vz: float) -> Quat:
    """:func:`~heli_common.kinematics.quat_from_rotvec` on the stack (the same arithmetic,
    no array: the kernels run it several times a tick)."""
    angle = math.sqrt(vx * vx + vy * vy + vz * vz)
    if angle < 1e-8:
        w, s = 1.0 - angle * angle / 8.0, 0.5 - angle * angle / 48.0
    else:
        w, s = math.cos(0.5 * angle), math.sin(0.5 * angle) / angle
    return w, s * vx, s * vy, s * vz


@njit
def _qmul(a: Quat, b: Quat) -> Quat:
    """:func:`~heli_common.kinematics.quat_mul` on the stack."""
    return (a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])  # fmt: skip


@njit
def _qrot(q: Quat) -> Rot:
    """:func:`~heli_common.kinematics.rot_from_quat` on the stack, row-major."""
    w, x, y, z = q
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))  # fmt: skip


@njit
def _rot_euler(phi: float, theta: float, psi: float) -> Rot:
    """:func:`~heli_common.kinematics.rot_body_to_earth` on the stack, row-major."""
    cph, sph = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cps, sps = math.cos(psi), math.sin(psi)
    return (cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps,
            cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps,
            -sth, sph * cth, cph * cth)  # fmt: skip


@njit
def _nom_quat(st: FloatArray) -> Quat:
    q = E_NOM + N_Q
    return st[q], st[q + 1], st[q + 2], st[q + 3]


@njit
def _transition_blocks(q: Quat, w: Vec3, a: Vec3, dt: float, fb: FloatArray, at: int) -> tuple[Quat, Vec3]:
    """The blocks of F (:data:`F_BLOCKS`, at ``fb[at:]``; not the decay) for the
    mechanisation ``v += R Exp(w dt / 2) a dt``: ``dv/d d_theta = -R_mid [a]x
    Exp(w dt / 2)^T dt`` (R Exp(d) Exp(h) = R Exp(h) Exp(Exp(h)^T d)), ``dv/d b_a = -R_mid
    dt``, and through the half-tick rotation ``dv/d b_g = R_mid [a]x dt^2 / 2``, with
    ``R_mid = R Exp(w dt / 2)``; and ``R{w dt}``. Returns the mechanisation's rotations:
    ``Exp(w dt)``, the attitude's increment, and ``R_mid a``, the specific force in earth
    axes."""
    dq = _qexp(w[0] * dt, w[1] * dt, w[2] * dt)
    rw = _qrot(dq)
    half = _qexp(0.5 * w[0] * dt, 0.5 * w[1] * dt, 0.5 * w[2] * dt)
    rh = _qrot(half)
    rm = _qrot(_qmul(q, half))
    for i in range(3):
        m0, m1, m2 = rm[3 * i], rm[3 * i + 1], rm[3 * i + 2]
        # R_mid [a]x: column j is R_mid (e_j x a)
        ra0 = m1 * a[2] - m2 * a[1]
        ra1 = m2 * a[0] - m0 * a[2]
        ra2 = m0 * a[1] - m1 * a[0]
        for j in range(3):
            fb[at + F_RW + 3 * i + j] = rw[3 * i + j]
            fb[at + F_M_VA + 3 * i + j] = -(ra0 * rh[3 * j] + ra1 * rh[3 * j + 1] + ra2 * rh[3 * j + 2]) * dt
            fb[at + F_R_DT + 3 * i + j] = rm[3 * i + j] * dt
        fb[at + F_M_VG + 3 * i] = 0.5 * dt * dt * ra0
        fb[at + F_M_VG + 3 * i + 1] = 0.5 * dt * dt * ra1
        fb[at + F_M_VG + 3 * i + 2] = 0.5 * dt * dt * ra2
    ra = (rm[0] * a[0] + rm[1] * a[1] + rm[2] * a[2], rm[3] * a[0] + rm[4] * a[1] + rm[5] * a[2],
          rm[6] * a[0] + rm[7] * a[1] + rm[8] * a[2])  # fmt: skip
    return dq, ra


@njit
def error_transition(
    q: FloatArray, gyro: FloatArray, accel: FloatArray, nom: FloatArray, dt: float, tau_w: float
) -> FloatArray:
    """The error-state transition matrix ``F`` over ``dt`` (Sola 2017 eq. 269, local angle
    error) with the IMU sample held: dense, for the tests and the docs; the kernel applies
    the same blocks without forming it (:func:`_apply_f`)."""
    f = np.eye(N_ERR)
    w = (gyro[0] - nom[N_BG], gyro[1] - nom[N_BG + 1], gyro[2] - nom[N_BG + 2])
    a = (accel[0] - nom[N_BA], accel[1] - nom[N_BA + 1], accel[2] - nom[N_BA + 2])
    fb = np.empty(FB_SIZE)
    _transition_blocks((q[0], q[1], q[2], q[3]), w, a, dt, fb, 0)
    for i in range(3):
        for j in range(3):
            f[D_ATT + i, D_ATT + j] = fb[F_RW + 3 * j + i]  # R{w dt}^T
            f[D_VEL + i, D_ATT + j] = fb[F_M_VA + 3 * i + j]
            f[D_VEL + i, D_BA + j] = -fb[F_R_DT + 3 * i + j]
            f[D_VEL + i, D_BG + j] = fb[F_M_VG + 3 * i + j]
            f[D_POS + i, D_BG + j] = 0.5 * dt * fb[F_M_VG + 3 * i + j]
            f[D_POS + i, D_ATT + j] = 0.5 * dt * fb[F_M_VA + 3 * i + j]
            f[D_POS + i, D_BA + j] = -0.5 * dt * fb[F_R_DT + 3 * i + j]
        f[D_ATT + i, D_BG + i] = -dt
        f[D_POS + i, D_VEL + i] = dt
        f[D_GW + i, D_GW + i] = math.exp(-dt / tau_w)
    return f


@njit
def _block(fb: FloatArray, at: int) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The 3 x 3 block at ``fb[at:]`` (row-major) as values: held in registers, not re-read
    from the array the loop writes."""
    return (fb[at], fb[at + 1], fb[at + 2], fb[at + 3], fb[at + 4], fb[at + 5], fb[at + 6], fb[at + 7],
            fb[at + 8])  # fmt: skip


@njit
def _apply_f(st: FloatArray, x: int, n: int, ncols: int, fbs: FloatArray, fb: int, dt: float) -> None:
    """``X <- F X`` in place for the ``N_ERR`` x ``ncols`` matrix ``X`` at ``st[x:]`` (row
    ``r`` at ``x + r n``): P itself, or a late fix's cross-covariance. F is the blocks of
    :func:`error_transition` at ``fbs[fb:]`` (``rw`` = R{w dt}, ``m_va`` = -R [a]x dt,
    ``r_dt`` = R dt): about 90 flops a column instead of the dense product's 21 x 21. The
    biases and the magnetometer offset are F's identity: their rows stay. Each column on
    its own, the same operations for every column: the compiler runs several at once."""
    x, n, ncols, fb = _nn(x), _nn(n), _nn(ncols), _nn(fb)
    rw0, rw1, rw2, rw3, rw4, rw5, rw6, rw7, rw8 = _block(fbs, fb + F_RW)
    va0, va1, va2, va3, va4, va5, va6, va7, va8 = _block(fbs, fb + F_M_VA)
    rd0, rd1, rd2, rd3, rd4, rd5, rd6, rd7, rd8 = _block(fbs, fb + F_R_DT)
    vg0, vg1, vg2, vg3, vg4, vg5, vg6, vg7, vg8 = _block(fbs, fb + F_M_VG)
    hdt = 0.5 * dt
    decay = fbs[fb + F_DECAY]
    att, vel, pos = x + D_ATT * n, x + D_VEL * n, x + D_POS * n
    bg, ba, gw = x + D_BG * n, x + D_BA * n, x + D_GW * n
    for j in range(ncols):
        a0, a1, a2 = st[att + j], st[att + n + j], st[att + 2 * n + j]
        g0, g1, g2 = st[bg + j], st[bg + n + j], st[bg + 2 * n + j]
        b0, b1, b2 = st[ba + j], st[ba + n + j], st[ba + 2 * n + j]
        inc0 = (va0 * a0 + va1 * a1 + va2 * a2 - rd0 * b0 - rd1 * b1 - rd2 * b2
                + vg0 * g0 + vg1 * g1 + vg2 * g2)  # fmt: skip
        inc1 = (va3 * a0 + va4 * a1 + va5 * a2 - rd3 * b0 - rd4 * b1 - rd5 * b2
                + vg3 * g0 + vg4 * g1 + vg5 * g2)  # fmt: skip
        inc2 = (va6 * a0 + va7 * a1 + va8 * a2 - rd6 * b0 - rd7 * b1 - rd8 * b2
                + vg6 * g0 + vg7 * g1 + vg8 * g2)  # fmt: skip
        v0, v1, v2 = st[vel + j], st[vel + n + j], st[vel + 2 * n + j]
        st[vel + j] = v0 + inc0
        st[vel + n + j] = v1 + inc1
        st[vel + 2 * n + j] = v2 + inc2
        # the position takes half the tick's velocity change (p += v dt + a dt^2 / 2)
        st[pos + j] = st[pos + j] + dt * v0 + hdt * inc0
        st[pos + n + j] = st[pos + n + j] + dt * v1 + hdt * inc1
        st[pos + 2 * n + j] = st[pos + 2 * n + j] + dt * v2 + hdt * inc2
        st[gw + j] *= decay
        st[gw + n + j] *= decay
        st[gw + 2 * n + j] *= decay
        # R{w dt}^T
        st[att + j] = rw0 * a0 + rw3 * a1 + rw6 * a2 - dt * g0
        st[att + n + j] = rw1 * a0 + rw4 * a1 + rw7 * a2 - dt * g1
        st[att + 2 * n + j] = rw2 * a0 + rw5 * a1 + rw8 * a2 - dt * g2


# the error-state blocks F changes (the others it holds: F's identity there): the
# attitude, velocity and position blocks are one run of rows, the wander another
_CHANGED = (D_ATT, D_VEL, D_POS, D_GW)
_HELD = (D_BG, D_BA, D_BM)
assert D_VEL == D_ATT + 3 and D_POS == D_VEL + 3 and D_BG == D_POS + 3 and D_BM == D_GW + 3 == N_ERR - 3
_N_CHANGED = 3 * len(_CHANGED)


@njit
def _changed(k: int) -> int:
    """The error-state index of the ``k``-th row F changes (attitude to position, then the
    wander)."""
    return D_ATT + k if k < D_BG - D_ATT else D_GW + k - (D_BG - D_ATT)


@njit
def _held(k: int) -> int:
    """The error-state index of the ``k``-th row F holds (the biases, then the compass
    offset)."""
    return D_BG + k if k < D_GW - D_BG else D_BM + k - (D_GW - D_BG)


@njit
def _f_rows(st: FloatArray, fbs: FloatArray, fb: int, dt: float) -> None:
    """``P <- A F^T`` in place, from ``A = F P`` (:func:`_apply_f` on P), F's blocks at
    ``fbs[fb:]``; the result is the symmetric ``F P F^T``, so only what F changes is
    computed: in a row of a block F changes, the columns of those blocks (F applied to
    the row, as to a column in :func:`_apply_f`), symmetrised; the rows of the held blocks
    take their columns from the rows of the changed ones (``(F P F^T)[u, c] = (F P)[c,
    u]``). For a symmetric P this is bit for bit the average of ``F (F P)^T`` with its
    transpose, at a third of the work. The rows are walked with plain counters
    (:func:`_changed`, :func:`_held`), not tuples of blocks: a loop over a tuple is
    unrolled into scalar code, three times slower here."""
    fb = _nn(fb)
    rw0, rw1, rw2, rw3, rw4, rw5, rw6, rw7, rw8 = _block(fbs, fb + F_RW)
    va0, va1, va2, va3, va4, va5, va6, va7, va8 = _block(fbs, fb + F_M_VA)
    rd0, rd1, rd2, rd3, rd4, rd5, rd6, rd7, rd8 = _block(fbs, fb + F_R_DT)
    vg0, vg1, vg2, vg3, vg4, vg5, vg6, vg7, vg8 = _block(fbs, fb + F_M_VG)
    hdt = 0.5 * dt
    decay = fbs[fb + F_DECAY]
    for k in range(_N_CHANGED):
        row = E_COV + _changed(k) * N_ERR
        a0, a1, a2 = st[row + D_ATT], st[row + D_ATT + 1], st[row + D_ATT + 2]
        g0, g1, g2 = st[row + D_BG], st[row + D_BG + 1], st[row + D_BG + 2]
        b0, b1, b2 = st[row + D_BA], st[row + D_BA + 1], st[row + D_BA + 2]
        inc0 = (va0 * a0 + va1 * a1 + va2 * a2 - rd0 * b0 - rd1 * b1 - rd2 * b2
                + vg0 * g0 + vg1 * g1 + vg2 * g2)  # fmt: skip
        inc1 = (va3 * a0 + va4 * a1 + va5 * a2 - rd3 * b0 - rd4 * b1 - rd5 * b2
                + vg3 * g0 + vg4 * g1 + vg5 * g2)  # fmt: skip
        inc2 = (va6 * a0 + va7 * a1 + va8 * a2 - rd6 * b0 - rd7 * b1 - rd8 * b2
                + vg6 * g0 + vg7 * g1 + vg8 * g2)  # fmt: skip
        v0, v1, v2 = st[row + D_VEL], st[row + D_VEL + 1], st[row + D_VEL + 2]
        st[row + D_VEL] = v0 + inc0
        st[row + D_VEL + 1] = v1 + inc1
        st[row + D_VEL + 2] = v2 + inc2
        st[row + D_POS] = st[row + D_POS] + dt * v0 + hdt * inc0
        st[row + D_POS + 1] = st[row + D_POS + 1] + dt * v1 + hdt * inc1
        st[row + D_POS + 2] = st[row + D_POS + 2] + dt * v2 + hdt * inc2
        st[row + D_GW] *= decay
        st[row + D_GW + 1] *= decay
        st[row + D_GW + 2] *= decay
        st[row + D_ATT] = rw0 * a0 + rw3 * a1 + rw6 * a2 - dt * g0
        st[row + D_ATT + 1] = rw1 * a0 + rw4 * a1 + rw7 * a2 - dt * g1
        st[row + D_ATT + 2] = rw2 * a0 + rw5 * a1 + rw8 * a2 - dt * g2
    for k in range(_N_CHANGED):  # the changed rows among themselves: symmetrised
        r = _changed(k)
        for kc in range(k + 1, _N_CHANGED):
            c = _changed(kc)
            m = 0.5 * (st[E_COV + r * N_ERR + c] + st[E_COV + c * N_ERR + r])
            st[E_COV + r * N_ERR + c] = m
            st[E_COV + c * N_ERR + r] = m
    for k in range(N_ERR - _N_CHANGED):  # the held rows, from the changed rows' columns
        u = _held(k)
        for kc in range(_N_CHANGED):
            c = _changed(kc)
            st[E_COV + u * N_ERR + c] = st[E_COV + c * N_ERR + u]


@njit
def _propagate(params: FloatArray, st: FloatArray, gyro: FloatArray, accel: FloatArray, dt: float) -> None:
    """:func:`_propagate_at` with the IMU sample given (for the tests)."""
    for i in range(3):
        st[E_IMU_IN + i] = gyro[i]
        st[E_IMU_IN + 3 + i] = accel[i]
    _propagate_at(params, st, E_IMU_IN, E_IMU_IN + 3, dt)


@njit
def _propagate_at(params: FloatArray, st: FloatArray, g_at: int, a_at: int, dt: float) -> None:
    """Nominal mechanisation and covariance over ``dt`` with the IMU sample (gyro at
    ``st[g_at:]``, accelerometer at ``st[a_at:]``) held: ``p += v dt + a_E dt^2 / 2``,
    ``v += a_E dt`` with ``a_E = R (f - b_a) + g_E``, ``q = q (x) Exp((w - b_g) dt)``;
    ``P = F P F^T + Q``. F's blocks are left in the scratch ``E_F_BLOCKS``."""
    if dt <= 0.0:
        return
    nom = E_NOM
    w = (st[g_at] - st[nom + N_BG], st[g_at + 1] - st[nom + N_BG + 1], st[g_at + 2] - st[nom + N_BG + 2])
    a = (st[a_at] - st[nom + N_BA], st[a_at + 1] - st[nom + N_BA + 1], st[a_at + 2] - st[nom + N_BA + 2])
    q = _nom_quat(st)
    # the specific force rotated with the attitude at the interval's middle: the error of
    # rotating it with the start attitude grows with the rate (a 45 deg/s pitch rate tilts
    # it by 0.2 deg over a 10 ms tick, which the filter would take for a bias)
    dq, ra = _transition_blocks(q, w, a, dt, st, E_F_BLOCKS)
    decay = math.exp(-dt / params[K_WANDER_TAU])
    st[E_F_BLOCKS + F_DECAY] = decay
    for i in range(3):
        ae = ra[i] - params[K_G] if i == 2 else ra[i]
        st[nom + N_POS + i] += dt * st[nom + N_VEL + i] + 0.5 * dt * dt * ae
        st[nom + N_VEL + i] += dt * ae
        st[nom + N_GW + i] *= decay  # the Gauss-Markov wander's mean decays toward zero
    qn = _qmul(q, dq)
    norm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for i in range(4):
        st[nom + N_Q + i] = qn[i] / norm
    # covariance: P <- F P F^T (P is symmetric: the updates keep it so), then Q on the
    # diagonal
    _apply_f(st, E_COV, N_ERR, N_ERR, st, E_F_BLOCKS, dt)
    _f_rows(st, st, E_F_BLOCKS, dt)
    for i in range(3):
        st[E_COV + (D_ATT + i) * (N_ERR + 1)] += params[K_Q_GYRO] * dt
        st[E_COV + (D_VEL + i) * (N_ERR + 1)] += params[K_Q_ACCEL] * dt
        st[E_COV + (D_BG + i) * (N_ERR + 1)] += params[K_Q_GYRO_WALK] * dt
        st[E_COV + (D_BA + i) * (N_ERR + 1)] += params[K_Q_ACCEL_WALK] * dt
        st[E_COV + (D_GW + i) * (N_ERR + 1)] += params[K_WANDER_VAR + i] * (1.0 - decay * decay)
        st[E_COV + (D_BM + i) * (N_ERR + 1)] += params[K_Q_MAG_WALK] * dt


# ------------------------------------------------------------------ corrections


@njit
def _prepare(st: FloatArray, m: int) -> float:
    """The first half of fusing ``m`` scalar measurements ``y_i = h_i dx + v_i`` (rows
    ``h_i`` in the scratch ``E_HM``, ``y_i`` against the nominal state in ``E_Y``,
    ``v_i ~ N(0, r_i)`` with ``r_i`` in ``E_R``) one after the other: ``K_i = P_i h_i /
    S_i``, ``dx += K_i (y_i - h_i dx)`` (the scratch ``E_DX``, cleared here), ``P_{i+1} =
    P_i - K_i (P_i h_i)^T``. A vector with uncorrelated components fused one component at
    a time equals the batch update. ``P_i h_i = P h_i - sum_k<i K_k (P_k h_k)^T h_i``
    needs only the ``P h`` of the ones before, so ``P`` is only read here and written once
    by :func:`_commit`, which a measurement the gate refuses never reaches. Returns the
    NIS, ``y^T S^-1 y = sum_i nu_i^2 / S_i`` with ``nu_i`` the sequential innovations, and
    leaves ``diag(S)`` in ``E_S_DIAG``."""
    n = _wide(st, N_ERR)
    _zero(st, E_DX, N_ERR)
    nis = 0.0
    for i in range(m):
        h, ph, nz = E_HM + i * N_ERR, E_PH + i * N_ERR, E_NZ + i * N_ERR
        for c in range(n):
            st[ph + c] = 0.0
        innov = st[E_Y + i]
        unit = -1  # the row's shape, for the log: h_att + a single 1
        fits = True
        n_nz = 0
        for j in range(N_ERR):
            hj = st[h + j]
            if hj != 0.0:  # H rows are sparse: a few ones or a heading Jacobian
                st[nz + n_nz] = j
                n_nz += 1
                innov -= hj * st[E_DX + j]
                for c in range(n):  # row j of P: its column j (P is symmetric)
                    st[ph + c] += st[E_COV + j * N_ERR + c] * hj
                if not D_ATT <= j < D_ATT + 3:
                    fits = fits and hj == 1.0 and unit < 0
                    unit = j
        st[E_NZ_N + i] = n_nz
        st[E_UNIT + i] = unit if fits else -1.0
        st[E_S_DIAG + i] = _sparse_dot(st, i, ph) + st[E_R + i]
        for k in range(i):  # what the updates before took off P h_i
            phk = E_PH + k * N_ERR
            f = _sparse_dot(st, i, phk) / st[E_S_UPD + k]
            for c in range(n):
                st[ph + c] -= st[phk + c] * f
        s = _sparse_dot(st, i, ph) + st[E_R + i]
        st[E_S_UPD + i] = s
        st[E_NU + i] = innov
        nis += innov * innov / s
        k_nu = innov / s
        for c in range(n):
            st[E_DX + c] += st[ph + c] * k_nu
    return nis


@njit
def _sparse_dot(st: FloatArray, i: int, x: int) -> float:
    """``h_i . x`` for row ``i`` of H (scratch ``E_HM``) and ``x`` at ``st[x:]``, over the
    columns :func:`_prepare` found it not zero in (in their order: the sum of the scan of
    the whole row, without the scan)."""
    h, nz = E_HM + i * N_ERR, E_NZ + i * N_ERR
    v = 0.0
    for k in range(int(st[E_NZ_N + i])):
        j = int(st[nz + k])
        v += st[h + j] * st[x + j]
    return v


@njit
def _commit(st: FloatArray, m: int) -> None:
    """The second half of :func:`_prepare`: ``P -= sum g_i g_i^T`` with ``g_i = P_i h_i /
    sqrt(S_i)``; every product ``g_a g_b`` is the same for ``(a, b)`` and ``(b, a)``, so
    ``P`` stays exactly symmetric, and its rows are its columns. The updates are logged
    where ``E_LOG_REC`` says; ``dx`` is left for :func:`_inject`."""
    n = _wide(st, N_ERR)
    for i in range(m):
        sq = 1.0 / math.sqrt(st[E_S_UPD + i])
        ph, g = E_PH + i * N_ERR, E_G + i * N_ERR
        for c in range(n):
            st[g + c] = st[ph + c] * sq
    if st[E_LOG_REC] >= 0.0:
        for i in range(m):
            _log_update(st, int(st[E_LOG_REC]), i)
    _downdate(st, m)


@njit
def _downdate(st: FloatArray, m: int) -> None:
    """``P -= sum_i g_i g_i^T`` for the ``m`` vectors in the scratch ``E_G``: three at a
    time, so P is read and written once for a magnetometer sample."""
    n = _wide(st, N_ERR)
    i = 0
    while m - i >= 3:
        g0, g1, g2 = E_G + i * N_ERR, E_G + (i + 1) * N_ERR, E_G + (i + 2) * N_ERR
        for a in range(N_ERR):
            a0, a1, a2 = st[g0 + a], st[g1 + a], st[g2 + a]
            row = E_COV + a * N_ERR
            for b in range(n):
                st[row + b] -= a0 * st[g0 + b] + a1 * st[g1 + b] + a2 * st[g2 + b]
        i += 3
    for k in range(i, m):
        g = E_G + k * N_ERR
        for a in range(N_ERR):
            ga = st[g + a]
            row = E_COV + a * N_ERR
            for b in range(n):
                st[row + b] -= ga * st[g + b]


@njit
def _log_update(st: FloatArray, rec: int, i: int) -> None:
    """Keep scalar update ``i`` of :func:`_prepare` in record ``rec`` for a late fix
    (:func:`_fuse_late_gps`); an update of another shape than ``h_att`` + a single 1, or
    one too many, ends the record's use for that."""
    rec = _nn(rec)
    k = int(st[rec + R_N_UPD])
    unit = st[E_UNIT + i]
    if k >= MAX_UPD or unit < 0.0:
        st[rec + R_XC_OK] = 0.0
        return
    u = rec + R_UPD + k * UPD_SIZE
    _copy(st, u + U_PH, E_PH + i * N_ERR, N_ERR)
    _copy(st, u + U_H_ATT, E_HM + i * N_ERR + D_ATT, 3)
    st[u + U_H_UNIT] = unit
    st[u + U_S] = st[E_S_UPD + i]
    st[u + U_NU] = st[E_NU + i]
    st[rec + R_N_UPD] = k + 1


@njit
def _inject(st: FloatArray, dx: FloatArray, at: int = 0) -> None:
    """Fold the error mean ``dx[at:]`` into the nominal state (the reset Jacobian taken as
    identity, Sola 2017 s. 6.3: its effect is second order in d_theta)."""
    nom = E_NOM
    dq = _qexp(dx[at + D_ATT], dx[at + D_ATT + 1], dx[at + D_ATT + 2])
    qn = _qmul(_nom_quat(st), dq)
    norm = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    for i in range(4):
        st[nom + N_Q + i] = qn[i] / norm
    for i in range(3):
        st[nom + N_VEL + i] += dx[at + D_VEL + i]
        st[nom + N_POS + i] += dx[at + D_POS + i]
        st[nom + N_BG + i] += dx[at + D_BG + i]
        st[nom + N_BA + i] += dx[at + D_BA + i]
        st[nom + N_GW + i] += dx[at + D_GW + i]
        st[nom + N_BM + i] += dx[at + D_BM + i]


@njit
def _cholesky_nis(st: FloatArray, m: int) -> float:
    """``y^T S^-1 y`` for the innovations ``y`` (scratch ``E_Y``) and their covariance ``S``
    (scratch ``E_S``, m x m row-major, its lower triangle): Cholesky, inf if not positive.
    ``L`` is left in ``E_CHOL`` (column j at ``j m + j``..) and ``L^-1 y`` in ``E_CHOL_Z``.
    Right-looking: each pivot's column is taken off the rest at once, whole columns at a
    time; every element sees the same subtractions in the same order as in the textbook's
    row-by-row form."""
    low, z = E_CHOL, E_CHOL_Z
    for j in range(m):
        for i in range(j, m):
            st[low + j * m + i] = st[E_S + i * m + j]
        st[z + j] = st[E_Y + j]
    for k in range(m):
        col = low + k * m
        v = st[col + k]
        if v <= 0.0:
            return math.inf
        d = math.sqrt(v)
        st[col + k] = d
        for i in range(k + 1, m):
            st[col + i] = st[col + i] / d
        for j in range(k + 1, m):
            ljk = st[col + j]
            for i in range(j, m):
                st[low + j * m + i] -= st[col + i] * ljk
    # forward substitution L z = y, column by column (the same order for each element)
    for k in range(m):
        col = low + k * m
        zk = st[z + k] / st[col + k]
        st[z + k] = zk
        for i in range(k + 1, m):
            st[z + i] -= st[col + i] * zk
    total = 0.0  # a loop, not ``zz @ zz``: numba's 1-D @ is a BLAS call for a handful of terms
    for i in range(m):
        total += st[z + i] * st[z + i]
    return total


@njit
def _gps_rows(params: FloatArray, st: FloatArray, use_vel: bool) -> int:
    """``H`` (rows: position N, W, U, then velocity) in the scratch ``E_HM``; its row count."""
    m = 6 if use_vel else 3
    _zero(st, E_HM, MAX_Y * N_ERR)
    for i in range(3):
        st[E_HM + i * N_ERR + D_POS + i] = 1.0
        if params[K_WANDER_VAR + i] > 0.0:
            st[E_HM + i * N_ERR + D_GW + i] = 1.0
        if use_vel:
            st[E_HM + (3 + i) * N_ERR + D_VEL + i] = 1.0
    return m


@njit
def _gps_r(params: FloatArray, i: int) -> float:
    """The white variance of row ``i`` of :func:`_gps_rows`."""
    return float(params[K_R_GPS_POS + i] if i < 3 else params[K_R_GPS_VEL + i - 3])


@njit
def _reset_gps(params: FloatArray, st: FloatArray, pos: int, vel: int, use_vel: bool) -> None:
    """Position (and velocity) set to the fix (at ``st[pos:]``, ``st[vel:]``), the wander
    zeroed, their covariance rows cleared and their variances set to the fix's: a
    receiver that jumped is believed."""
    nom = st[E_NOM : E_NOM + N_NOM]
    p = _cov(st)
    for i in range(3):
        nom[N_POS + i] = st[pos + i]
        nom[N_GW + i] = 0.0
        if use_vel:
            nom[N_VEL + i] = st[vel + i]
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
def _gate_gps(params: FloatArray, st: FloatArray, t_fix: float, m: int, nis: float) -> float:
    """The chi-square gate of a fix (its NIS; innovations in ``E_Y``, the diagonal of their
    covariance in ``E_S_DIAG``; ``m`` = 3: position only), its log and counters; the flag
    it ends with."""
    use_vel = m == 6
    st[E_NIS] = nis
    st[E_T_INNOV] = t_fix
    for i in range(3):
        st[E_INNOV_POS + i], st[E_S_POS + i] = st[E_Y + i], st[E_S_DIAG + i]
        st[E_INNOV_VEL + i] = st[E_Y + 3 + i] if use_vel else math.nan
        st[E_S_VEL + i] = st[E_S_DIAG + 3 + i] if use_vel else math.nan
    st[E_T_FIX_SEEN] = max(st[E_T_FIX_SEEN], t_fix)
    gate = params[K_GATE_6] if use_vel else params[K_GATE_3]
    flag = gate_outcome(st, nis, gate, params[K_MAX_REJECTS], E_N_FIX, E_N_CONSEC, E_N_RESET, E_N_REJECT)
    if flag == M_NONE:
        return M_NONE
    if flag == M_ACCEPTED:
        st[E_T_FIX_GATED] = max(st[E_T_FIX_GATED], t_fix)
    st[E_T_FIX] = max(st[E_T_FIX], t_fix)
    return flag


@njit
def _apply_gps(params: FloatArray, st: FloatArray, flag: float, t_fix: float, pos: int, vel: int) -> float:
    """Fuse one fix (position at ``st[pos:]``, velocity at ``st[vel:]``, NaN: none) into the
    filter as it is now (its validity time). A pending fix is gated on the NIS of the
    whole fix and logged; returns the flag it ends with."""
    use_vel = _finite3(st, vel)
    m = _gps_rows(params, st, use_vel)
    for i in range(3):
        st[E_Y + i] = st[pos + i] - st[E_NOM + N_POS + i] - st[E_NOM + N_GW + i]
        if use_vel:
            st[E_Y + 3 + i] = st[vel + i] - st[E_NOM + N_VEL + i]
    for i in range(m):
        st[E_R + i] = _gps_r(params, i)
    nis = _prepare(st, m)
    if flag == M_PENDING:
        flag = _gate_gps(params, st, t_fix, m, nis)
        if flag == M_NONE:
            return flag
    if flag == M_RESET:
        _reset_gps(params, st, pos, vel, use_vel)
        return flag
    _commit(st, m)
    _inject(st, st, E_DX)
    return flag


@njit
def _apply_baro(params: FloatArray, st: FloatArray, flag: float, z: float) -> float:
    y = z - st[E_NOM + N_POS + 2]
    if flag == M_PENDING:
        s = st[E_COV + (D_POS + 2) * (N_ERR + 1)] + params[K_R_BARO]
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
    _zero(st, E_HM, N_ERR)
    st[E_HM + D_POS + 2] = 1.0
    st[E_Y] = y
    st[E_R] = params[K_R_BARO]
    _prepare(st, 1)
    _commit(st, 1)
    _inject(st, st, E_DX)
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
def _apply_mag(params: FloatArray, st: FloatArray, flag: float, t_meas: float, field: int) -> float:
    """Fuse a magnetometer sample (at ``st[field:]``) as the three components of the body
    field: the measurement less the calibration offsets against ``R^T m`` of the earth's
    field at home. A 3-axis fusion and not a heading: where the field is steep (68 deg of
    inclination at the default home) a heading levelled with a roll error of 1 deg is off
    by up to 2.5 deg, which a heading fusion would book as a yaw error."""
    r = _qrot(_nom_quat(st))
    m0, m1, m2 = params[K_MAG_FIELD], params[K_MAG_FIELD + 1], params[K_MAG_FIELD + 2]
    # the rows of H = [J 0 ... I], J = [R^T m]x (mag_jacobian)
    mb = (r[0] * m0 + r[3] * m1 + r[6] * m2, r[1] * m0 + r[4] * m1 + r[7] * m2,
          r[2] * m0 + r[5] * m1 + r[8] * m2)  # fmt: skip
    h = E_HM
    _zero(st, h, 3 * N_ERR)
    st[h + D_ATT + 1], st[h + D_ATT + 2] = -mb[2], mb[1]
    st[h + N_ERR + D_ATT], st[h + N_ERR + D_ATT + 2] = mb[2], -mb[0]
    st[h + 2 * N_ERR + D_ATT], st[h + 2 * N_ERR + D_ATT + 1] = -mb[1], mb[0]
    for i in range(3):
        st[h + i * N_ERR + D_BM + i] = 1.0
        st[E_Y + i] = st[field + i] - params[K_MAG_OFFSETS + i] - st[E_NOM + N_BM + i] - mb[i]
    for i in range(3):
        st[E_R + i] = params[K_R_MAG]
    nis = _prepare(st, 3)
    if flag == M_PENDING:
        y0, y1, y2 = st[E_Y], st[E_Y + 1], st[E_Y + 2]
        st[E_MAG_NIS] = nis
        st[E_MAG_S] = st[E_S_DIAG] + st[E_S_DIAG + 1] + st[E_S_DIAG + 2]
        st[E_MAG_INNOV] = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        st[E_T_MAG_SEEN] = max(st[E_T_MAG_SEEN], t_meas)
        # a field persistently away from the prediction (an attitude that drifted while the
        # compass was off, a touchdown, a bad start) is believed after ten times the GPS's
        # run of rejections: realigned
        flag = gate_outcome(st, nis, params[K_GATE_3], params[K_MAX_REJECTS] * 10.0, E_N_MAG, E_N_MAG_CONSEC,
                            E_N_MAG_RESET, E_N_MAG_REJECT)  # fmt: skip
        if flag == M_NONE:
            return M_NONE
        if flag == M_ACCEPTED:
            st[E_T_MAG_OK] = max(st[E_T_MAG_OK], t_meas)
    if flag == M_RESET:
        m = np.empty(3)
        for i in range(3):
            m[i] = st[field + i] - params[K_MAG_OFFSETS + i] - st[E_NOM + N_BM + i]
        _realign(params, st, m)
        return flag
    _commit(st, 3)
    _inject(st, st, E_DX)
    return flag


@njit
def _apply(params: FloatArray, st: FloatArray, rec: int, kind: int, flag: float, at_end: bool) -> float:
    """Fuse record ``rec``'s measurement of ``kind``; ``at_end``: the filter is at the end
    of the record's interval (its updates are logged there for a late fix to be carried
    through; a GPS update, a reset, or an update inside the interval is not)."""
    t_meas = st[rec + R_T0]
    st[E_LOG_REC] = rec if at_end and kind != _GPS else -1.0
    if not at_end or kind == _GPS:
        st[rec + R_XC_OK] = 0.0
    if kind == _GPS:
        flag = _apply_gps(params, st, flag, t_meas + st[rec + R_GPS_TAU], rec + R_GPS_POS, rec + R_GPS_VEL)
    elif kind == _BARO:
        flag = _apply_baro(params, st, flag, st[rec + R_BARO_Z])
    else:
        flag = _apply_mag(params, st, flag, t_meas + st[rec + R_MAG_TAU], rec + R_MAG_FIELD)
    st[E_LOG_REC] = -1.0
    if flag == M_RESET:
        st[rec + R_XC_OK] = 0.0
    return flag


# ------------------------------------------------------------------ the buffer


_BIG = 1.7976931348623157e308  # the largest float64
_FLAG = (R_GPS_FLAG, R_BARO_FLAG, R_MAG_FLAG)
_TAU = (R_GPS_TAU, R_BARO_TAU, R_MAG_TAU)


@njit
def _replay_record(params: FloatArray, st: FloatArray, rec: int) -> float:
    """Propagate the filter over record ``rec``'s interval, fusing its measurements at their
    validity times in time order; returns the final flag of a pending one (M_NONE if none)."""
    result = M_NONE
    done = 0.0
    dt = st[rec + R_DT]
    st[rec + R_XC_OK] = 1.0
    st[rec + R_STALE] = 0.0
    st[rec + R_N_UPD] = 0.0
    pending = 0  # bit k: measurement k still to fuse
    for k in range(3):
        if st[rec + _FLAG[k]] != M_NONE:
            pending |= 1 << k
    for _ in range(3):
        kind = -1
        for k in range(3):
            if pending & (1 << k) and (kind < 0 or st[rec + _TAU[k]] < st[rec + _TAU[kind]]):
                kind = k
        if kind < 0:
            break
        tau = st[rec + _TAU[kind]]
        _propagate_rec(params, st, rec, tau - done)
        done = tau
        old = st[rec + _FLAG[kind]]
        new = _apply(params, st, rec, kind, old, tau >= dt)
        st[rec + _FLAG[kind]] = new
        pending &= ~(1 << kind)
        if old == M_PENDING:
            result = new
    _propagate_rec(params, st, rec, dt - done)
    return result


@njit
def _propagate_rec(params: FloatArray, st: FloatArray, rec: int, dt: float) -> None:
    """:func:`_propagate_at` over a part of record ``rec``'s interval with its IMU sample,
    its F kept there; a second part, or one after an update, ends the record's use for a
    late fix."""
    if dt <= 0.0:
        return
    if st[rec + R_N_UPD] > 0.0 or dt < st[rec + R_DT]:
        st[rec + R_XC_OK] = 0.0
    _propagate_at(params, st, rec + R_GYRO, rec + R_ACCEL, dt)
    _copy(st, rec + R_FB, E_F_BLOCKS, FB_SIZE)


@njit
def _replay(params: FloatArray, st: FloatArray, age_from: int) -> float:
    """Re-run the filter from the start of record ``age_from`` to now, rewriting the later
    records' start states; the flag the pending measurement ends with."""
    result = M_NONE
    for age in range(age_from, -1, -1):
        rec = _rec(params, st, age)
        if age == age_from:
            _copy(st, E_NOM, rec + R_NOM0, N_NOM)
            _unpack_cov(st, rec + R_COV0)
        else:
            _copy(st, rec + R_NOM0, E_NOM, N_NOM)
            _pack_cov(st, rec + R_COV0)
        flag = _replay_record(params, st, rec)
        if flag != M_NONE:
            result = flag
    return result


@njit
def _locate(params: FloatArray, st: FloatArray, t_meas: float) -> tuple[int, float]:
    """The record ``t_meas`` falls in (its age) and how far into it; a time within
    ``T_SNAP_S`` of a tick is at the tick, the start of the next interval (the end of the
    newest, now)."""
    for age in range(int(st[E_COUNT])):
        rec = _rec(params, st, age)
        tau = t_meas - st[rec + R_T0]
        if tau >= -T_SNAP_S:
            dt = st[rec + R_DT]
            if tau >= dt - T_SNAP_S:
                return (age - 1, 0.0) if age > 0 else (0, dt)
            return age, max(tau, 0.0)
    return -1, 0.0


@njit
def _carried(params: FloatArray, st: FloatArray, age: int) -> bool:
    """Whether a fix valid at the start of record ``age`` can be fused now through its
    cross-covariance (:func:`_fuse_late_gps`): the record's start state has every earlier
    fix in it, and each interval since is one propagation and logged updates (no other
    fix, no reset)."""
    ok = bool(st[_rec(params, st, age) + R_STALE] == 0.0)
    for a in range(age, -1, -1):
        ok = ok and st[_rec(params, st, a) + R_XC_OK] == 1.0
    return ok


@njit
def _hx(params: FloatArray, st: FloatArray, x: int, n: int, c: int) -> float:
    """Row ``c`` of the GPS's H (position N, W, U with the wander, then velocity) times the
    column of the ``N_ERR``-row matrix at ``st[x:]`` (row stride ``n``)."""
    if c >= 3:
        return float(st[x + (D_VEL + c - 3) * n])
    v = float(st[x + (D_POS + c) * n])
    if params[K_WANDER_VAR + c] > 0.0:
        v += st[x + (D_GW + c) * n]
    return v


@njit
def _fuse_late_gps(params: FloatArray, st: FloatArray, age: int) -> float:
    """Fuse the fix valid at the start of record ``age`` into the filter as it is now,
    without running the filter again: with ``z = H x_s + v`` and the updates since
    ``t_s``, the joint Gaussian of ``x_now`` and ``H x_s`` is carried forward, and the fix
    conditions ``x_now`` on it (docs/estimator.md, "Late fixes"). ``C = Cov(x, H x_s)``
    starts as ``P_s H^T`` and goes ``C <- F C`` over each interval (the process noise after
    ``t_s`` is independent of ``x_s``) and ``C <- C - K (h^T C)`` at each scalar update of
    gain ``K = P h / S``, which also takes ``(h^T C)^T (h^T C) / S`` off ``V = Var(H x_s)``
    and adds ``(h^T C)^T nu / S`` to ``E[H x_s]``. Then ``x_now += C S^-1 (z - E[H x_s])``
    and ``P -= C S^-1 C^T`` with ``S = V + R``: the replay's result for a linear filter
    (conditioning does not depend on the order), here to first order in the correction,
    as the filter's own linearisation. Gated as a fix fused at its time; the flag it
    ends with."""
    rec_s = _nn(_rec(params, st, age))
    pos, vel = rec_s + R_GPS_POS, rec_s + R_GPS_VEL
    use_vel = _finite3(st, vel)
    m = 6 if use_vel else 3
    n = XC_W
    # C, V, E[H x_s] and an update's h^T C / S in arrays of their own (made once a fix):
    # the compiler then sees that the loops writing them read nothing they write, and runs
    # them wide, which scratch in the state (one array to it) does not allow
    xc = np.zeros(N_ERR * XC_W)
    v = np.zeros(XC_W * XC_W)
    mu = np.zeros(XC_W)
    w = np.zeros(XC_W)
    _unpack_cov(st, rec_s + R_COV0, E_COV_S)
    nom0 = rec_s + R_NOM0
    for r in range(N_ERR):  # P_s H^T: row r of P_s times H^T (P_s symmetric)
        for c in range(m):
            xc[r * n + c] = _hx(params, st, E_COV_S + r * N_ERR, 1, c)
    for c in range(m):
        for d in range(m):
            v[c * n + d] = _hx(params, xc, d, n, c)
        mu[c] = st[nom0 + N_VEL + c - 3] if c >= 3 else st[nom0 + N_POS + c] + st[nom0 + N_GW + c]
    for a in range(age, -1, -1):
        rec = _nn(_rec(params, st, a))
        _apply_f(xc, 0, n, n, st, rec + R_FB, st[rec + R_DT])
        for k in range(int(st[rec + R_N_UPD])):
            u = _nn(rec + R_UPD + k * UPD_SIZE)
            unit, inv_s, nu = _nn(int(st[u + U_H_UNIT])), 1.0 / st[u + U_S], st[u + U_NU]
            h0, h1, h2 = st[u + U_H_ATT], st[u + U_H_ATT + 1], st[u + U_H_ATT + 2]
            for c in range(n):  # h^T C, then over S
                w[c] = (h0 * xc[D_ATT * n + c] + h1 * xc[(D_ATT + 1) * n + c] + h2 * xc[(D_ATT + 2) * n + c]
                        + xc[unit * n + c]) * inv_s  # fmt: skip
            for r in range(N_ERR):
                kr = st[u + U_PH + r]
                for c in range(n):
                    xc[r * n + c] -= kr * w[c]
            s_u = st[u + U_S]
            for c in range(m):
                wc = w[c]
                mu[c] += wc * nu
                wcs = wc * s_u
                for d in range(c, m):  # the upper triangle: V is symmetric
                    v[c * n + d] -= wcs * w[d]
    # the fix's innovation and its covariance, gated as at its time
    for c in range(m):
        st[E_Y + c] = (st[vel + c - 3] if c >= 3 else st[pos + c]) - mu[c]
        for d in range(m):
            st[E_S + c * m + d] = v[c * n + d] if d >= c else v[d * n + c]
        st[E_S + c * m + c] += _gps_r(params, c)
    for c in range(m):
        st[E_S_DIAG + c] = st[E_S + c * m + c]
    flag = _gate_gps(params, st, st[rec_s + R_T0], m, _cholesky_nis(st, m))
    st[rec_s + R_GPS_FLAG] = flag
    if flag == M_RESET:  # a receiver that jumped is believed from its time on
        _replay(params, st, age)
        return flag
    if flag != M_ACCEPTED:
        return flag
    # S = L L^T (left by the gate), z = L^-1 (z - E[H x_s]): with C' = C L^-T the update is
    # m scalar ones, dx = C' z and P -= C' C'^T
    low, z = E_CHOL, E_CHOL_Z
    for k in range(m):
        w[k] = 1.0 / st[low + k * m + k]
    _zero(st, E_DX, N_ERR)
    for r in range(N_ERR):
        row = r * n
        for k in range(m):
            xk = xc[row + k] * w[k]
            st[E_G + k * N_ERR + r] = xk
            st[E_DX + r] += xk * st[z + k]
            for i in range(k + 1, m):
                xc[row + i] -= st[low + k * m + i] * xk
    _downdate(st, m)
    _inject(st, st, E_DX)
    # the start states since t_s miss this fix: no replay starts there, and no later late
    # fix is carried across it
    for a in range(age - 1, -1, -1):
        st[_rec(params, st, a) + R_STALE] = 1.0
    st[_rec(params, st, 0) + R_XC_OK] = 0.0
    return flag


@njit
def _validity(params: FloatArray, st: FloatArray, t_meas: float) -> float:
    if math.isnan(st[E_T]) or not math.isfinite(t_meas) or t_meas > st[E_T] + params[K_T_TOL]:
        return math.nan
    return float(min(t_meas, st[E_T]))


@njit
def _measure(
    params: FloatArray, st: FloatArray, kind: int, t_meas: float, a: FloatArray, a_at: int, b: FloatArray,
    b_at: int,
) -> int:  # fmt: skip
    """Fuse a measurement of ``kind`` valid at ``t_meas``: ``a[a_at:]`` the GPS position, the
    baro height (``a[a_at]``) or the body field; ``b[b_at:]`` the GPS velocity (NaN: none)."""
    if math.isnan(st[E_T]):
        return NOT_STARTED
    t = _validity(params, st, t_meas)
    if math.isnan(t) or not _finite3(a, a_at):
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
        use_vel = params[K_USE_VEL] > 0.5 and _finite3(b, b_at)
        for i in range(3):
            st[rec + R_GPS_POS + i] = a[a_at + i]
            st[rec + R_GPS_VEL + i] = b[b_at + i] if use_vel else math.nan
    elif kind == _BARO:
        st[rec + R_BARO_Z] = a[a_at]
    else:
        for i in range(3):
            st[rec + R_MAG_FIELD + i] = a[a_at + i]
    if age == 0 and tau >= st[rec + R_DT]:
        # valid at the end of the newest interval, which is now: fuse into the present
        flag = _apply(params, st, rec, kind, M_PENDING, True)
        st[rec + _FLAG[kind]] = flag
    elif kind == _GPS and tau == 0.0 and _carried(params, st, age):
        flag = _fuse_late_gps(params, st, age)
    else:
        while age < st[E_COUNT] and st[_rec(params, st, age) + R_STALE] != 0.0:
            age += 1  # back to a start state that has every fix in it
        if age >= st[E_COUNT]:
            st[rec + _FLAG[kind]] = M_NONE
            st[E_N_TOO_OLD] += 1.0
            return TOO_OLD
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
    st[E_LOG_REC] = -1.0


@njit
def est_predict(params: FloatArray, st: FloatArray, t_s: float, gyro: FloatArray, accel: FloatArray) -> int:
    """One IMU tick to ``t_s``: the sample is taken as valid over (t, t_s]; a bad sample
    holds the last good one. The first call only sets the time."""
    return _predict(params, st, t_s, gyro, 0, accel, 0)


@njit
def _predict(
    params: FloatArray, st: FloatArray, t_s: float, gyro: FloatArray, g_at: int, accel: FloatArray, a_at: int
) -> int:
    """:func:`est_predict` with the sample at ``gyro[g_at:]``, ``accel[a_at:]``."""
    status = P_OK
    if _finite3(gyro, g_at) and _finite3(accel, a_at):
        _copy(st, E_GYRO_PREV, E_GYRO, 3)
        _copy(st, E_ACCEL_PREV, E_ACCEL, 3)
        for i in range(3):
            st[E_GYRO + i] = gyro[g_at + i]
            st[E_ACCEL + i] = accel[a_at + i]
    else:
        status = P_BAD_IMU
        st[E_N_BAD_IMU] += 1.0
    if math.isnan(st[E_T]):
        st[E_T] = t_s
        st[E_T_FIX] = t_s
        st[E_T_FIX_GATED] = t_s
        st[E_T_MAG_OK] = t_s
        _copy(st, E_GYRO_PREV, E_GYRO, 3)
        _copy(st, E_ACCEL_PREV, E_ACCEL, 3)
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
    _copy(st, rec + R_NOM0, E_NOM, N_NOM)
    _pack_cov(st, rec + R_COV0)
    st[rec + R_GPS_FLAG] = M_NONE
    st[rec + R_BARO_FLAG] = M_NONE
    st[rec + R_MAG_FLAG] = M_NONE
    st[rec + R_XC_OK] = 1.0
    st[rec + R_STALE] = 0.0
    st[rec + R_N_UPD] = 0.0
    _propagate_rec(params, st, rec, dt)
    st[E_T] = t_s
    return status


@njit
def est_gps(params: FloatArray, st: FloatArray, t_fix: float, pos: FloatArray, vel: FloatArray) -> int:
    """Fuse a GPS fix valid at ``t_fix`` (<= now) at its validity time."""
    return _measure(params, st, _GPS, t_fix, pos, 0, vel, 0)


@njit
def est_baro(params: FloatArray, st: FloatArray, t_meas: float, alt_m: float) -> int:
    """Fuse a barometric height above home valid at ``t_meas``."""
    for i in range(3):
        st[E_BARO_IN + i] = alt_m
    return _measure(params, st, _BARO, t_meas, st, E_BARO_IN, st, E_BARO_IN)


@njit
def est_mag(params: FloatArray, st: FloatArray, t_meas: float, field_flu: FloatArray) -> int:
    """Fuse a magnetometer sample (body FLU, gauss) valid at ``t_meas`` as a heading."""
    return _measure(params, st, _MAG, t_meas, field_flu, 0, field_flu, 0)


@njit
def _check_divergence(params: FloatArray, st: FloatArray) -> None:
    """Latch ``diverged`` when the state or covariance is not finite, or when a sensor that
    is delivering has had no measurement inside its gate for ``divergence_s``."""
    t = st[E_T]
    lim = params[K_DIVERGENCE_S]
    # the nominal state and the covariance finite: a comparison false for NaN and inf,
    # and-ed over the block without an early exit (a loop the compiler runs wide)
    finite = True
    for i in range(E_NOM, E_COV + N_COV):
        finite &= abs(st[i]) <= _BIG
    bad = not finite
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
    nom = E_NOM
    r = _qrot(_nom_quat(st))
    v0, v1, v2 = st[nom + N_VEL], st[nom + N_VEL + 1], st[nom + N_VEL + 2]
    for i in range(3):
        x_out[X_N + i] = st[nom + N_POS + i]
        x_out[U_F + i] = r[i] * v0 + r[3 + i] * v1 + r[6 + i] * v2
        x_out[PHI + 3 + i] = st[E_GYRO + i] - st[nom + N_BG + i]
    # euler_from_rot's
    x_out[PHI] = math.atan2(r[7], r[8])
    x_out[THETA] = math.asin(max(-1.0, min(1.0, -r[6])))
    x_out[PSI] = math.atan2(r[3], r[0])


@njit
def est_tick(
    params: FloatArray, st: FloatArray, t_s: float, meas: FloatArray, mask: int, x_out: FloatArray
) -> int:
    """One control tick on the measurement layout (latest sample of each sensor, ``mask``
    the new ones): predict with the IMU sample, fuse a new GPS fix, baro height and
    magnetometer heading at their validity times, write the estimate. Returns the GPS
    status (``NO_FIX`` when none was new)."""
    _predict(params, st, t_s, meas, OUT_GYRO, meas, OUT_ACCEL)
    if params[K_USE_MAG] > 0.5 and mask & NEW_MAG:
        _measure(params, st, _MAG, meas[OUT_MAG_T], meas, OUT_MAG, meas, OUT_MAG)
    if params[K_USE_BARO] > 0.5 and mask & NEW_BARO:
        est_baro(params, st, meas[OUT_BARO_T], meas[OUT_BARO_ALT])
    status = NO_FIX
    if mask & NEW_GPS:
        status = _measure(params, st, _GPS, meas[OUT_GPS_T], meas, OUT_GPS_POS, meas, OUT_GPS_VEL)
    _check_divergence(params, st)
    est_output(st, x_out)
    return status


@njit
def log_tick(st: FloatArray, gps_status: int, row: FloatArray) -> None:
    """One row of :data:`~autopilot.estimation.log.EST_LOG_COLUMNS` for the tick just
    estimated."""
    nom = E_NOM
    r = _qrot(_nom_quat(st))
    fix = gps_status != NO_FIX
    b0, b1, b2 = st[nom + N_BA], st[nom + N_BA + 1], st[nom + N_BA + 2]
    for i in range(3):
        row[L_SD_POS + i] = math.sqrt(max(st[E_COV + (D_POS + i) * (N_ERR + 1)], 0.0))
        row[L_SD_VEL + i] = math.sqrt(max(st[E_COV + (D_VEL + i) * (N_ERR + 1)], 0.0))
        row[L_BIAS + i] = r[3 * i] * b0 + r[3 * i + 1] * b1 + r[3 * i + 2] * b2
        row[L_INNOV + i] = st[E_INNOV_POS + i] if fix else math.nan
        row[L_SD_ATT + i] = math.sqrt(max(st[E_COV + (D_ATT + i) * (N_ERR + 1)], 0.0))
        row[L_GYRO_BIAS + i] = st[nom + N_BG + i]
        row[L_SD_GYRO_BIAS + i] = math.sqrt(max(st[E_COV + (D_BG + i) * (N_ERR + 1)], 0.0))
        row[L_ACCEL_BIAS + i] = st[nom + N_BA + i]
        row[L_SD_ACCEL_BIAS + i] = math.sqrt(max(st[E_COV + (D_BA + i) * (N_ERR + 1)], 0.0))
    row[L_GPS_STATUS] = gps_status
    row[L_NIS] = st[E_NIS] if fix else math.nan
    row[L_SINCE_FIX] = st[E_T] - st[E_T_FIX]
    row[L_MAG_INNOV] = st[E_MAG_INNOV]
    row[L_MAG_NIS] = st[E_MAG_NIS]
    row[L_DIVERGED] = st[E_DIVERGED]
    for i in range(L_NEES, row.size):  # the truth's columns: filled where a simulation knows it
        row[i] = math.nan


@njit
def nav_error(st: FloatArray, x_true: FloatArray, gyro_bias_true: Vec3, accel_bias_true: Vec3,
              err: FloatArray, at: int = 0) -> None:  # fmt: skip
    """The true error of the navigation states (the first ``N_NAV`` of the error state, into
    ``err[at:]``) from the truth: ``d_theta = Log(R^T R_true)``, the velocity and position
    errors in earth NWU, the bias errors. Only a simulation knows it: for NEES and tests."""
    nom = E_NOM
    r = _qrot(_nom_quat(st))
    rt = _rot_euler(x_true[PHI], x_true[THETA], x_true[PSI])

    def d(i: int, j: int) -> float:  # (R^T R_true)[i, j]
        return r[i] * rt[j] + r[3 + i] * rt[3 + j] + r[6 + i] * rt[6 + j]

    c = max(-1.0, min(1.0, 0.5 * (d(0, 0) + d(1, 1) + d(2, 2) - 1.0)))
    angle = math.acos(c)
    k = 0.5 if angle < 1e-8 else 0.5 * angle / math.sin(angle)
    err[at + D_ATT] = k * (d(2, 1) - d(1, 2))
    err[at + D_ATT + 1] = k * (d(0, 2) - d(2, 0))
    err[at + D_ATT + 2] = k * (d(1, 0) - d(0, 1))
    for i in range(3):
        v = rt[3 * i] * x_true[U_F] + rt[3 * i + 1] * x_true[V_L] + rt[3 * i + 2] * x_true[W_U]
        err[at + D_VEL + i] = v - st[nom + N_VEL + i]
        err[at + D_POS + i] = x_true[X_N + i] - st[nom + N_POS + i]
        err[at + D_BG + i] = gyro_bias_true[i] - st[nom + N_BG + i]
        err[at + D_BA + i] = accel_bias_true[i] - st[nom + N_BA + i]


@njit
def nees(st: FloatArray, err: FloatArray, at: int = 0) -> float:
    """The normalised estimation error squared of the navigation states,
    ``e^T P_nav^-1 e`` (``e`` at ``err[at:]``) with ``P_nav`` their block of the covariance
    (the marginal)."""
    # Gaussian elimination of [[P_nav, e], [e^T, 0]]: its last pivot ends as -e^T P_nav^-1 e
    # (the Schur complement), and an elimination without pivoting meets a pivot <= 0 where
    # P_nav is not positive definite. The matrix stays symmetric through it, so only the
    # upper triangle is read: row j takes f_kj = a_kj / a_kk times the pivot row. Whole rows
    # of 16, the same width every time, are what the compiler runs widest (two vector
    # operations a row); the columns left of a row's diagonal fill with values never read.
    m = N_NAV + 1
    a = E_CHOL
    for i in range(N_NAV):
        for j in range(i, N_NAV):
            st[a + i * m + j] = st[E_COV + i * N_ERR + j]
        st[a + i * m + N_NAV] = err[at + i]
    st[a + m * m - 1] = 0.0
    width = _wide(st, m)
    for k in range(N_NAV):
        d = st[a + k * m + k]
        if d <= 0.0:
            return math.inf
        r = 1.0 / d
        for j in range(k + 1, m):
            f = st[a + k * m + j] * r
            for c in range(width):
                st[a + j * m + c] -= f * st[a + k * m + c]
    return -float(st[a + m * m - 1])


@njit
def truth_log(st: FloatArray, x_true: FloatArray, gyro_bias_true: Vec3, accel_bias_true: Vec3,
              row: FloatArray) -> None:  # fmt: skip
    """The log's truth columns: the NEES over the navigation states and the true attitude
    and gyro-bias errors (the true error kept in the scratch ``E_ERR``)."""
    nav_error(st, x_true, gyro_bias_true, accel_bias_true, st, E_ERR)
    row[L_NEES] = nees(st, st, E_ERR)
    for i in range(3):
        row[L_ATT_ERR + i] = st[E_ERR + D_ATT + i]
        row[L_GYRO_BIAS_ERR + i] = st[E_ERR + D_BG + i]


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
