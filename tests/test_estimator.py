"""The state estimator (autopilot.estimation) against theory.

True motion is analytic (hover, a constant-velocity line, a 10 m circle of 80 s period
climbing 0.5 m/s, attitude from the thrust direction with the nose along the path); the
sensors are synthetic with known, seeded noise: IMU at 100 Hz (white, the configured
densities; a random-walk earth-frame acceleration bias of the configured size), the
attitude source with its configured white error, GPS at 5 Hz with 100 ms latency. Checks:
NEES in its chi-square bounds, RMS error below the GPS noise, the delayed-fix handling
(exactly the no-latency filter when both have the same fixes; as good as it on average;
better than applying late fixes as current), white innovations, step-for-step agreement
with filterpy's KalmanFilter, and determinism. The cost of a tick is a benchmark
(benchmarks/bench_estimator.py, ``python -m benchmarks navigation``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from filterpy import kalman
from numpy.testing import assert_allclose, assert_array_equal
from scipy.linalg import expm
from scipy.stats import chi2

from autopilot.estimation import Estimator, EstimatorConfig
from autopilot.estimation.config import MPU6000_ACCEL_DENSITY
from autopilot.estimation.kf import (
    ACCEPTED,
    BAD_INPUT,
    E_N_FIX,
    E_P,
    E_X,
    REJECTED,
    RESET,
    TOO_OLD,
    axis_model,
)
from heli_common.config import ConfigError
from heli_common.kinematics import euler_rate_matrix, rot_body_to_earth
from heli_common.state import N_STATE, PSI, FloatArray
from heli_common.wire.measurements import AttitudeSample, BaroSample, GpsFix, ImuSample, Vec3

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ
G = 9.81
GPS_EVERY = 20  # ticks: 5 Hz
LATENCY = 10  # ticks: 100 ms
GYRO_DENSITY = 8.7e-5  # rad/s/rtHz

# ------------------------------------------------------------------ true motion


@dataclass(frozen=True)
class Motion:
    t: FloatArray  # (n,)
    pos: FloatArray  # (n, 3) NWU
    vel: FloatArray
    acc: FloatArray
    euler: FloatArray
    omega: FloatArray  # body FLU


def _attitude(
    t: FloatArray, acc: FloatArray, psi: FloatArray, psi_dot: float
) -> tuple[FloatArray, FloatArray]:
    """Roll and pitch that put the body z axis along the thrust a - g_E, with the given yaw;
    body rates for constant roll and pitch and yaw rate psi_dot."""
    thrust = acc + np.array([0.0, 0.0, G])
    u = thrust / np.linalg.norm(thrust, axis=1, keepdims=True)
    c, s = np.cos(psi), np.sin(psi)
    wx = c * u[:, 0] + s * u[:, 1]
    wy = -s * u[:, 0] + c * u[:, 1]
    phi = np.arcsin(-wy)
    theta = np.arctan2(wx, u[:, 2])
    euler = np.column_stack([phi, theta, np.arctan2(np.sin(psi), np.cos(psi))])
    omega = np.array([euler_rate_matrix(e[0], e[1]) @ np.array([0.0, 0.0, psi_dot]) for e in euler])
    return euler, omega


def hover(duration_s: float) -> Motion:
    t = np.arange(round(duration_s * RATE_HZ) + 1) * DT
    n = t.size
    pos = np.tile([5.0, -3.0, 10.0], (n, 1))
    zero = np.zeros((n, 3))
    euler, omega = _attitude(t, zero, np.full(n, 0.3), 0.0)
    return Motion(t, pos, zero.copy(), zero.copy(), euler, omega)


def line(duration_s: float) -> Motion:
    t = np.arange(round(duration_s * RATE_HZ) + 1) * DT
    v = np.array([3.0, -2.0, 0.5])
    pos = np.array([0.0, 0.0, 10.0]) + t[:, None] * v
    vel = np.tile(v, (t.size, 1))
    acc = np.zeros_like(vel)
    euler, omega = _attitude(t, acc, np.full(t.size, math.atan2(v[1], v[0])), 0.0)
    return Motion(t, pos, vel, acc, euler, omega)


CIRCLE_R, CIRCLE_W, CLIMB = 10.0, 2.0 * math.pi / 80.0, 0.5


def circle(duration_s: float) -> Motion:
    t = np.arange(round(duration_s * RATE_HZ) + 1) * DT
    wt = CIRCLE_W * t
    r, w = CIRCLE_R, CIRCLE_W
    pos = np.column_stack([r * np.cos(wt), r * np.sin(wt), 10.0 + CLIMB * t])
    vel = np.column_stack([-r * w * np.sin(wt), r * w * np.cos(wt), np.full(t.size, CLIMB)])
    acc = np.column_stack([-r * w * w * np.cos(wt), -r * w * w * np.sin(wt), np.zeros(t.size)])
    euler, omega = _attitude(t, acc, wt + math.pi / 2.0, w)
    return Motion(t, pos, vel, acc, euler, omega)


MOTIONS: dict[str, Callable[[float], Motion]] = {"hover": hover, "line": line, "circle": circle}

# ------------------------------------------------------------------ sensors


@dataclass(frozen=True)
class Sensors:
    gyro: FloatArray  # (n, 3)
    accel: FloatArray
    att: FloatArray
    bias: FloatArray  # (n, 3) the true earth-frame acceleration bias
    gps_ticks: FloatArray  # ticks at which fixes are valid
    gps_pos: FloatArray  # (m, 3)
    gps_vel: FloatArray
    x0: FloatArray  # initial estimate, drawn from the initial covariance


def v3(a: Iterable[float]) -> Vec3:
    x, y, z = (float(v) for v in a)
    return (x, y, z)


def config_for(pos_sigma: float, vel_sigma: float, **kw: Any) -> EstimatorConfig:
    return replace(
        EstimatorConfig(),
        gps_pos_sigma_m=(pos_sigma,) * 3,
        gps_vel_sigma_m_s=(vel_sigma,) * 3,
        gravity_m_s2=G,
        **kw,
    )


def rotations(euler: FloatArray) -> FloatArray:
    """(n, 3, 3) body-to-earth rotations of (n, 3) Euler angles (heli_common.kinematics)."""
    return np.array([rot_body_to_earth(*e) for e in euler])


def sense(m: Motion, cfg: EstimatorConfig, rng: np.random.Generator) -> Sensors:
    n = m.t.size
    s_acc = cfg.accel_noise_density * math.sqrt(RATE_HZ)  # per-sample sigma of a white density
    s_gyro = GYRO_DENSITY * math.sqrt(RATE_HZ)
    bias = rng.normal(0.0, cfg.init_accel_bias_sigma, 3) + np.cumsum(
        rng.normal(0.0, cfg.accel_bias_walk * math.sqrt(DT), (n, 3)), axis=0
    )
    r = rotations(m.euler)
    accel = np.einsum("nji,nj->ni", r, m.acc + np.array([0.0, 0.0, G]) + bias)  # R' (a - g_E + b)
    accel += rng.normal(0.0, s_acc, (n, 3))
    gyro = m.omega + rng.normal(0.0, s_gyro, (n, 3))
    att = m.euler + rng.normal(0.0, cfg.attitude_noise_rad, (n, 3))
    ticks = np.arange(0, n, GPS_EVERY)
    gps_pos = m.pos[ticks] + rng.normal(0.0, 1.0, (ticks.size, 3)) * np.array(cfg.gps_pos_sigma_m)
    gps_vel = m.vel[ticks] + rng.normal(0.0, 1.0, (ticks.size, 3)) * np.array(cfg.gps_vel_sigma_m_s)
    p0 = m.pos[0] + rng.normal(0.0, cfg.init_pos_sigma_m, 3)
    v0 = m.vel[0] + rng.normal(0.0, cfg.init_vel_sigma_m_s, 3)
    x0 = np.zeros(N_STATE)
    x0[0:3] = p0
    x0[3:6] = rot_body_to_earth(*m.euler[0]).T @ v0
    x0[6:9] = m.euler[0]
    return Sensors(gyro, accel, att, bias, ticks, gps_pos, gps_vel, x0)


# ------------------------------------------------------------------ running the estimator


@dataclass(frozen=True)
class Run:
    pos: FloatArray  # (n, 3) earth position estimate
    vel: FloatArray  # (n, 3) earth velocity estimate
    bias: FloatArray  # (n, 3) earth-frame acceleration bias estimate
    cov: FloatArray  # (n, 3, 3, 3) per-axis covariance of [p, v, b]
    x: FloatArray  # (n, 12) the output
    innov: FloatArray  # (fixes, 6) normalised innovations y / sqrt(S): pos N W U, vel N W U
    innov_t: FloatArray


def fly(cfg: EstimatorConfig, m: Motion, s: Sensors, mode: str = "delayed") -> Run:
    """mode: "delayed" (fixes arrive LATENCY ticks after their validity time, fused there),
    "nolat" (arrive at their validity time), "naive" (arrive late, stamped as current)."""
    lat = 0 if mode == "nolat" else LATENCY
    arrivals: dict[int, list[GpsFix]] = {}
    for j, k in enumerate(s.gps_ticks):
        kk = int(k) + lat
        if kk >= m.t.size:
            break
        t_valid = m.t[kk] if mode == "naive" else m.t[int(k)]
        fix = GpsFix(float(t_valid), v3(s.gps_pos[j]), v3(s.gps_vel[j]))
        arrivals.setdefault(kk, []).append(fix)
    est = Estimator(cfg, s.x0, RATE_HZ)
    n = m.t.size
    pos, vel, bias = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    cov, xs = np.empty((n, 3, 3, 3)), np.empty((n, N_STATE))
    innov: list[FloatArray] = []
    innov_t: list[float] = []
    # views into the filter (the properties return copies; this loop runs 10^5 times)
    x_view = est.state[E_X : E_X + 9].reshape(3, 3)  # axis, [p, v, b]
    p_view = est.state[E_P : E_P + 27].reshape(3, 3, 3)
    ts = m.t.tolist()
    gyro, accel, att = (list(map(tuple, a.tolist())) for a in (s.gyro, s.accel, s.att))
    for k in range(n):
        t = ts[k]
        fixes = arrivals.get(k, ())
        n_before = est.state[E_N_FIX]
        xs[k] = est.update(t, ImuSample(t, gyro[k], accel[k]), AttitudeSample(t, att[k]), fixes)
        pos[k], vel[k], bias[k], cov[k] = x_view[:, 0], x_view[:, 1], x_view[:, 2], p_view
        if est.state[E_N_FIX] > n_before:
            i = est.innovations
            innov.append(np.concatenate([i.pos_m / np.sqrt(i.s_pos), i.vel_m_s / np.sqrt(i.s_vel)]))
            innov_t.append(i.t_s)
    return Run(pos, vel, bias, cov, xs, np.array(innov), np.array(innov_t))


def nees(m: Motion, r: Run) -> FloatArray:
    """Per tick, e' P^-1 e over [p, v] of the three axes (6 degrees of freedom)."""
    e = np.stack([r.pos - m.pos, r.vel - m.vel], axis=2)  # (n, 3 axes, 2)
    p = r.cov[:, :, 0:2, 0:2]
    return np.einsum("nai,naij,naj->n", e, np.linalg.inv(p), e)


