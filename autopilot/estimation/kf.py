"""The state estimator: compiled kernels over flat arrays and a thin class around them.

Position and velocity come from three independent linear Kalman filters, one per earth
axis (NWU), each with the state ``[p, v, b]``: position, velocity and an earth-frame
acceleration bias. Every tick predicts with the earth-frame acceleration
``a_E = R(attitude) f_b + (0, 0, -g)`` (the bias is subtracted inside the model); GPS fixes
(position and velocity) and barometric heights are fused at their time of validity
although they arrive late, by re-running the filter from a buffer of past ticks. Attitude is
the attitude source's (AHRS) output, optionally low-passed, dead-reckoned with the gyro
between samples; body rates are the gyro less a configured bias. docs/estimator.md has the
equations, the tuning and the test results.

Layouts (all ``float64``; the names are the only way code refers to an element):

* ``params`` (``N_PARAMS``): the tuning, built by :func:`make_params` (``K_*``).
* ``state`` (``state_size(n_buf)``): the filter (``E_*``) followed by a ring buffer of
  ``n_buf`` records of ``N_REC`` values (``R_*``). Filter values are per axis: ``E_X + N_AX a``
  holds ``[p, v, b]`` (``I_*``) of axis ``a`` (0 north, 1 west, 2 up), ``E_P + N_COV a`` its
  3x3 covariance, row-major (``COV_*``).
* a record covers one tick interval ``[t0, t0 + dt]``: the filter at ``t0`` (``R_X0``,
  ``R_P0``), the input over the interval (``R_A``, ``R_QA``), and the GPS fix and baro
  height whose validity time falls inside it (``R_GPS_*``, ``R_BARO_*``), so the interval
  can be replayed.

No I/O and no clock: time is an argument.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.gating import M_ACCEPTED, M_NONE, M_PENDING, M_RESET, chi2_quantile, gate_outcome
from autopilot.estimation.log import (
    L_BIAS,
    L_DIVERGED,
    L_GPS_STATUS,
    L_INNOV,
    L_NIS,
    L_SD_ATT,
    L_SD_POS,
    L_SD_VEL,
    L_SINCE_FIX,
)
from heli_common.jit import njit
from heli_common.kinematics import euler_rates, rot_body_to_earth, wrap_pi
from heli_common.layout import Layout
from heli_common.state import EULER, N_STATE, OMEGA, P_X, PHI, PSI, THETA, U_F, V_L, W_U, X_N, FloatArray
from heli_common.wire.measurements import (
    NEW_ATT,
    NEW_BARO,
    NEW_GPS,
    OUT_ACCEL,
    OUT_ATT,
    OUT_BARO_ALT,
    OUT_BARO_T,
    OUT_GPS_POS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    AttitudeSample,
    BaroSample,
    GpsFix,
    ImuSample,
)

# --- per-axis filter state [p, v, b] and the axes
AXIS_STATE = Layout("estimator axis state", ("p", 1), ("v", 1), ("b", 1))
I_P = AXIS_STATE.offset("p")
I_V = AXIS_STATE.offset("v")
I_B = AXIS_STATE.offset("b")
N_AX = AXIS_STATE.size  # states per axis
AX_N, AX_W, AX_U = 0, 1, 2
N_AXES = 3  # north, west, up: one filter each
N_COV = N_AX * N_AX  # one axis' covariance, row-major: element (i, j) at N_AX * i + j
COV_PP = N_AX * I_P + I_P
COV_PV = N_AX * I_P + I_V
COV_PB = N_AX * I_P + I_B
COV_VP = N_AX * I_V + I_P
COV_VV = N_AX * I_V + I_V
COV_VB = N_AX * I_V + I_B
COV_BP = N_AX * I_B + I_P
COV_BV = N_AX * I_B + I_V
COV_BB = N_AX * I_B + I_B
N_FX = N_AXES * N_AX  # the filter state of every axis: E_X + N_AX a holds axis a's
N_FP = N_AXES * N_COV  # the covariance of every axis: E_P + N_COV a holds axis a's

# --- params (K_*)
PARAMS = Layout(
    "estimator parameters",
    ("g", 1),  # gravity [m/s^2]
    ("qa", 1),  # accelerometer white noise PSD [(m/s^2)^2/Hz]
    ("qatt", 1),  # attitude-noise variance times the nominal tick [rad^2 s]
    ("qb", 1),  # bias random-walk PSD [(m/s^2)^2/s]
    ("p0_pos", 1),  # initial variances
    ("p0_vel", 1),
    ("p0_bias", 1),
    ("r_pos", N_AXES),  # GPS position variance per axis
    ("r_vel", N_AXES),  # GPS velocity variance per axis
    ("use_vel", 1),  # 1: fuse GPS velocity
    ("gate_pos", 1),  # chi-square threshold, 3 dof (position only)
    ("gate_pos_vel", 1),  # 6 dof (position and velocity)
    ("gate_baro", 1),  # 1 dof
    ("max_rejects", 1),
    ("gps_timeout", 1),  # [s]
    ("r_baro", 1),  # baro variance [m^2]
    ("n_buf", 1),  # records in the ring buffer
    ("gyro_bias", 3),  # [rad/s]
    ("att_tau", 1),  # attitude low-pass time constant [s], 0: pass-through
    ("rate_tau", 1),  # rate low-pass time constant [s], 0: pass-through
    ("dt_nom", 1),  # nominal tick [s]
    ("t_tol", 1),  # a validity time up to this far after "now" is taken as now [s]
)
K_G = PARAMS.offset("g")
K_QA = PARAMS.offset("qa")
K_QATT = PARAMS.offset("qatt")
K_QB = PARAMS.offset("qb")
K_P0_POS = PARAMS.offset("p0_pos")
K_P0_VEL = PARAMS.offset("p0_vel")
K_P0_BIAS = PARAMS.offset("p0_bias")
K_R_POS = PARAMS.offset("r_pos")
K_R_VEL = PARAMS.offset("r_vel")
K_USE_VEL = PARAMS.offset("use_vel")
K_GATE_POS = PARAMS.offset("gate_pos")
K_GATE_POS_VEL = PARAMS.offset("gate_pos_vel")
K_GATE_BARO = PARAMS.offset("gate_baro")
K_MAX_REJECTS = PARAMS.offset("max_rejects")
K_GPS_TIMEOUT = PARAMS.offset("gps_timeout")
K_R_BARO = PARAMS.offset("r_baro")
K_N_BUF = PARAMS.offset("n_buf")
K_GYRO_BIAS = PARAMS.offset("gyro_bias")
K_ATT_TAU = PARAMS.offset("att_tau")
K_RATE_TAU = PARAMS.offset("rate_tau")
K_DT_NOM = PARAMS.offset("dt_nom")
K_T_TOL = PARAMS.offset("t_tol")
N_PARAMS = PARAMS.size

# --- filter (E_*); the ring buffer of records follows at E_HIST
FILTER = Layout(
    "estimator filter",
    ("t", 1),  # time of the estimate [s]; NaN until the first predict
    ("x", N_FX),  # [p, v, b] per axis
    ("p", N_FP),  # 3x3 covariance per axis
    ("att", 3),  # Euler ZYX [rad]
    ("rate", 3),  # body rates FLU [rad/s]
    ("a", N_AXES),  # last earth-frame acceleration input R f + g_E [m/s^2]
    ("qa", N_AXES),  # last acceleration noise PSD per axis
    ("t_fix", 1),  # validity time of the newest accepted GPS fix (the first tick before any)
    ("n_fix", 1),  # accepted GPS fixes
    ("n_reject", 1),  # fixes rejected by the gate
    ("n_consec", 1),  # consecutive rejected fixes
    ("n_too_old", 1),  # measurements older than the buffer (dropped)
    ("n_bad", 1),  # measurements with a non-finite value or a validity time in the future
    ("n_reset", 1),  # position/velocity re-initialised from a fix after repeated rejections
    ("n_baro", 1),  # accepted baro heights
    ("n_baro_reject", 1),
    ("n_bad_imu", 1),  # ticks with a non-finite gyro or accelerometer (last value held)
    ("nis", 1),  # normalised innovation squared of the last GPS fix (gated or not)
    ("t_innov", 1),  # its validity time
    ("innov_pos", N_AXES),  # position innovation z - H x [m]
    ("innov_vel", N_AXES),  # velocity innovation [m/s] (NaN when not fused)
    ("s_pos", N_AXES),  # innovation variances and covariance per axis
    ("s_vel", N_AXES),
    ("s_pv", N_AXES),
    ("baro_innov", 1),
    ("baro_s", 1),
    ("baro_nis", 1),
    ("head", 1),  # ring-buffer slot of the newest record
    ("count", 1),  # records held
)
E_T = FILTER.offset("t")
E_X = FILTER.offset("x")
E_P = FILTER.offset("p")
E_ATT = FILTER.offset("att")
E_RATE = FILTER.offset("rate")
E_A = FILTER.offset("a")
E_QA = FILTER.offset("qa")
E_T_FIX = FILTER.offset("t_fix")
E_N_FIX = FILTER.offset("n_fix")
E_N_REJECT = FILTER.offset("n_reject")
E_N_CONSEC = FILTER.offset("n_consec")
E_N_TOO_OLD = FILTER.offset("n_too_old")
E_N_BAD = FILTER.offset("n_bad")
E_N_RESET = FILTER.offset("n_reset")
E_N_BARO = FILTER.offset("n_baro")
E_N_BARO_REJECT = FILTER.offset("n_baro_reject")
E_N_BAD_IMU = FILTER.offset("n_bad_imu")
E_NIS = FILTER.offset("nis")
E_T_INNOV = FILTER.offset("t_innov")
E_INNOV_POS = FILTER.offset("innov_pos")
E_INNOV_VEL = FILTER.offset("innov_vel")
E_S_POS = FILTER.offset("s_pos")
E_S_VEL = FILTER.offset("s_vel")
E_S_PV = FILTER.offset("s_pv")
E_BARO_INNOV = FILTER.offset("baro_innov")
E_BARO_S = FILTER.offset("baro_s")
E_BARO_NIS = FILTER.offset("baro_nis")
E_HEAD = FILTER.offset("head")
E_COUNT = FILTER.offset("count")
E_HIST = FILTER.end  # first record
N_FILTER = FILTER.size

# --- one record of the ring buffer (R_*), relative to its start
RECORD = Layout(
    "estimator record",
    ("t0", 1),  # start of the interval [s]
    ("dt", 1),  # its length [s]
    ("a", N_AXES),  # earth-frame acceleration input over the interval
    ("qa", N_AXES),  # acceleration noise PSD per axis
    ("x0", N_FX),  # filter state at t0
    ("p0", N_FP),  # covariance at t0
    ("gps_flag", 1),  # M_* below
    ("gps_tau", 1),  # validity time - t0
    ("gps_pos", N_AXES),
    ("gps_vel", N_AXES),  # NaN: position only
    ("baro_flag", 1),
    ("baro_tau", 1),
    ("baro_z", 1),
)
R_T0 = RECORD.offset("t0")
R_DT = RECORD.offset("dt")
R_A = RECORD.offset("a")
R_QA = RECORD.offset("qa")
R_X0 = RECORD.offset("x0")
R_P0 = RECORD.offset("p0")
R_GPS_FLAG = RECORD.offset("gps_flag")
R_GPS_TAU = RECORD.offset("gps_tau")
R_GPS_POS = RECORD.offset("gps_pos")
R_GPS_VEL = RECORD.offset("gps_vel")
R_BARO_FLAG = RECORD.offset("baro_flag")
R_BARO_TAU = RECORD.offset("baro_tau")
R_BARO_Z = RECORD.offset("baro_z")
N_REC = RECORD.size


# status of est_gps / est_baro
ACCEPTED, REJECTED, RESET, TOO_OLD, BAD_INPUT, NOT_STARTED = 0, 1, 2, 3, 4, 5
NO_FIX = -1  # est_tick: no new fix this tick
# status of est_predict
P_OK, P_FIRST, P_NO_ADVANCE, P_BAD_IMU = 0, 1, 2, 3

_TAU_EPS = 1e-9  # slack on the interval bounds [s]

# what _innovation hands back for one axis: the innovations and their covariance
_INNOV = Layout("innovation", ("yp", 1), ("yv", 1), ("spp", 1), ("spv", 1), ("svv", 1))
_IN_YP = _INNOV.offset("yp")
_IN_YV = _INNOV.offset("yv")
_IN_SPP = _INNOV.offset("spp")
_IN_SPV = _INNOV.offset("spv")
_IN_SVV = _INNOV.offset("svv")
_N_INNOV = _INNOV.size


def state_size(n_buf: int) -> int:
    return N_FILTER + n_buf * N_REC


def make_params(config: EstimatorConfig, rate_hz: float) -> FloatArray:
    """The flat parameter vector of the kernels for ``config`` at tick rate ``rate_hz``."""
    if not 10.0 <= rate_hz <= 2000.0:
        raise ValueError(f"estimator rate must be in [10, 2000] Hz, got {rate_hz}")
    dt = 1.0 / rate_hz
    k = np.zeros(N_PARAMS)
    k[K_G] = config.gravity_m_s2
    k[K_QA] = config.accel_noise_density**2
    k[K_QATT] = config.attitude_noise_rad**2 * dt
    k[K_QB] = config.accel_bias_walk**2
    k[K_P0_POS] = config.init_pos_sigma_m**2
    k[K_P0_VEL] = config.init_vel_sigma_m_s**2
    k[K_P0_BIAS] = config.init_accel_bias_sigma**2
    k[K_R_POS : K_R_POS + N_AXES] = np.square(config.gps_pos_sigma_m)
    k[K_R_VEL : K_R_VEL + N_AXES] = np.square(config.gps_vel_sigma_m_s)
    k[K_USE_VEL] = 1.0 if config.use_gps_velocity else 0.0
    k[K_GATE_POS] = chi2_quantile(config.gate_probability, 3)
    k[K_GATE_POS_VEL] = chi2_quantile(config.gate_probability, 6)
    k[K_GATE_BARO] = chi2_quantile(config.gate_probability, 1)
    k[K_MAX_REJECTS] = config.max_consecutive_rejects
    k[K_GPS_TIMEOUT] = config.gps_timeout_s
    k[K_R_BARO] = config.baro_sigma_m**2
    k[K_N_BUF] = math.ceil(config.buffer_s * rate_hz) + 2
    k[K_GYRO_BIAS : K_GYRO_BIAS + 3] = config.gyro_bias_rad_s
    k[K_ATT_TAU] = config.attitude_lpf_tau_s
    k[K_RATE_TAU] = config.rate_lpf_tau_s
    k[K_DT_NOM] = dt
    k[K_T_TOL] = 0.5 * dt
    return k


def axis_model(dt: float, qa: float, qb: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(F, B, Q)`` of one axis over ``dt`` (x' = F x + B a + w, w ~ N(0, Q)); the kernels
    inline the same algebra. ``qa``: acceleration white-noise PSD, ``qb``: bias-walk PSD."""
    h = 0.5 * dt * dt
    f = np.array([[1.0, dt, -h], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
    b = np.array([h, dt, 0.0])
    d2, d3 = dt * dt, dt * dt * dt
    q = qa * np.array([[d3 / 3.0, d2 / 2.0, 0.0], [d2 / 2.0, dt, 0.0], [0.0, 0.0, 0.0]]) + qb * np.array(
        [
            [d3 * d2 / 20.0, d2 * d2 / 8.0, -d3 / 6.0],
            [d2 * d2 / 8.0, d3 / 3.0, -d2 / 2.0],
            [-d3 / 6.0, -d2 / 2.0, dt],
        ]
    )
    return f, b, q


# ------------------------------------------------------------------ compiled kernels


@njit
def _finite3(v: FloatArray) -> bool:
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


@njit
def _rec(params: FloatArray, st: FloatArray, age: int) -> int:
    """Offset of the record ``age`` ticks before the newest (0: newest)."""
    n = int(params[K_N_BUF])
    slot = (int(st[E_HEAD]) - age) % n
    return E_HIST + slot * N_REC


@njit
def _predict_axis(st: FloatArray, ax: int, dt: float, a: float, qa: float, qb: float) -> None:
    """x <- F x + B a, P <- F P F' + Q for axis ``ax`` over ``dt`` (axis_model, written out)."""
    xo = E_X + N_AX * ax
    po = E_P + N_COV * ax
    h = 0.5 * dt * dt
    p, v, b = st[xo + I_P], st[xo + I_V], st[xo + I_B]
    st[xo + I_P] = p + dt * v - h * b + h * a
    st[xo + I_V] = v - dt * b + dt * a
    p00, p01, p02 = st[po + COV_PP], st[po + COV_PV], st[po + COV_PB]
    p11, p12, p22 = st[po + COV_VV], st[po + COV_VB], st[po + COV_BB]
    # A = F P (rows), then F P F'
    a00 = p00 + dt * p01 - h * p02
    a01 = p01 + dt * p11 - h * p12
    a02 = p02 + dt * p12 - h * p22
    a11 = p11 - dt * p12
    a12 = p12 - dt * p22
    n00 = a00 + dt * a01 - h * a02
    n01 = a01 - dt * a02
    n02 = a02
    n11 = a11 - dt * a12
    n12 = a12
    n22 = p22
    d2 = dt * dt
    d3 = d2 * dt
    n00 += qa * d3 / 3.0 + qb * d3 * d2 / 20.0
    n01 += qa * d2 / 2.0 + qb * d2 * d2 / 8.0
    n02 += -qb * d3 / 6.0
    n11 += qa * dt + qb * d3 / 3.0
    n12 += -qb * d2 / 2.0
    n22 += qb * dt
    st[po + COV_PP], st[po + COV_PV], st[po + COV_PB] = n00, n01, n02
    st[po + COV_VP], st[po + COV_VV], st[po + COV_VB] = n01, n11, n12
    st[po + COV_BP], st[po + COV_BV], st[po + COV_BB] = n02, n12, n22


@njit
def _propagate(params: FloatArray, st: FloatArray, rec: int, dt: float) -> None:
    if dt <= 0.0:
        return
    for ax in range(N_AXES):
        _predict_axis(st, ax, dt, st[rec + R_A + ax], st[rec + R_QA + ax], params[K_QB])


@njit
def _innovation(
    st: FloatArray, ax: int, zp: float, zv: float, rp: float, rv: float, use_vel: bool, out: FloatArray
) -> float:
    """Innovation of axis ``ax`` and its covariance into ``out`` = (y_p, y_v, S_pp, S_pv, S_vv);
    returns the normalised innovation squared y' S^-1 y."""
    xo = E_X + N_AX * ax
    po = E_P + N_COV * ax
    yp = zp - st[xo + I_P]
    spp = st[po + COV_PP] + rp
    out[_IN_YP], out[_IN_SPP] = yp, spp
    if not use_vel:
        out[_IN_YV], out[_IN_SPV], out[_IN_SVV] = math.nan, math.nan, math.nan
        return float(yp * yp / spp)
    yv = zv - st[xo + I_V]
    spv = st[po + COV_PV]
    svv = st[po + COV_VV] + rv
    out[_IN_YV], out[_IN_SPV], out[_IN_SVV] = yv, spv, svv
    det = spp * svv - spv * spv
    return float((svv * yp * yp - 2.0 * spv * yp * yv + spp * yv * yv) / det)


@njit
def _correct_axis(st: FloatArray, ax: int, zp: float, zv: float, rp: float, rv: float, use_vel: bool) -> None:
    """Kalman update of axis ``ax`` with H = [1 0 0] (position) or [[1 0 0], [0 1 0]] (and
    velocity); Joseph form P = (I - K H) P (I - K H)' + K R K'."""
    xo = E_X + N_AX * ax
    po = E_P + N_COV * ax
    p = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            p[i, j] = st[po + N_AX * i + j]
    # gain K = P H' S^-1 (3 x 2; column 1 unused without velocity)
    k = np.zeros((3, 2))
    yp = zp - st[xo + I_P]
    yv = 0.0
    if use_vel:
        yv = zv - st[xo + I_V]
        spp, spv, svv = p[0, 0] + rp, p[0, 1], p[1, 1] + rv
        det = spp * svv - spv * spv
        for i in range(3):
            k[i, 0] = (p[i, 0] * svv - p[i, 1] * spv) / det
            k[i, 1] = (p[i, 1] * spp - p[i, 0] * spv) / det
    else:
        for i in range(3):
            k[i, 0] = p[i, 0] / (p[0, 0] + rp)
    for i in range(3):
        st[xo + i] += k[i, 0] * yp + k[i, 1] * yv
    # A = I - K H; P <- A P A' + K R K'
    a = np.eye(3)
    for i in range(3):
        a[i, 0] -= k[i, 0]
        a[i, 1] -= k[i, 1]
    ap = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for m in range(3):
                ap[i, j] += a[i, m] * p[m, j]
    for i in range(3):
        for j in range(i, 3):
            v = k[i, 0] * rp * k[j, 0] + k[i, 1] * rv * k[j, 1]
            for m in range(3):
                v += ap[i, m] * a[j, m]
            st[po + N_AX * i + j] = v
            st[po + N_AX * j + i] = v


@njit
def _reset_axis(st: FloatArray, ax: int, zp: float, zv: float, rp: float, rv: float, use_vel: bool) -> None:
    """Position (and velocity) of axis ``ax`` set to the fix, with the fix's variance and no
    correlation to the rest; the bias and its variance are kept."""
    xo = E_X + N_AX * ax
    po = E_P + N_COV * ax
    st[xo + I_P] = zp
    n = 2 if use_vel else 1
    if use_vel:
        st[xo + I_V] = zv
    for i in range(n):
        for j in range(3):
            st[po + N_AX * i + j] = 0.0
            st[po + N_AX * j + i] = 0.0
    st[po + COV_PP] = rp
    if use_vel:
        st[po + COV_VV] = rv


@njit
def _apply_gps(
    params: FloatArray, st: FloatArray, flag: float, t_fix: float, pos: FloatArray, vel: FloatArray
) -> float:
    """Fuse one fix into the filter as it is now (the validity time). A pending fix is gated
    and logged; returns the flag it ends with (accepted, reset, or none if rejected)."""
    use_vel = _finite3(vel)
    if flag == M_PENDING:
        buf = np.empty(_N_INNOV)
        nis = 0.0
        for ax in range(N_AXES):
            nis += _innovation(
                st, ax, pos[ax], vel[ax], params[K_R_POS + ax], params[K_R_VEL + ax], use_vel, buf
            )
            st[E_INNOV_POS + ax], st[E_INNOV_VEL + ax] = buf[_IN_YP], buf[_IN_YV]
            st[E_S_POS + ax], st[E_S_PV + ax], st[E_S_VEL + ax] = buf[_IN_SPP], buf[_IN_SPV], buf[_IN_SVV]
        st[E_NIS] = nis
        st[E_T_INNOV] = t_fix
        gate = params[K_GATE_POS_VEL] if use_vel else params[K_GATE_POS]
        flag = gate_outcome(st, nis, gate, params[K_MAX_REJECTS], E_N_FIX, E_N_CONSEC, E_N_RESET, E_N_REJECT)
        if flag == M_NONE:
            return M_NONE
        st[E_T_FIX] = max(st[E_T_FIX], t_fix)
    for ax in range(N_AXES):
        rp, rv = params[K_R_POS + ax], params[K_R_VEL + ax]
        if flag == M_RESET:
            _reset_axis(st, ax, pos[ax], vel[ax], rp, rv, use_vel)
        else:
            _correct_axis(st, ax, pos[ax], vel[ax], rp, rv, use_vel)
    return flag


@njit
def _apply_baro(params: FloatArray, st: FloatArray, flag: float, z: float) -> float:
    if flag == M_PENDING:
        buf = np.empty(_N_INNOV)
        nis = _innovation(st, AX_U, z, 0.0, params[K_R_BARO], 0.0, False, buf)
        st[E_BARO_INNOV], st[E_BARO_S], st[E_BARO_NIS] = buf[_IN_YP], buf[_IN_SPP], nis
        if nis > params[K_GATE_BARO]:
            st[E_N_BARO_REJECT] += 1.0
            return M_NONE
        flag = M_ACCEPTED
        st[E_N_BARO] += 1.0
    _correct_axis(st, AX_U, z, 0.0, params[K_R_BARO], 0.0, False)
    return flag


@njit
def _replay(params: FloatArray, st: FloatArray, age_from: int) -> float:
    """Re-run the filter from the start of record ``age_from`` to now, fusing each record's
    measurements at their validity times and rewriting the later records' start states.
    Returns the final flag of the pending measurement met on the way (M_NONE if none)."""
    result = M_NONE
    for age in range(age_from, -1, -1):
        rec = _rec(params, st, age)
        if age == age_from:
            st[E_X : E_X + N_FX] = st[rec + R_X0 : rec + R_X0 + N_FX]
            st[E_P : E_P + N_FP] = st[rec + R_P0 : rec + R_P0 + N_FP]
        else:
            st[rec + R_X0 : rec + R_X0 + N_FX] = st[E_X : E_X + N_FX]
            st[rec + R_P0 : rec + R_P0 + N_FP] = st[E_P : E_P + N_FP]
        gps_on = st[rec + R_GPS_FLAG] != M_NONE
        baro_on = st[rec + R_BARO_FLAG] != M_NONE
        t_g, t_b = st[rec + R_GPS_TAU], st[rec + R_BARO_TAU]
        done = 0.0
        for _ in range(2):  # at most one fix and one height per record, in time order
            do_gps = gps_on and (not baro_on or t_g <= t_b)
            if not (do_gps or baro_on):
                break
            tau = t_g if do_gps else t_b
            _propagate(params, st, rec, tau - done)
            done = tau
            t_meas = st[rec + R_T0] + tau
            if do_gps:
                old = st[rec + R_GPS_FLAG]
                pos = st[rec + R_GPS_POS : rec + R_GPS_POS + N_AXES]
                vel = st[rec + R_GPS_VEL : rec + R_GPS_VEL + N_AXES]
                new = _apply_gps(params, st, old, t_meas, pos, vel)
                st[rec + R_GPS_FLAG] = new
                gps_on = False
            else:
                old = st[rec + R_BARO_FLAG]
                new = _apply_baro(params, st, old, st[rec + R_BARO_Z])
                st[rec + R_BARO_FLAG] = new
                baro_on = False
            if old == M_PENDING:
                result = new
        _propagate(params, st, rec, st[rec + R_DT] - done)
    return result


@njit
def _locate(params: FloatArray, st: FloatArray, t_meas: float) -> tuple[int, float]:
    """The newest record whose interval [t0, t0 + dt] holds ``t_meas`` and the offset into
    it; age -1 if older than the buffer."""
    for age in range(int(st[E_COUNT])):
        rec = _rec(params, st, age)
        tau = t_meas - st[rec + R_T0]
        if tau >= 0.0:
            return age, min(tau, st[rec + R_DT])
    return -1, 0.0


@njit
def _validity(params: FloatArray, st: FloatArray, t_meas: float) -> float:
    """``t_meas`` clamped to now if just after it; NaN if not usable."""
    if math.isnan(st[E_T]) or not math.isfinite(t_meas) or t_meas > st[E_T] + params[K_T_TOL]:
        return math.nan
    return float(min(t_meas, st[E_T]))


@njit
def est_init(params: FloatArray, st: FloatArray, x0: FloatArray) -> None:
    """Start from the 12-state ``x0`` (NWU position, FLU velocity, Euler, rates) with the
    configured initial covariance; counters cleared; time unset until the first predict."""
    st[:] = 0.0
    st[E_T] = math.nan
    r = rot_body_to_earth(x0[PHI], x0[THETA], x0[PSI])
    for ax in range(N_AXES):
        xo = E_X + N_AX * ax
        po = E_P + N_COV * ax
        st[xo + I_P] = x0[X_N + ax]
        st[xo + I_V] = r[ax, 0] * x0[U_F] + r[ax, 1] * x0[V_L] + r[ax, 2] * x0[W_U]
        st[xo + I_B] = 0.0
        st[po + COV_PP] = params[K_P0_POS]
        st[po + COV_VV] = params[K_P0_VEL]
        st[po + COV_BB] = params[K_P0_BIAS]
    st[E_ATT : E_ATT + 3] = x0[EULER]
    st[E_RATE : E_RATE + 3] = x0[OMEGA]
    for ax in range(N_AXES):
        st[E_QA + ax] = params[K_QA]
    st[E_NIS] = math.nan
    st[E_T_INNOV] = math.nan
    for ax in range(N_AXES):
        st[E_INNOV_POS + ax] = math.nan
        st[E_INNOV_VEL + ax] = math.nan
        st[E_S_POS + ax] = math.nan
        st[E_S_VEL + ax] = math.nan
        st[E_S_PV + ax] = math.nan
    st[E_BARO_INNOV], st[E_BARO_S], st[E_BARO_NIS] = math.nan, math.nan, math.nan
    st[E_HEAD] = 0.0
    st[E_COUNT] = 0.0


@njit
def est_predict(
    params: FloatArray, st: FloatArray, t_s: float, gyro: FloatArray, accel: FloatArray, att: FloatArray
) -> int:
    """Advance the estimate to ``t_s`` with the gyro and the specific force ``accel`` (body FLU)
    and, if finite, the attitude sample ``att`` (Euler ZYX); NaN ``att``: none this tick (the
    attitude is then dead-reckoned with the gyro). The first call only sets the time."""
    status = P_OK
    has_att = _finite3(att)
    if math.isnan(st[E_T]):
        st[E_T] = t_s
        st[E_T_FIX] = t_s
        if has_att:
            st[E_ATT : E_ATT + 3] = att
        if _finite3(gyro):
            for i in range(3):
                st[E_RATE + i] = gyro[i] - params[K_GYRO_BIAS + i]
        return P_FIRST
    dt = t_s - st[E_T]
    if not dt > 0.0:
        return P_NO_ADVANCE

    # rates: gyro less the configured bias, optionally low-passed
    if _finite3(gyro):
        alpha = dt / (params[K_RATE_TAU] + dt)
        for i in range(3):
            w = gyro[i] - params[K_GYRO_BIAS + i]
            st[E_RATE + i] = w if alpha == 1.0 else st[E_RATE + i] + alpha * (w - st[E_RATE + i])
    else:
        status = P_BAD_IMU
    # attitude: the AHRS sample (optionally low-passed), else dead-reckoned with the gyro
    if has_att and params[K_ATT_TAU] > 0.0:
        alpha = dt / (params[K_ATT_TAU] + dt)
        for i in range(3):
            st[E_ATT + i] = wrap_pi(st[E_ATT + i] + alpha * wrap_pi(att[i] - st[E_ATT + i]))
    elif has_att:
        st[E_ATT : E_ATT + 3] = att
    else:
        de = euler_rates(st[E_ATT], st[E_ATT + 1], st[E_RATE], st[E_RATE + 1], st[E_RATE + 2])
        for i in range(3):
            st[E_ATT + i] = wrap_pi(st[E_ATT + i] + dt * de[i])
    # earth-frame acceleration and its noise
    if _finite3(accel):
        r = rot_body_to_earth(st[E_ATT], st[E_ATT + 1], st[E_ATT + 2])
        f2 = accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2]
        for i in range(3):
            fe = r[i, 0] * accel[0] + r[i, 1] * accel[1] + r[i, 2] * accel[2]
            st[E_A + i] = fe
            st[E_QA + i] = params[K_QA] + params[K_QATT] * (f2 - fe * fe)
        st[E_A + 2] -= params[K_G]
    else:
        status = P_BAD_IMU
    if status == P_BAD_IMU:
        st[E_N_BAD_IMU] += 1.0

    # new record for (t, t_s], then propagate
    n = int(params[K_N_BUF])
    head = (int(st[E_HEAD]) + 1) % n
    st[E_HEAD] = head
    st[E_COUNT] = min(st[E_COUNT] + 1.0, n)
    rec = E_HIST + head * N_REC
    st[rec + R_T0] = st[E_T]
    st[rec + R_DT] = dt
    st[rec + R_A : rec + R_A + N_AXES] = st[E_A : E_A + N_AXES]
    st[rec + R_QA : rec + R_QA + N_AXES] = st[E_QA : E_QA + N_AXES]
    st[rec + R_X0 : rec + R_X0 + N_FX] = st[E_X : E_X + N_FX]
    st[rec + R_P0 : rec + R_P0 + N_FP] = st[E_P : E_P + N_FP]
    st[rec + R_GPS_FLAG] = M_NONE
    st[rec + R_BARO_FLAG] = M_NONE
    _propagate(params, st, rec, dt)
    st[E_T] = t_s
    return status


@njit
def est_gps(params: FloatArray, st: FloatArray, t_fix: float, pos: FloatArray, vel: FloatArray) -> int:
    """Fuse a GPS fix valid at ``t_fix`` (<= now): roll back to the buffered filter at
    ``t_fix``, gate and apply the fix there, re-propagate to now with the stored inputs.
    ``vel`` NaN (or velocity fusion off): position only. Returns a status code."""
    if math.isnan(st[E_T]):
        return NOT_STARTED
    t = _validity(params, st, t_fix)
    if math.isnan(t) or not _finite3(pos):
        st[E_N_BAD] += 1.0
        return BAD_INPUT
    use_vel = params[K_USE_VEL] > 0.5 and _finite3(vel)
    age, tau = _locate(params, st, t)
    if age < 0 and t == st[E_T]:  # the first tick: no record yet, fuse into the present
        v = vel.copy() if use_vel else np.full(3, math.nan)
        flag = _apply_gps(params, st, M_PENDING, t, pos, v)
        return ACCEPTED if flag == M_ACCEPTED else RESET if flag == M_RESET else REJECTED
    if age < 0:
        st[E_N_TOO_OLD] += 1.0
        return TOO_OLD
    rec = _rec(params, st, age)
    st[rec + R_GPS_FLAG] = M_PENDING
    st[rec + R_GPS_TAU] = tau
    for i in range(3):
        st[rec + R_GPS_POS + i] = pos[i]
        st[rec + R_GPS_VEL + i] = vel[i] if use_vel else math.nan
    flag = _replay(params, st, age)
    if flag == M_ACCEPTED:
        return ACCEPTED
    return RESET if flag == M_RESET else REJECTED


@njit
def est_baro(params: FloatArray, st: FloatArray, t_meas: float, alt_m: float) -> int:
    """Fuse a barometric height (above home, = z up) valid at ``t_meas``, as est_gps."""
    if math.isnan(st[E_T]):
        return NOT_STARTED
    t = _validity(params, st, t_meas)
    if math.isnan(t) or not math.isfinite(alt_m):
        st[E_N_BAD] += 1.0
        return BAD_INPUT
    age, tau = _locate(params, st, t)
    if age < 0 and t == st[E_T]:
        return ACCEPTED if _apply_baro(params, st, M_PENDING, alt_m) == M_ACCEPTED else REJECTED
    if age < 0:
        st[E_N_TOO_OLD] += 1.0
        return TOO_OLD
    rec = _rec(params, st, age)
    st[rec + R_BARO_FLAG] = M_PENDING
    st[rec + R_BARO_TAU] = tau
    st[rec + R_BARO_Z] = alt_m
    flag = _replay(params, st, age)
    return ACCEPTED if flag == M_ACCEPTED else REJECTED


@njit
def est_output(st: FloatArray, x_out: FloatArray) -> None:
    """The 12-state estimate (heli_common.state layout): body FLU velocity = R' v_E."""
    r = rot_body_to_earth(st[E_ATT], st[E_ATT + 1], st[E_ATT + 2])
    for i in range(3):
        x_out[X_N + i] = st[E_X + N_AX * i + I_P]
    for i in range(3):
        x_out[U_F + i] = (
            r[0, i] * st[E_X + I_V] + r[1, i] * st[E_X + N_AX + I_V] + r[2, i] * st[E_X + 2 * N_AX + I_V]
        )
    for i in range(3):
        x_out[PHI + i] = st[E_ATT + i]
        x_out[P_X + i] = st[E_RATE + i]


@njit
def est_tick(
    params: FloatArray, st: FloatArray, t_s: float, meas: FloatArray, mask: int, use_baro: bool,
    x_out: FloatArray,
) -> int:  # fmt: skip
    """One tick on the measurement layout of :mod:`heli_common.wire.measurements` (``meas`` holds
    each sensor's latest sample, ``mask`` says which are new): predict with the latest IMU
    sample (held between samples), the attitude sample if new; fuse a new GPS fix and (if
    ``use_baro``) a new baro height at their validity times; write the estimate into
    ``x_out``. The in-process loop and the autopilot process both call this. Returns the
    GPS status (``NO_FIX`` when none was new)."""
    att = meas[OUT_ATT : OUT_ATT + 3] if mask & NEW_ATT else np.full(3, math.nan)
    est_predict(params, st, t_s, meas[OUT_GYRO : OUT_GYRO + 3], meas[OUT_ACCEL : OUT_ACCEL + 3], att)
    status = NO_FIX
    if mask & NEW_GPS:
        status = est_gps(params, st, meas[OUT_GPS_T], meas[OUT_GPS_POS : OUT_GPS_POS + 3],
                         meas[OUT_GPS_VEL : OUT_GPS_VEL + 3])  # fmt: skip
    if use_baro and mask & NEW_BARO:
        est_baro(params, st, meas[OUT_BARO_T], meas[OUT_BARO_ALT])
    est_output(st, x_out)
    return status


@njit
def log_tick(st: FloatArray, gps_status: int, row: FloatArray) -> None:
    """One row of :data:`EST_LOG_COLUMNS` for the tick just estimated."""
    for a in range(N_AXES):
        po = E_P + N_COV * a
        row[L_SD_POS + a] = math.sqrt(max(st[po + COV_PP], 0.0))
        row[L_SD_VEL + a] = math.sqrt(max(st[po + COV_VV], 0.0))
        row[L_BIAS + a] = st[E_X + N_AX * a + I_B]
    row[L_GPS_STATUS] = gps_status
    fix = gps_status != NO_FIX
    row[L_NIS] = st[E_NIS] if fix else math.nan
    for a in range(N_AXES):
        row[L_INNOV + a] = st[E_INNOV_POS + a] if fix else math.nan
    row[L_SINCE_FIX] = st[E_T] - st[E_T_FIX]
    # the navigation filter's own columns: this filter has no such states
    row[L_SD_ATT:] = math.nan
    row[L_DIVERGED] = 0.0


# ------------------------------------------------------------------ the Python wrapper


class Innovations(NamedTuple):
    """The last GPS fix's innovations z - H x at its validity time, with their covariance S
    (per axis N, W, U), its NIS, and the last baro innovation. NaN before any."""

    t_s: float
    pos_m: FloatArray
    vel_m_s: FloatArray
    s_pos: FloatArray
    s_vel: FloatArray
    s_pos_vel: FloatArray
    nis: float
    baro_m: float
    s_baro: float


class Health(NamedTuple):
    time_since_fix_s: float  # since the validity time of the newest accepted fix
    gps_lost: bool  # no accepted fix for longer than gps_timeout_s
    n_fixes: int
    n_rejected: int  # by the chi-square gate
    n_consecutive_rejects: int
    n_resets: int  # re-initialised from a fix after max_consecutive_rejects
    n_too_old: int  # older than the buffer, dropped
    n_bad: int  # non-finite, or valid in the future
    n_baro: int
    n_baro_rejected: int
    n_bad_imu: int


class Estimator:
    """The estimator with its state; one :meth:`update` per tick, time passed in."""

    def __init__(self, config: EstimatorConfig, x0: FloatArray, rate_hz: float = 100.0) -> None:
        self.config = config
        self.rate_hz = float(rate_hz)
        self.params = make_params(config, self.rate_hz)
        self.n_buf = int(self.params[K_N_BUF])
        self.state = np.zeros(state_size(self.n_buf))
        self._gyro = np.zeros(3)
        self._accel = np.zeros(3)
        self._att = np.zeros(3)
        self._pos = np.zeros(3)
        self._vel = np.zeros(3)
        self._out = np.zeros(N_STATE)
        self.last_predict_status = P_OK
        self.last_gps_status = ACCEPTED
        self.reset(x0)

    def reset(self, x0: FloatArray) -> None:
        """Restart from the 12-state ``x0`` with the initial covariance; counters cleared."""
        x = np.asarray(x0, dtype=float)
        if x.shape != (N_STATE,) or not np.all(np.isfinite(x)):
            raise ValueError(f"x0 must be a finite ({N_STATE},) state")
        est_init(self.params, self.state, x)
        est_output(self.state, self._out)

    def update(
        self,
        t_s: float,
        imu: ImuSample,
        att: AttitudeSample | None = None,
        gps_fixes: Sequence[GpsFix] = (),
        baro: BaroSample | None = None,
    ) -> FloatArray:
        """Advance to ``t_s`` with this tick's IMU sample (taken as valid now), the attitude
        source's sample if one arrived, the GPS fixes that arrived (each fused at its own
        validity time ``t_s``) and a baro height; returns the 12-state estimate (a new array)."""
        self._gyro[:] = imu.gyro_flu_rad_s
        self._accel[:] = imu.accel_flu_m_s2
        if att is None:
            self._att[:] = math.nan
        else:
            self._att[:] = att.euler_rad
        self.last_predict_status = est_predict(
            self.params, self.state, t_s, self._gyro, self._accel, self._att
        )
        for fix in gps_fixes:
            self._pos[:] = fix.pos_nwu_m
            self._vel[:] = fix.vel_nwu_m_s
            self.last_gps_status = est_gps(self.params, self.state, fix.t_s, self._pos, self._vel)
        if baro is not None and self.config.use_baro:
            est_baro(self.params, self.state, baro.t_s, baro.alt_m)
        est_output(self.state, self._out)
        return self._out.copy()

    def warm_up(self) -> None:
        """Run every kernel once on throwaway copies: numba loads compiled code on a
        function's first call, which a real-time loop's first tick must not pay."""
        st = self.state.copy()
        est_init(self.params, st, np.zeros(N_STATE))
        zero = np.zeros(3)
        acc = np.array([0.0, 0.0, self.config.gravity_m_s2])
        est_predict(self.params, st, 0.0, zero, acc, zero)
        est_predict(self.params, st, 1.0 / self.rate_hz, zero, acc, zero)
        est_gps(self.params, st, 1.0 / self.rate_hz, zero, zero)
        est_baro(self.params, st, 1.0 / self.rate_hz, 0.0)
        est_output(st, np.zeros(N_STATE))

    # --- views for logging and the failsafe
    @property
    def t_s(self) -> float:
        return float(self.state[E_T])

    @property
    def x(self) -> FloatArray:
        """The last 12-state estimate (a copy)."""
        return self._out.copy()

    @property
    def pos_nwu_m(self) -> FloatArray:
        return self.state[E_X + I_P : E_X + N_FX : N_AX].copy()

    @property
    def vel_nwu_m_s(self) -> FloatArray:
        return self.state[E_X + I_V : E_X + N_FX : N_AX].copy()

    @property
    def accel_bias_nwu(self) -> FloatArray:
        """Earth-frame acceleration bias b (the model uses R f + g_E - b)."""
        return self.state[E_X + I_B : E_X + N_FX : N_AX].copy()

    @property
    def covariance(self) -> FloatArray:
        """(3, 3, 3): per axis (N, W, U) the covariance of [p, v, b]."""
        return self.state[E_P : E_P + N_FP].reshape(N_AXES, N_AX, N_AX).copy()

    @property
    def pos_vel_var(self) -> FloatArray:
        """(6,): variances of position N, W, U [m^2] then velocity N, W, U [m^2/s^2] (earth)."""
        p = self.state[E_P : E_P + N_FP].reshape(N_AXES, N_COV)
        return np.concatenate([p[:, COV_PP], p[:, COV_VV]])

    @property
    def innovations(self) -> Innovations:
        s = self.state
        return Innovations(
            t_s=float(s[E_T_INNOV]),
            pos_m=s[E_INNOV_POS : E_INNOV_POS + N_AXES].copy(),
            vel_m_s=s[E_INNOV_VEL : E_INNOV_VEL + N_AXES].copy(),
            s_pos=s[E_S_POS : E_S_POS + N_AXES].copy(),
            s_vel=s[E_S_VEL : E_S_VEL + N_AXES].copy(),
            s_pos_vel=s[E_S_PV : E_S_PV + N_AXES].copy(),
            nis=float(s[E_NIS]),
            baro_m=float(s[E_BARO_INNOV]),
            s_baro=float(s[E_BARO_S]),
        )

    @property
    def health(self) -> Health:
        s = self.state
        since = float(s[E_T] - s[E_T_FIX]) if math.isfinite(s[E_T]) else 0.0
        return Health(
            time_since_fix_s=since,
            gps_lost=bool(since > self.params[K_GPS_TIMEOUT]),
            n_fixes=int(s[E_N_FIX]),
            n_rejected=int(s[E_N_REJECT]),
            n_consecutive_rejects=int(s[E_N_CONSEC]),
            n_resets=int(s[E_N_RESET]),
            n_too_old=int(s[E_N_TOO_OLD]),
            n_bad=int(s[E_N_BAD]),
            n_baro=int(s[E_N_BARO]),
            n_baro_rejected=int(s[E_N_BARO_REJECT]),
            n_bad_imu=int(s[E_N_BAD_IMU]),
        )


__all__ = [
    "Estimator",
    "Health",
    "Innovations",
    "est_baro",
    "est_gps",
    "est_init",
    "est_output",
    "est_predict",
]
