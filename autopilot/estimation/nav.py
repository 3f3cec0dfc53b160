"""The estimator the vehicle flies on, whichever it is: one set of compiled kernels over
one parameter array that names the filter.

``attitude = "ins"`` (the default) is the inertial navigation filter of
:mod:`autopilot.estimation.ins`; ``"ideal-ahrs"`` the attitude source with per-axis
position filters of :mod:`autopilot.estimation.kf`, kept for comparisons. The in-process
loop and the autopilot process both call :func:`nav_tick` and :func:`nav_log`, so they
fly the same filter on the same numbers.

``params`` = the header (``H_*``) followed by that filter's own parameters; ``state`` is
that filter's state array (:func:`nav_state_size`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from autopilot.estimation import ins, kf
from autopilot.estimation.config import EstimatorConfig
from heli_common.geo import GeoPoint
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import FloatArray
from heli_common.world.magnetic import earth_field_nwu_gauss

HEADER = Layout("navigation header", ("kind", 1), ("use_baro", 1))
H_KIND = HEADER.offset("kind")
H_USE_BARO = HEADER.offset("use_baro")
N_HEADER = HEADER.size
KIND_AHRS, KIND_INS = 0.0, 1.0


def make_nav_params(config: EstimatorConfig, rate_hz: float, home: GeoPoint | None = None) -> FloatArray:
    """The parameter array of ``config`` at ``rate_hz``; the home gives the navigation
    filter the earth's field its magnetometer is compared with (the same field model as
    the plant's magnetometer, :mod:`heli_common.world.magnetic`, as ArduPilot takes its
    declination from a table; none: no magnetometer fusion)."""
    head = np.zeros(N_HEADER)
    head[H_USE_BARO] = 1.0 if config.use_baro else 0.0
    if config.attitude == "ins":
        head[H_KIND] = KIND_INS
        field = (0.0, 0.0, 0.0) if home is None else earth_field_nwu_gauss(home.lat_deg, home.lon_deg)
        return np.concatenate([head, ins.make_params(config, rate_hz, field)])
    head[H_KIND] = KIND_AHRS
    return np.concatenate([head, kf.make_params(config, rate_hz)])


def nav_state_size(params: FloatArray) -> int:
    if params[H_KIND] == KIND_INS:
        return ins.state_size(int(params[N_HEADER + ins.K_N_BUF]))
    return kf.state_size(int(params[N_HEADER + kf.K_N_BUF]))


def nav_state(params: FloatArray, x0: FloatArray) -> FloatArray:
    """A new state array started from the 12-state ``x0``."""
    st = np.zeros(nav_state_size(params))
    nav_init(params, st, np.asarray(x0, dtype=float))
    return st


@njit
def nav_init(params: FloatArray, st: FloatArray, x0: FloatArray) -> None:
    if params[H_KIND] == KIND_INS:
        ins.est_init(params[N_HEADER:], st, x0)
    else:
        kf.est_init(params[N_HEADER:], st, x0)


@njit
def nav_tick(
    params: FloatArray, st: FloatArray, t_s: float, meas: FloatArray, mask: int, x_out: FloatArray
) -> int:
    """One tick on the measurement layout; the estimate into ``x_out``; the GPS status."""
    if params[H_KIND] == KIND_INS:
        return ins.est_tick(params[N_HEADER:], st, t_s, meas, mask, x_out)
    return kf.est_tick(params[N_HEADER:], st, t_s, meas, mask, params[H_USE_BARO] > 0.5, x_out)


@njit
def nav_log(params: FloatArray, st: FloatArray, gps_status: int, row: FloatArray) -> None:
    """One row of the estimator's log (:mod:`autopilot.estimation.log`)."""
    if params[H_KIND] == KIND_INS:
        ins.log_tick(st, gps_status, row)
    else:
        kf.log_tick(st, gps_status, row)


def nav_health(params: FloatArray, st: FloatArray) -> tuple[bool, float, int, int, float, bool]:
    """``(gps_lost, time_since_fix_s, n_rejected, n_resets, last_nis, diverged)``."""
    if params[H_KIND] == KIND_INS:
        k = params[N_HEADER:]
        since = float(st[ins.E_T] - st[ins.E_T_FIX]) if math.isfinite(st[ins.E_T]) else 0.0
        return (since > k[ins.K_GPS_TIMEOUT], since, int(st[ins.E_N_REJECT]), int(st[ins.E_N_RESET]),
                float(st[ins.E_NIS]), bool(st[ins.E_DIVERGED] > 0.5))  # fmt: skip
    k = params[N_HEADER:]
    since = float(st[kf.E_T] - st[kf.E_T_FIX]) if math.isfinite(st[kf.E_T]) else 0.0
    return (since > k[kf.K_GPS_TIMEOUT], since, int(st[kf.E_N_REJECT]), int(st[kf.E_N_RESET]),
            float(st[kf.E_NIS]), False)  # fmt: skip