def rms(x: FloatArray) -> FloatArray:
    return np.sqrt(np.mean(x**2, axis=0))


# ------------------------------------------------------------------ (a), (b): consistency and accuracy

MC_RUNS, MC_S = 10, 60.0
GPS_POS_SIGMA, GPS_VEL_SIGMA = 1.0, 0.1


MonteCarlo = dict[str, tuple[Motion, list[Sensors], list[Run], EstimatorConfig]]


@pytest.fixture(scope="module")
def monte_carlo() -> MonteCarlo:
    cfg = config_for(GPS_POS_SIGMA, GPS_VEL_SIGMA)
    out = {}
    for name, make in MOTIONS.items():
        m = make(MC_S)
        sens = [sense(m, cfg, np.random.default_rng(100 + i)) for i in range(MC_RUNS)]
        out[name] = (m, sens, [fly(cfg, m, s) for s in sens], cfg)
    return out


@pytest.mark.parametrize("name", list(MOTIONS))
def test_nees_within_chi_square_bounds(name: str, monte_carlo: MonteCarlo) -> None:
    m, _, runs, _ = monte_carlo[name]
    q = np.array([nees(m, r) for r in runs])  # (runs, n)
    q = q[:, ::10]  # at 10 Hz
    lo1, hi1 = chi2.ppf([0.025, 0.975], 6)
    single = np.mean((q >= lo1) & (q <= hi1))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * MC_RUNS) / MC_RUNS
    avg = q.mean(axis=0)
    inside = np.mean((avg >= lo) & (avg <= hi))
    print(
        f"\n{name}: NEES(6 dof) mean {q.mean():.2f}; single runs: {single:.1%} of samples in "
        f"[{lo1:.2f}, {hi1:.2f}]; {MC_RUNS}-run average: {inside:.1%} in [{lo:.2f}, {hi:.2f}]"
    )
    assert single >= 0.90
    assert inside >= 0.90
    assert 5.0 < q.mean() < 7.0


@pytest.mark.parametrize("name", list(MOTIONS))
def test_rms_error_well_below_gps_noise(name: str, monte_carlo: MonteCarlo) -> None:
    m, sens, runs, cfg = monte_carlo[name]
    skip = int(10 * RATE_HZ)  # after the initial transient
    ep = np.concatenate([r.pos[skip:] - m.pos[skip:] for r in runs])
    ev = np.concatenate([r.vel[skip:] - m.vel[skip:] for r in runs])
    sig = np.sqrt(np.concatenate([r.cov[skip:, :, 0, 0] for r in runs])).mean(axis=0)
    print(
        f"\n{name}: RMS position error {np.round(rms(ep), 3)} m (GPS noise {GPS_POS_SIGMA} m, "
        f"filter sigma {np.round(sig, 3)}), velocity {np.round(rms(ev), 3)} m/s (GPS {GPS_VEL_SIGMA})"
    )
    assert np.all(rms(ep) < 0.35 * GPS_POS_SIGMA)
    assert np.all(rms(ev) < 0.5 * GPS_VEL_SIGMA)
    # the acceleration bias (drawn with sigma init_accel_bias_sigma, walking): learnt, consistently
    eb = np.concatenate([r.bias[skip:] - s.bias[skip:] for r, s in zip(runs, sens, strict=True)])
    zb = eb / np.sqrt(np.concatenate([r.cov[skip:, :, 2, 2] for r in runs]))
    print(
        f"{name}: RMS bias error {np.round(rms(eb), 4)} m/s^2 (prior {cfg.init_accel_bias_sigma}), "
        f"normalised {np.round(rms(zb), 2)}"
    )
    assert np.all(rms(eb) < 0.1 * cfg.init_accel_bias_sigma)
    assert np.all((rms(zb) > 0.6) & (rms(zb) < 1.4))