@njit
def nav_truth(params: FloatArray, st: FloatArray, x_true: FloatArray, gyro_bias_true: ins.Vec3,
              accel_bias_true: ins.Vec3, row: FloatArray) -> None:  # fmt: skip
    """The log's truth columns where a simulation knows the truth: the navigation filter's
    NEES over its 15 navigation states and its true attitude error (NaN for ideal-ahrs)."""
    if params[H_KIND] != KIND_INS:
        return
    ins.truth_log(st, x_true, gyro_bias_true, accel_bias_true, row)


class NavStatus(NamedTuple):
    """What the estimator tells a ground station (ESTIMATOR_STATUS, EKF_STATUS_REPORT,
    SYS_STATUS): test ratios are ``sqrt(innovation^2 / (gate S))`` per measurement kind,
    the largest component of the last one (1: at the gate, as ArduPilot reports them;
    NaN: none yet); accuracies are 1-sigma."""

    gps_lost: bool
    diverged: bool
    vel_ratio: float
    pos_horiz_ratio: float
    pos_vert_ratio: float  # the barometer's (the GPS height's without one)
    mag_ratio: float  # NaN for ideal-ahrs (no magnetometer fusion)
    pos_horiz_sd_m: float
    pos_vert_sd_m: float
    n_rejected: int  # GPS fixes refused by the gate so far
    mag_ok: bool  # the magnetometer's samples pass their gate (or none are fused)


def _ratio(y: float, s: float, gate: float) -> float:
    return math.sqrt(y * y / (gate * s)) if math.isfinite(y) and s > 0.0 else math.nan


def _worst(innov: FloatArray, s: FloatArray, gate: float, n: int) -> float:
    """The largest test ratio of the first ``n`` components (NaN if none is known)."""
    r = [_ratio(float(innov[i]), float(s[i]), gate) for i in range(n)]
    known = [v for v in r if math.isfinite(v)]
    return max(known) if known else math.nan


def nav_status(params: FloatArray, st: FloatArray) -> NavStatus:
    """The estimator's state for a ground station (either filter)."""
    gps_lost, _, n_rej, _, _, diverged = nav_health(params, st)
    k = params[N_HEADER:]
    if params[H_KIND] == KIND_INS:
        g1 = k[ins.K_GATE_1]
        vel = _worst(st[ins.E_INNOV_VEL :], st[ins.E_S_VEL :], g1, 3)
        pos_h = _worst(st[ins.E_INNOV_POS :], st[ins.E_S_POS :], g1, 2)
        pos_v = _ratio(st[ins.E_BARO_INNOV], st[ins.E_BARO_S], g1)
        mag_nis = st[ins.E_MAG_NIS]
        mag = math.sqrt(mag_nis / k[ins.K_GATE_3]) if math.isfinite(mag_nis) else math.nan
        p = st[ins.E_COV : ins.E_COV + ins.N_COV].reshape(ins.N_ERR, ins.N_ERR)
        sd_h = math.sqrt(max(p[ins.D_POS, ins.D_POS], p[ins.D_POS + 1, ins.D_POS + 1]))
        sd_v = math.sqrt(p[ins.D_POS + 2, ins.D_POS + 2])
        t = st[ins.E_T]
        mag_ok = not (t - st[ins.E_T_MAG_SEEN] <= 1.0 and t - st[ins.E_T_MAG_OK] > 1.0)
        return NavStatus(gps_lost, diverged, vel, pos_h, pos_v, mag, sd_h, sd_v, n_rej, mag_ok)
    g1 = float(k[kf.K_GATE_BARO])
    vel = _worst(st[kf.E_INNOV_VEL :], st[kf.E_S_VEL :], g1, 3)
    pos_h = _worst(st[kf.E_INNOV_POS :], st[kf.E_S_POS :], g1, 2)
    pos_v = _ratio(st[kf.E_BARO_INNOV], st[kf.E_BARO_S], g1)
    sd_h = math.sqrt(max(st[kf.E_P + kf.COV_PP], st[kf.E_P + kf.N_COV + kf.COV_PP]))
    sd_v = math.sqrt(st[kf.E_P + 2 * kf.N_COV + kf.COV_PP])
    return NavStatus(gps_lost, diverged, vel, pos_h, pos_v, math.nan, sd_h, sd_v, n_rej, True)