def test_position_only_fusion_is_consistent() -> None:
    """Without GPS velocity (3-dof gate) the filter is slower but still consistent. Its errors
    are slow (correlated over seconds), so the check is on the NEES averaged over runs and
    time, and on the per-sample fraction inside the single-run bounds."""
    cfg = config_for(1.0, 0.1, use_gps_velocity=False)
    m = circle(40.0)
    runs = [fly(cfg, m, sense(m, cfg, np.random.default_rng(200 + i))) for i in range(12)]
    q = np.array([nees(m, r) for r in runs])[:, ::10]
    lo1, hi1 = chi2.ppf([0.025, 0.975], 6)
    single = np.mean((q >= lo1) & (q <= hi1))
    ep = np.concatenate([r.pos[1000:] - m.pos[1000:] for r in runs])
    print(
        f"\nposition only: NEES mean {q.mean():.2f}, {single:.1%} of samples in [{lo1:.2f}, {hi1:.2f}]; "
        f"RMS position {np.round(rms(ep), 3)} m"
    )
    assert 5.1 < q.mean() < 6.9
    assert single >= 0.90
    assert np.all(rms(ep) < 0.5)
    assert all(r.innov.shape[0] > 150 and np.all(np.isnan(r.innov[:, 3:])) for r in runs)


# ------------------------------------------------------------------ (c): the delayed fixes


def test_replay_equals_no_latency_filter_when_both_have_the_same_fixes() -> None:
    """When a late fix has just been fused (latency 100 ms < GPS period 200 ms), the delayed
    filter has exactly the fixes the no-latency filter has: re-propagation is exact."""
    cfg = config_for(1.0, 0.1)
    m = circle(20.0)
    s = sense(m, cfg, np.random.default_rng(7))
    d, n = fly(cfg, m, s, "delayed"), fly(cfg, m, s, "nolat")
    at = s.gps_ticks[s.gps_ticks + LATENCY < m.t.size] + LATENCY
    assert_allclose(d.pos[at], n.pos[at], rtol=0, atol=1e-9)
    assert_allclose(d.vel[at], n.vel[at], rtol=0, atol=1e-9)
    assert_allclose(d.cov[at], n.cov[at], rtol=1e-9, atol=1e-15)
    assert_allclose(d.x[at], n.x[at], rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def latency_runs() -> tuple[Motion, dict[str, list[Run]]]:
    cfg = config_for(0.5, 0.1)
    m = circle(80.0)
    sensors = [sense(m, cfg, np.random.default_rng(300 + i)) for i in range(6)]
    return m, {mode: [fly(cfg, m, s, mode) for s in sensors] for mode in ("delayed", "nolat", "naive")}


def test_delayed_fixes_as_good_as_no_latency_and_better_than_naive(
    latency_runs: tuple[Motion, dict[str, list[Run]]],
) -> None:
    """Same noise for the three variants: the error differences to the no-latency filter show
    what the latency costs. The naive filter trails the vehicle by about 100 ms of travel."""
    m, runs = latency_runs
    skip = int(10 * RATE_HZ)
    tangent = m.vel[skip:, 0:2] / np.linalg.norm(m.vel[skip:, 0:2], axis=1, keepdims=True)
    err = {mode: np.concatenate([r.pos[skip:] - m.pos[skip:] for r in rs]) for mode, rs in runs.items()}
    tan = np.tile(tangent, (len(runs["delayed"]), 1))
    res = {}
    for mode, e in err.items():
        d = e - err["nolat"]  # paired with the no-latency filter
        res[mode] = (
            float(np.sqrt(np.mean(np.sum(e**2, axis=1)))),
            float(np.mean(np.sum(d[:, 0:2] * tan, axis=1))),
            float(np.mean(d[:, 2])),
            float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        )
        print(
            f"\n{mode:8s}: RMS 3-D position error {res[mode][0]:.4f} m; relative to the no-latency "
            f"filter: mean along-track {res[mode][1]:+.4f} m, mean vertical {res[mode][2]:+.4f} m, "
            f"RMS difference {res[mode][3]:.4f} m"
        )
    lag_h = CIRCLE_R * CIRCLE_W * LATENCY * DT  # 100 ms of horizontal travel
    lag_v = CLIMB * LATENCY * DT
    print(f"100 ms of travel: {lag_h:.4f} m along track, {lag_v:.4f} m up")
    assert res["delayed"][0] <= 1.10 * res["nolat"][0]
    assert res["naive"][0] >= 1.05 * res["delayed"][0]
    assert abs(res["delayed"][1]) < 0.05 * lag_h and abs(res["delayed"][2]) < 0.05 * lag_v
    assert res["naive"][1] == pytest.approx(-lag_h, rel=0.2)
    assert res["naive"][2] == pytest.approx(-lag_v, rel=0.2)


# ------------------------------------------------------------------ (d): white innovations


def test_innovations_are_white() -> None:
    cfg = config_for(1.0, 0.1)
    m = circle(240.0)
    r = fly(cfg, m, sense(m, cfg, np.random.default_rng(11)))
    y = r.innov[r.innov_t >= 10.0]
    n = y.shape[0]
    bound = 3.0 / math.sqrt(n)
    worst = 0.0
    for c in range(6):
        v = y[:, c] - y[:, c].mean()
        acf = np.array([np.dot(v[:-lag], v[lag:]) for lag in range(1, 6)]) / np.dot(v, v)
        worst = max(worst, float(np.max(np.abs(acf))))
        assert np.all(np.abs(acf) < bound), (c, acf, bound)
    print(f"\ninnovations: N = {n}, largest |autocorrelation| at lags 1..5: {worst:.3f} (bound {bound:.3f})")
    assert_allclose(y.std(axis=0), 1.0, atol=0.1)  # normalised by their predicted S


# ------------------------------------------------------------------ (e): filterpy, step for step


def van_loan_q(dt: float, qa: float, qb: float) -> FloatArray:
    """Discrete process noise of x = [p, v, b], p' = v, v' = a - b + w_a, b' = w_b."""
    fc = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    gqg = np.diag([0.0, qa, qb])
    big = np.zeros((6, 6))
    big[0:3, 0:3] = -fc
    big[0:3, 3:6] = gqg
    big[3:6, 3:6] = fc.T
    e = expm(big * dt)
    phi = e[3:6, 3:6].T
    return phi @ e[0:3, 3:6]


def test_axis_model_matches_continuous_time_theory() -> None:
    qa, qb = 0.3, 0.02
    for dt in (0.01, 0.1, 1.0):
        f, b, q = axis_model(dt, qa, qb)
        fc = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
        assert_allclose(f, expm(fc * dt), atol=1e-14)
        assert_allclose(b, [0.5 * dt * dt, dt, 0.0])
        assert_allclose(q, van_loan_q(dt, qa, qb), rtol=1e-9, atol=1e-16)


def test_matches_filterpy_step_for_step() -> None:
    cfg = config_for(1.0, 0.1)
    m = circle(10.0)
    s = sense(m, cfg, np.random.default_rng(5))
    est = Estimator(cfg, s.x0, RATE_HZ)
    qa0 = cfg.accel_noise_density**2
    qb = cfg.accel_bias_walk**2
    p0 = np.diag([cfg.init_pos_sigma_m**2, cfg.init_vel_sigma_m_s**2, cfg.init_accel_bias_sigma**2])
    v0 = rot_body_to_earth(*s.x0[6:9]) @ s.x0[3:6]
    kfs = []
    for ax in range(3):
        kf = kalman.KalmanFilter(dim_x=3, dim_z=2, dim_u=1)
        kf.x = np.array([[s.x0[ax]], [v0[ax]], [0.0]])
        kf.P = p0.copy()
        kf.H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        kf.R = np.diag([cfg.gps_pos_sigma_m[ax] ** 2, cfg.gps_vel_sigma_m_s[ax] ** 2])
        kfs.append(kf)
    gps = {int(k): j for j, k in enumerate(s.gps_ticks)}
    f, b, _ = axis_model(DT, 0.0, 0.0)
    q_unit_a, q_unit_b = van_loan_q(DT, 1.0, 0.0), van_loan_q(DT, 0.0, 1.0)  # Q is linear in (qa, qb)
    n = m.t.size
    ours, theirs = np.empty((2, n, 3, 9)), np.empty((2, n, 3, 9))
    n_upd = 0
    for k in range(n):
        t = float(m.t[k])
        fix = []
        if k in gps:
            fix = [GpsFix(t, v3(s.gps_pos[gps[k]]), v3(s.gps_vel[gps[k]]))]
        est.update(t, ImuSample(t, v3(s.gyro[k]), v3(s.accel[k])), AttitudeSample(t, v3(s.att[k])), fix)
        fe = rot_body_to_earth(*s.att[k]) @ s.accel[k]
        a_e = fe + np.array([0.0, 0.0, -G])
        for ax, kf in enumerate(kfs):
            if k > 0:  # the first tick only sets the time
                qa = qa0 + cfg.attitude_noise_rad**2 * DT * (fe @ fe - fe[ax] ** 2)
                q = qa * q_unit_a + qb * q_unit_b
                kf.predict(u=np.array([[a_e[ax]]]), B=b.reshape(3, 1), F=f, Q=q)
            if fix:
                kf.update(np.array([[s.gps_pos[gps[k], ax]], [s.gps_vel[gps[k], ax]]]))
                n_upd += 1
            ours[0, k, ax, 0:3] = est.pos_nwu_m[ax], est.vel_nwu_m_s[ax], est.accel_bias_nwu[ax]
            ours[1, k, ax, 0:9] = est.covariance[ax].ravel()
            theirs[0, k, ax, 0:3] = kf.x[:, 0]
            theirs[1, k, ax, 0:9] = kf.P.ravel()
    assert n_upd == 3 * len(gps)
    dx = np.abs(ours[0, :, :, 0:3] - theirs[0, :, :, 0:3]).max()
    dp = (np.abs(ours[1] - theirs[1]) / np.abs(theirs[1]).max(axis=2, keepdims=True)).max()
    print(f"\nfilterpy: {n} ticks, {len(gps)} fixes; largest |x - x_fp| {dx:.1e}, |P - P_fp|/max|P| {dp:.1e}")
    assert_allclose(ours[0, :, :, 0:3], theirs[0, :, :, 0:3], rtol=1e-9, atol=1e-10)
    assert_allclose(ours[1], theirs[1], rtol=1e-8, atol=1e-14)


# ------------------------------------------------------------------ (f): determinism


def test_deterministic_and_reset_restarts() -> None:
    cfg = config_for(1.0, 0.1)
    m = circle(15.0)
    a = fly(cfg, m, sense(m, cfg, np.random.default_rng(9)))
    b = fly(cfg, m, sense(m, cfg, np.random.default_rng(9)))
    assert_array_equal(a.x, b.x)
    assert_array_equal(a.cov, b.cov)
    assert_array_equal(a.innov, b.innov)
    s = sense(m, cfg, np.random.default_rng(9))
    est = Estimator(cfg, s.x0, RATE_HZ)
    for attempt in range(2):
        est.reset(s.x0)
        out = [
            est.update(float(t), ImuSample(float(t), v3(s.gyro[k]), v3(s.accel[k])), None)
            for k, t in enumerate(m.t[:300])
        ]
        if attempt == 0:
            first = np.array(out)
    assert_array_equal(np.array(out), first)


# ------------------------------------------------------------------ health, gating, edge cases


def _hover_est(cfg: EstimatorConfig) -> Estimator:
    est = Estimator(cfg, np.zeros(N_STATE), RATE_HZ)
    return est


def _tick(
    est: Estimator, k: int, fixes: list[GpsFix] | None = None, baro: BaroSample | None = None
) -> FloatArray:
    """One hover tick at rest, level, at time k DT."""
    t = k * DT
    imu = ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, G))
    return est.update(t, imu, AttitudeSample(t, (0.0, 0.0, 0.0)), fixes or (), baro)


def test_gate_rejects_glitch_then_resets_on_a_persistent_jump() -> None:
    cfg = config_for(1.0, 0.1, max_consecutive_rejects=3)
    est = _hover_est(cfg)
    rng = np.random.default_rng(3)
    k = 0
    for k in range(0, 1000):
        fixes = []
        if k % GPS_EVERY == 0 and k >= LATENCY:
            tv = (k - LATENCY) * DT
            fixes = [GpsFix(tv, v3(rng.normal(0, 1.0, 3)), v3(rng.normal(0, 0.1, 3)))]
        _tick(est, k, fixes)
    h = est.health
    assert h.n_rejected == 0 and h.n_fixes == 49
    pos_before = est.pos_nwu_m
    # one glitch of 30 m north: rejected, counted, no effect
    k += 1
    jump = GpsFix((k - LATENCY) * DT, (30.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    _tick(est, k, [jump])
    assert est.last_gps_status == REJECTED
    assert est.health.n_rejected == 1 and est.health.n_consecutive_rejects == 1
    assert est.innovations.nis > chi2.ppf(cfg.gate_probability, 6)
    assert_allclose(est.pos_nwu_m, pos_before, atol=0.01)
    # the jump persists: rejected max_consecutive_rejects times, then taken as the new truth
    statuses = []
    for _ in range(4):
        k += GPS_EVERY
        for kk in range(k - GPS_EVERY + 1, k):
            _tick(est, kk)
        _tick(est, k, [GpsFix((k - LATENCY) * DT, (30.0, 0.0, 0.0), (0.0, 0.0, 0.0))])
        statuses.append(est.last_gps_status)
    assert statuses == [REJECTED, REJECTED, RESET, ACCEPTED]
    h = est.health
    assert (h.n_rejected, h.n_resets, h.n_consecutive_rejects) == (3, 1, 0)
    assert abs(est.pos_nwu_m[0] - 30.0) < 1.0


def test_gps_lost_after_timeout_and_stale_or_future_fixes() -> None:
    cfg = config_for(1.0, 0.1, gps_timeout_s=1.0)
    est = _hover_est(cfg)
    for k in range(0, 201):
        fixes = [GpsFix(k * DT, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))] if k % GPS_EVERY == 0 else []
        _tick(est, k, fixes)
    assert not est.health.gps_lost and est.health.time_since_fix_s == pytest.approx(0.0, abs=1e-9)
    for k in range(201, 301):
        _tick(est, k)
    assert est.health.time_since_fix_s == pytest.approx(1.0) and not est.health.gps_lost
    _tick(est, 301)
    assert est.health.gps_lost
    var_lost = est.pos_vel_var
    # a fix older than the buffer (0.5 s) is dropped; one from the future is refused
    _tick(est, 302, [GpsFix(302 * DT - 0.8, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))])
    assert est.last_gps_status == TOO_OLD and est.health.n_too_old == 1
    _tick(est, 303, [GpsFix(303 * DT + 0.1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))])
    assert est.last_gps_status == BAD_INPUT and est.health.n_bad == 1
    assert est.health.gps_lost
    # the covariance grew while lost; a fix valid 0.3 s ago is still fused at its time
    assert np.all(var_lost[0:3] > 0.0)
    _tick(est, 304, [GpsFix(304 * DT - 0.3, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))])
    assert est.last_gps_status == ACCEPTED
    assert est.health.time_since_fix_s == pytest.approx(0.3)
    assert not est.health.gps_lost


def test_out_of_order_fixes_give_the_same_estimate() -> None:
    cfg = config_for(1.0, 0.1)
    m = line(3.0)
    s = sense(m, cfg, np.random.default_rng(4))
    fix_a = GpsFix(1.0, v3(s.gps_pos[5]), v3(s.gps_vel[5]))
    fix_b = GpsFix(1.2, v3(s.gps_pos[6]), v3(s.gps_vel[6]))
    outs = []
    for order in ([fix_a, fix_b], [fix_b, fix_a]):
        est = Estimator(cfg, s.x0, RATE_HZ)
        for k in range(m.t.size):
            t = float(m.t[k])
            fixes = order if k == 130 else []
            est.update(t, ImuSample(t, v3(s.gyro[k]), v3(s.accel[k])), AttitudeSample(t, v3(s.att[k])), fixes)
        outs.append((est.x, est.covariance))
        assert est.health.n_fixes == 2
    assert_allclose(outs[0][0], outs[1][0], rtol=0, atol=1e-12)
    assert_allclose(outs[0][1], outs[1][1], rtol=0, atol=1e-15)


def test_baro_fused_at_its_time() -> None:
    cfg = config_for(1.0, 0.1, use_baro=True, baro_sigma_m=0.2)
    est = _hover_est(cfg)
    for k in range(0, 500):
        baro = BaroSample(k * DT - 0.05, 2.0) if k % 2 == 0 and k >= 5 else None
        _tick(est, k, baro=baro)
    h = est.health
    assert h.n_baro > 200 and h.n_baro_rejected == 0
    assert est.pos_nwu_m[2] == pytest.approx(2.0, abs=0.05)
    assert math.isfinite(est.innovations.baro_m)
    # off by configuration: ignored
    est = _hover_est(config_for(1.0, 0.1))
    _tick(est, 0)
    _tick(est, 1, baro=BaroSample(DT, 5.0))
    assert est.health.n_baro == 0


def test_attitude_dead_reckoned_between_samples_and_body_velocity() -> None:
    """AHRS at 10 Hz: the yaw follows the gyro in between; the output velocity is body FLU."""
    cfg = config_for(1.0, 0.1, attitude_noise_rad=0.0)
    m = circle(5.0)
    v_body = rot_body_to_earth(*m.euler[0]).T @ m.vel[0]
    est = Estimator(cfg, np.concatenate([m.pos[0], v_body, m.euler[0], m.omega[0]]), RATE_HZ)
    for k in range(m.t.size):
        t = float(m.t[k])
        f = rot_body_to_earth(*m.euler[k]).T @ (m.acc[k] + np.array([0.0, 0.0, G]))
        att = AttitudeSample(t, v3(m.euler[k])) if k % 10 == 0 else None
        x = est.update(t, ImuSample(t, v3(m.omega[k]), v3(f)), att)
        assert abs(x[PSI] - m.euler[k, 2]) < 1e-6
    vb = rot_body_to_earth(*x[6:9]).T @ est.vel_nwu_m_s
    assert_allclose(x[3:6], vb, atol=1e-12)
    assert_allclose(x[3:6], rot_body_to_earth(*m.euler[-1]).T @ m.vel[-1], atol=0.01)
    assert_allclose(x[9:12], m.omega[-1], atol=1e-12)


def test_config_loads_from_toml(tmp_path: Path) -> None:
    p = tmp_path / "est.toml"
    p.write_text("gps_pos_sigma_m = [0.5, 0.5, 0.8]\nuse_baro = true\nbuffer_s = 0.3\n")
    c = EstimatorConfig.load(p)
    assert c.gps_pos_sigma_m == (0.5, 0.5, 0.8) and c.use_baro and c.buffer_s == 0.3
    assert c.accel_noise_density == MPU6000_ACCEL_DENSITY
    p.write_text("gps_pos_sigma = [0.5, 0.5, 0.8]\n")
    with pytest.raises(ConfigError, match="did you mean"):
        EstimatorConfig.load(p)
    p.write_text("gate_probability = 1.5\n")
    with pytest.raises(ConfigError, match="gate_probability"):
        EstimatorConfig.load(p)
