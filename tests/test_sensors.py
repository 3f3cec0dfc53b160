"""Sensor models (heli_plant.sensors) against theory, and their configuration.

Long seeded runs of the compiled step check each white noise's mean and standard deviation
(``N sqrt(rate)`` for a density ``N``) and its Welch spectrum (two-sided ``N^2``), the bias
random walk's variance growth ``K^2 t`` over many seeds, the GPS Gauss-Markov wander's
stationary variance and autocorrelation ``exp(-lag/tau)``, the GPS schedule (spacing
``1/rate`` without drift) and latency (the delivered fix against the truth peaks at the lag);
then the accelerometer's specific force at rest and in a coordinated turn, determinism (in
process and under ``NUMBA_DISABLE_JIT=1``), ideal sensors reading the truth exactly, the
failures, live updates, and the SIM_ parameters.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
import scipy.signal
from numpy.testing import assert_allclose

from heli_common.config import ConfigError
from heli_common.jit import njit
from heli_common.state import EULER, N_STATE, OMEGA, PHI, POS, PSI, THETA, U_F, Z_U, FloatArray
from heli_common.world.config import SIM_PARAM_NAMES, WORLD_SIM_PARAMS, World
from heli_common.world.sensors import (
    PRESETS,
    SIM_SENSOR_PARAM_NAMES,
    SIM_SENSOR_PARAMS,
    Attitude,
    Baro,
    Gps,
    Imu,
    Sensors,
    preset,
    sensor_sim_values,
    validate,
    with_sensor_param,
)
from heli_plant.sensors import model
from heli_plant.sensors.model import (
    N_OUT,
    NEW_ATT,
    NEW_BARO,
    NEW_GPS,
    NEW_IMU,
    NEW_MAG,
    OUT_ACCEL,
    OUT_ATT,
    OUT_BARO_ALT,
    OUT_BARO_T,
    OUT_GPS_POS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_IMU_T,
    SNP_MAG_FIELD,
    SNP_SEED,
    SensorModel,
    earth_accel_from_derivative,
    earth_accel_from_states,
    magnetic_field_flu,
    sensor_parameters,
    sensor_state,
    sensor_step,
    specific_force_flu,
    velocity_nwu,
)
from heli_plant.world.noise import STREAM_SENSOR_BASE

ROOT = Path(__file__).resolve().parent.parent
G = 9.81  # the X-Cell airframe file's gravity
DEG = math.pi / 180.0

# --- compiled drivers (a Python loop over 1e5-1e6 steps would dominate the run time) -------


@njit
def _drive(
    params: FloatArray, state: FloatArray, out: FloatArray, h: float, n: int, xs: FloatArray, accs: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``n`` steps at ``t = k h`` with state row ``k % len(xs)``: every step's ``out`` and mask."""
    rec = np.empty((n, out.shape[0]))
    masks = np.empty(n)
    m = xs.shape[0]
    for k in range(n):
        masks[k] = sensor_step(k * h, xs[k % m], accs[k % m], params, state, out)
        rec[k, :] = out
    return rec, masks


def _drive_seeds(
    params: FloatArray, state0: FloatArray, h: float, n: int, seeds: FloatArray, col: int, every: int
) -> FloatArray:
    """One run per seed from ``state0`` at rest: ``out[col:col+3]`` every ``every`` steps."""
    res = np.empty((seeds.shape[0], n // every, 3))
    x, a = np.zeros((1, N_STATE)), np.zeros((1, 3))
    for j, seed in enumerate(seeds):
        p = params.copy()
        p[SNP_SEED] = seed
        rec, _ = _drive(p, state0.copy(), np.full(N_OUT, np.nan), h, n, x, a)
        res[j] = rec[every - 1 :: every, col : col + 3]
    return res


def _arrays(config: Sensors, h: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    p = sensor_parameters(config, h, G)
    return p, sensor_state(p), np.full(N_OUT, np.nan)


def _run(config: Sensors, h: float, n: int, xs: FloatArray | None = None, accs: FloatArray | None = None
         ) -> tuple[FloatArray, npt.NDArray[np.int64]]:  # fmt: skip
    p, s, out = _arrays(config, h)
    xs = np.zeros((1, N_STATE)) if xs is None else xs
    accs = np.zeros((1, 3)) if accs is None else accs
    rec, masks = _drive(p, s, out, h, n, xs, accs)
    return rec, masks.astype(np.int64)


def _rest(alt_m: float = 0.0) -> FloatArray:
    x = np.zeros((1, N_STATE))
    x[0, Z_U] = alt_m
    return x


# --- white noise: moments and spectrum ----------------------------------------------------------

N_GYRO = 0.005 * DEG  # MPU-6000: 0.005 deg/s/rtHz
N_ACCEL = 400e-6 * 9.80665  # 400 ug/rtHz
WHITE = Sensors(
    seed=7,
    imu=Imu(on=True, rate_hz=100.0, gyro_density_rad_s_rthz=N_GYRO, accel_density_m_s2_rthz=N_ACCEL),
    gps=Gps(on=True, rate_hz=100.0, lag_s=0.0, noise_h_m=0.3, noise_v_m=0.5, vel_noise_m_s=0.05),
    attitude=Attitude(on=True, rate_hz=100.0, noise_rad=(0.01, 0.02, 0.03)),
    baro=Baro(on=True, rate_hz=100.0, noise_m=0.2),
)
N_WHITE = 100_000


@pytest.fixture(scope="module")
def white_run() -> FloatArray:
    rec, masks = _run(WHITE, 0.01, N_WHITE, _rest(5.0))
    # every sensor at the plant rate (the magnetometer is off: ideal, every step)
    assert np.all(masks == NEW_IMU | NEW_GPS | NEW_ATT | NEW_BARO | NEW_MAG)
    return rec


@pytest.mark.parametrize(
    ("cols", "mean", "std"),
    [
        (slice(OUT_GYRO, OUT_GYRO + 3), (0.0, 0.0, 0.0), N_GYRO * 10.0),  # 0.05 deg/s at 100 Hz
        (slice(OUT_ACCEL, OUT_ACCEL + 3), (0.0, 0.0, G), N_ACCEL * 10.0),  # 0.039 m/s^2
        (slice(OUT_GPS_POS, OUT_GPS_POS + 3), (0.0, 0.0, 5.0), (0.3, 0.3, 0.5)),
        (slice(OUT_GPS_VEL, OUT_GPS_VEL + 3), (0.0, 0.0, 0.0), 0.05),
        (slice(OUT_ATT, OUT_ATT + 3), (0.0, 0.0, 0.0), (0.01, 0.02, 0.03)),
        (slice(OUT_BARO_ALT, OUT_BARO_ALT + 1), (5.0,), 0.2),
    ],
)
def test_white_noise_mean_and_std(white_run: FloatArray, cols: slice, mean: tuple[float, ...],
                                  std: float | tuple[float, ...]) -> None:  # fmt: skip
    """Sample mean within 5 standard errors of the truth; sample std within 1.5 % of the
    set per-sample value (its own standard error is 0.22 % for 1e5 samples)."""
    v = white_run[:, cols]
    sd = np.broadcast_to(np.asarray(std, dtype=float), (v.shape[1],))
    assert np.all(np.abs(v.mean(axis=0) - np.asarray(mean)) < 5.0 * sd / math.sqrt(N_WHITE))
    assert_allclose(v.std(axis=0), sd, rtol=0.015)


def test_white_noise_psd_is_the_density(white_run: FloatArray) -> None:
    """Welch, two-sided: the gyro and accelerometer PSD is N^2 (one-sided 2 N^2) within 10 %
    in the mean over frequency, flat (low and high halves agree within 10 %), and every bin
    within 35 % (about 5 of each bin's standard errors)."""
    cases = ((OUT_GYRO, N_GYRO, 0.0), (OUT_GYRO + 2, N_GYRO, 0.0), (OUT_ACCEL, N_ACCEL, 0.0),
             (OUT_ACCEL + 2, N_ACCEL, G))  # fmt: skip
    for col, dens, mean in cases:
        v = white_run[:, col] - mean  # the known mean, not a per-segment one (that would notch DC)
        f, pxx = scipy.signal.welch(v, fs=100.0, nperseg=512, detrend=False, return_onesided=False)
        ratio = pxx / dens**2
        assert abs(ratio.mean() - 1.0) < 0.10
        lo, hi = ratio[np.abs(f) < 25.0], ratio[np.abs(f) >= 25.0]
        assert abs(lo.mean() / hi.mean() - 1.0) < 0.10
        assert np.all(np.abs(ratio - 1.0) < 0.35)
        _, p1 = scipy.signal.welch(v, fs=100.0, nperseg=512, detrend=False)
        assert abs(p1[1:-1].mean() / (2.0 * dens**2) - 1.0) < 0.10


# --- bias random walk -----------------------------------------------------------------------------


def test_bias_random_walk_variance_grows_as_k2_t() -> None:
    """1000 seeds x 3 axes, 10 s at 100 Hz, no white noise: the bias variance at t = 1..10 s
    is K^2 t within 10 % (3000 paths: the estimate's standard error is 2.6 %), and a line
    through the origin fits it with slope K^2 within 5 %."""
    k_gyro, k_acc = 1e-3, 2e-3
    cfg = Sensors(imu=Imu(on=True, rate_hz=100.0, gyro_walk_rad_s_rts=k_gyro, accel_walk_m_s2_rts=k_acc))
    p, s, _ = _arrays(cfg, 0.01)
    seeds = np.arange(1000, dtype=float)
    t = np.arange(1, 11) * 1.0 - 0.01  # the first sample (t = 0) has no walk yet; sample k is at k h
    for col, k_walk, offset in ((OUT_GYRO, k_gyro, 0.0), (OUT_ACCEL, k_acc, G)):
        b = _drive_seeds(p, s, 0.01, 1000, seeds, col, 100)
        b[:, :, 2] -= offset
        var = (b**2).transpose(1, 0, 2).reshape(10, -1).mean(axis=1)  # over seeds and axes
        assert_allclose(var, k_walk**2 * t, rtol=0.10)
        slope = float(np.sum(var * t) / np.sum(t * t))
        assert abs(slope / k_walk**2 - 1.0) < 0.05


def test_bias_walk_increments_are_white_with_k2_dt() -> None:
    """One long run (1e5 steps): the per-sample increments have variance K^2 dt within 2 %
    and no lag-1 correlation (|r| < 5/sqrt(n))."""
    k = 5e-4
    rec, _ = _run(Sensors(imu=Imu(on=True, rate_hz=100.0, gyro_walk_rad_s_rts=k)), 0.01, 100_000)
    inc = np.diff(rec[:, OUT_GYRO : OUT_GYRO + 3], axis=0)
    assert_allclose(inc.var(axis=0), k**2 * 0.01, rtol=0.02)
    for i in range(3):
        r = np.corrcoef(inc[:-1, i], inc[1:, i])[0, 1]
        assert abs(r) < 5.0 / math.sqrt(inc.shape[0])


def test_initial_bias_is_added() -> None:
    cfg = Sensors(imu=Imu(on=True, gyro_bias_rad_s=(0.01, -0.02, 0.03), accel_bias_m_s2=(0.1, 0.2, -0.3)))
    rec, _ = _run(cfg, 0.01, 10)
    assert_allclose(rec[:, OUT_GYRO : OUT_GYRO + 3], np.tile([0.01, -0.02, 0.03], (10, 1)), rtol=0, atol=0)
    assert_allclose(rec[:, OUT_ACCEL : OUT_ACCEL + 3], np.tile([0.1, 0.2, G - 0.3], (10, 1)), rtol=1e-15)


# --- GPS: Gauss-Markov wander, schedule, latency ----------------------------------------------------

GM_TAU, GM_H, GM_V = 1.0, 2.0, 3.0


def test_gauss_markov_stationary_variance_and_autocorrelation() -> None:
    """GPS at 10 Hz (the plant's rate), tau 1 s, sigma 2 m horizontal and 3 m vertical, for
    2e4 s: the variance is sigma^2 within 5 % (standard error about 1 %) and the
    autocorrelation at 0.1 to 2 s is exp(-lag/tau) within 0.03."""
    cfg = Sensors(seed=3, gps=Gps(on=True, rate_hz=10.0, lag_s=0.0, wander_h_m=GM_H, wander_v_m=GM_V,
                                  wander_tau_s=GM_TAU))  # fmt: skip
    n = 200_000
    rec, masks = _run(cfg, 0.1, n)
    assert np.all(masks & NEW_GPS)
    w = rec[:, OUT_GPS_POS : OUT_GPS_POS + 3]
    assert_allclose(w.var(axis=0), [GM_H**2, GM_H**2, GM_V**2], rtol=0.05)
    for i in range(3):
        z = (w[:, i] - w[:, i].mean()) / w[:, i].std()
        for lag in (1, 5, 10, 20):
            r = float(np.mean(z[:-lag] * z[lag:]))
            assert abs(r - math.exp(-lag * 0.1 / GM_TAU)) < 0.03, (i, lag, r)


def test_gauss_markov_starts_stationary() -> None:
    """Across 2000 seeds the first fix's wander already has the stationary variance (10 %)."""
    cfg = Sensors(gps=Gps(on=True, rate_hz=5.0, lag_s=0.0, wander_h_m=GM_H, wander_v_m=GM_V))
    p, s, _ = _arrays(cfg, 0.2)
    first = _drive_seeds(p, s, 0.2, 1, np.arange(2000, dtype=float), OUT_GPS_POS, 1)[:, 0, :]
    assert_allclose(first.var(axis=0), [GM_H**2, GM_H**2, GM_V**2], rtol=0.10)


def test_gps_spacing_and_delivery_delay() -> None:
    """5 Hz fixes from a 100 Hz plant: validity times exactly 0.2 s apart, each delivered
    exactly lag = 0.1 s after it is valid."""
    cfg = Sensors(gps=Gps(on=True, rate_hz=5.0, lag_s=0.1, noise_h_m=0.3))
    n = 6000
    rec, masks = _run(cfg, 0.01, n)
    got = np.flatnonzero(masks & NEW_GPS)
    t_valid = rec[got, OUT_GPS_T]
    assert len(got) == 300  # valid at 0, 0.2, ..., 59.8 s; the last delivered at 59.9 s
    assert_allclose(np.diff(t_valid), 0.2, rtol=0, atol=1e-9)
    assert_allclose(got * 0.01 - t_valid, 0.1, rtol=0, atol=1e-9)
    assert t_valid[0] == 0.0


def test_gps_rate_not_dividing_the_step_does_not_drift() -> None:
    """3 Hz from a 100 Hz plant over 100 s: fix k is taken at the first step at or after k/3."""
    rec, masks = _run(Sensors(gps=Gps(on=True, rate_hz=3.0, lag_s=0.0)), 0.01, 10_000)
    t = rec[np.flatnonzero(masks & NEW_GPS), OUT_GPS_T]
    k = np.arange(len(t))
    assert len(t) == 300
    assert np.all(t >= k / 3.0 - 1e-9)
    assert np.all(t - k / 3.0 < 0.01)


def test_gps_cross_correlation_peaks_at_the_lag() -> None:
    """Fixes at the plant rate, 0.25 s lag, 0.3 m white noise, on a random-walk path: the
    cross-correlation of the delivered north increments with the true ones peaks at 25 steps."""
    h, n, lag_steps = 0.01, 20_000, 25
    rng = np.random.default_rng(11)
    xs = np.zeros((n, N_STATE))
    xs[:, 0] = np.cumsum(rng.normal(0.0, 0.2, n))
    cfg = Sensors(seed=5, gps=Gps(on=True, rate_hz=100.0, lag_s=lag_steps * h, noise_h_m=0.3))
    rec, masks = _run(cfg, h, n, xs, np.zeros((n, 3)))
    got = np.flatnonzero(masks & NEW_GPS)
    assert got[0] == lag_steps
    y = np.diff(rec[got, OUT_GPS_POS])
    truth = np.diff(xs[got, 0])  # the truth at the delivery steps
    c = scipy.signal.correlate(y - y.mean(), truth - truth.mean(), mode="full")
    lags = scipy.signal.correlation_lags(len(y), len(truth), mode="full")
    assert lags[np.argmax(c)] == lag_steps  # y[n + 25] matches truth[n]: the fix repeats it 25 steps later


# --- accelerometer: specific force --------------------------------------------------------------------


def test_accelerometer_reads_plus_g_level_at_rest() -> None:
    m = SensorModel(Sensors(imu=Imu(on=True, rate_hz=100.0)), 0.01, G)
    x = np.zeros(N_STATE)
    x[PSI] = 1.2  # heading does not matter
    imu = m.step(0.0, x, np.zeros(3)).imu
    assert imu is not None
    assert imu.accel_flu_m_s2 == (0.0, 0.0, G)
    assert imu.gyro_flu_rad_s == (0.0, 0.0, 0.0)
    x[PHI], x[THETA] = 0.1, -0.2  # tilted at rest: g along the body's view of earth up
    f = specific_force_flu(x, np.zeros(3), G)
    up = [-math.sin(-0.2), math.sin(0.1) * math.cos(-0.2), math.cos(0.1) * math.cos(-0.2)]
    assert_allclose(f, G * np.array(up), rtol=1e-14)


def test_on_the_ground_with_thrust_short_of_the_weight_the_accelerometer_reads_g() -> None:
    """The vehicle on the ground surface but not flagged resting (the step that set it down,
    or a lift-off that thrust cannot hold): the ground's reaction holds it, so the
    accelerometer reads +g up, not the free fall of the bare derivative; one metre up, the
    same pitches (no thrust) are a free fall: zero specific force."""
    from heli_common.defaults import HOME
    from heli_common.vehicle.airframe import Airframe
    from heli_plant.sensors.sensing import Sensing

    af = Airframe.load()
    c = af.constants()
    sensing = Sensing.build(Sensors(imu=Imu(on=True, rate_hz=100.0)), 0.01, c.gravity_m_s2, HOME)
    x = np.zeros(N_STATE)
    no_thrust = np.zeros(4)
    sensing.sample(0.0, x, no_thrust, c, False, None)
    assert_allclose(sensing.meas[OUT_ACCEL : OUT_ACCEL + 3], [0.0, 0.0, c.gravity_m_s2], atol=1e-9)
    x[Z_U] = 1.0
    sensing.sample(0.01, x, no_thrust, c, False, None)
    assert_allclose(sensing.meas[OUT_ACCEL : OUT_ACCEL + 3], [0.0, 0.0, 0.0], atol=1e-9)


def test_specific_force_in_a_coordinated_turn() -> None:
    """A level left turn at V = 10 m/s, yaw rate 0.5 rad/s, banked phi = -atan(V w / g) (FLU:
    left wing down): the earth acceleration is V w toward the centre and the accelerometer
    reads only (0, 0, sqrt(g^2 + (V w)^2)), nothing sideways."""
    v, w, psi = 10.0, 0.5, 0.7
    phi = -math.atan(v * w / G)
    x = np.zeros(N_STATE)
    x[PHI], x[PSI], x[U_F] = phi, psi, v
    x[OMEGA] = (0.0, math.sin(phi) * w, math.cos(phi) * w)  # E(gamma) (0, 0, w)
    xdot = np.zeros(N_STATE)  # body velocity and rates are constant in the steady turn
    a = np.array(earth_accel_from_derivative(x, xdot))
    assert_allclose(a, v * w * np.array([-math.sin(psi), math.cos(psi), 0.0]), atol=1e-12)
    f = specific_force_flu(x, a, G)
    assert_allclose(f, [0.0, 0.0, math.hypot(G, v * w)], atol=1e-12)
    # the finite difference of two states half a step either side agrees to O(h^2)
    h = 0.01
    x0, x1 = x.copy(), x.copy()
    x0[PSI], x1[PSI] = psi - w * h / 2, psi + w * h / 2
    assert_allclose(earth_accel_from_states(x0, x1, h), a, atol=1e-4)
    # and the model's IMU sample is that specific force
    imu = SensorModel(Sensors(imu=Imu(on=True)), 0.01, G).step(0.0, x, a).imu
    assert imu is not None
    assert_allclose(imu.accel_flu_m_s2, f, rtol=0, atol=0)
    assert_allclose(imu.gyro_flu_rad_s, x[OMEGA], rtol=0, atol=0)


# --- determinism ------------------------------------------------------------------------------------------


def _trajectory(n: int) -> tuple[FloatArray, FloatArray]:
    k = np.arange(n)[:, None]
    xs = np.sin(0.01 * k * (1.0 + np.arange(N_STATE))[None, :]) * (1.0 + np.arange(N_STATE))[None, :] * 0.1
    accs = np.cos(0.02 * k * np.arange(1, 4)[None, :])
    return xs, accs


def _samples(m: SensorModel, n: int, h: float = 0.01) -> list[tuple[object, ...]]:
    xs, accs = _trajectory(n)
    return [tuple(m.step(k * h, xs[k], accs[k])) for k in range(n)]


def test_same_seed_same_samples_other_seed_differs() -> None:
    a = _samples(SensorModel(preset("noisy"), 0.01, G), 400)
    b = _samples(SensorModel(preset("noisy"), 0.01, G), 400)
    c = _samples(SensorModel(dataclasses.replace(preset("noisy"), seed=2), 0.01, G), 400)
    assert a == b
    for i in range(5):  # every sensor's values change with the seed
        pairs = [(s[i], t[i]) for s, t in zip(a, c, strict=True) if s[i] is not None]
        assert pairs and all(s != t for s, t in pairs)


def test_streams_do_not_collide_with_the_world() -> None:
    ids = [getattr(model, n) for n in dir(model) if n.startswith("STREAM_") and n != "STREAM_SENSOR_BASE"]
    assert len(ids) == len(set(ids)) == 11
    assert min(ids) >= STREAM_SENSOR_BASE == 16


_PY_SCRIPT = """
import json, sys
import numpy as np
from heli_common.world.sensors import preset
from heli_plant.sensors.model import SensorModel
g, h, xs, accs = json.load(sys.stdin)
m = SensorModel(preset("noisy"), h, g)
print(json.dumps([tuple(m.step(k * h, np.array(xs[k]), np.array(accs[k]))) for k in range(len(xs))]))
"""


def test_plain_python_matches_compiled() -> None:
    """NUMBA_DISABLE_JIT=1 (plain Python) gives the very same numbers, bit for bit."""
    xs, accs = _trajectory(120)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    given = json.dumps([G, 0.01, xs.tolist(), accs.tolist()])
    proc = subprocess.run([sys.executable, "-c", _PY_SCRIPT], input=given, capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120, check=True)  # fmt: skip
    got = json.loads(proc.stdout)
    ref = json.loads(json.dumps(_samples(SensorModel(preset("noisy"), 0.01, G), 120)))
    assert any(s[1] is not None for s in ref)  # GPS fixes are among them
    assert got == ref


def test_update_keeps_the_noise_processes() -> None:
    """Stopping half way and taking the same settings again changes nothing."""
    xs, accs = _trajectory(600)
    a = SensorModel(preset("noisy"), 0.01, G)
    b = SensorModel(preset("noisy"), 0.01, G)
    ra = [a.step(k * 0.01, xs[k], accs[k]) for k in range(600)]
    rb = []
    for k in range(600):
        if k == 300:
            b.update(dataclasses.replace(preset("noisy"), name="again"))
        rb.append(b.step(k * 0.01, xs[k], accs[k]))
    assert ra == rb


def test_update_keeps_fixes_in_flight_and_moves_to_a_new_rate() -> None:
    cfg = Sensors(gps=Gps(on=True, rate_hz=5.0, lag_s=0.5))
    m = SensorModel(cfg, 0.01, G)
    x, a = np.zeros(N_STATE), np.zeros(3)
    t_valid = []
    for k in range(2000):
        if k == 1000:  # longer lag: the fixes in flight wait longer, none is lost
            m.update(dataclasses.replace(cfg, gps=dataclasses.replace(cfg.gps, lag_s=1.0)))
        if k == 1500:
            m.update(dataclasses.replace(cfg, gps=dataclasses.replace(cfg.gps, lag_s=1.0, rate_hz=2.0)))
        fix = m.step(k * 0.01, x, a).gps
        if fix is not None:
            t_valid.append(fix.t_s)
    d = np.diff(t_valid)
    before = np.array(t_valid[:-1]) < 15.0 - 1e-9
    assert_allclose(d[before], 0.2, atol=1e-9)
    assert_allclose(d[~before], 0.5, atol=1e-9)  # 2 Hz from its first grid point on


# --- ideal sensors, failures --------------------------------------------------------------------------


def test_every_sensor_off_reads_the_truth_exactly() -> None:
    rng = np.random.default_rng(4)
    m = SensorModel(Sensors(), 0.01, G)
    for k in range(200):
        x = rng.normal(size=N_STATE)
        a = rng.normal(size=3)
        s = m.step(k * 0.01, x, a)
        assert s.imu is not None and s.gps is not None and s.attitude is not None and s.baro is not None
        assert s.mag is not None
        assert s.imu.t_s == s.gps.t_s == s.attitude.t_s == s.baro.t_s == s.mag.t_s == k * 0.01
        assert s.imu.gyro_flu_rad_s == tuple(x[OMEGA])
        assert s.imu.accel_flu_m_s2 == specific_force_flu(x, a, G)
        assert s.gps.pos_nwu_m == tuple(x[POS])
        assert s.gps.vel_nwu_m_s == velocity_nwu(x)
        assert s.attitude.euler_rad == tuple(x[EULER])
        assert s.baro.alt_m == x[Z_U]
        assert s.mag.field_flu_gauss == magnetic_field_flu(x, m.params[SNP_MAG_FIELD : SNP_MAG_FIELD + 3])


def test_gps_disable_stops_fixes() -> None:
    cfg = preset("gps-typical")
    m = SensorModel(cfg, 0.01, G)
    x, a = np.zeros(N_STATE), np.zeros(3)
    counts = [0, 0, 0]
    for k in range(3000):
        if k == 1000:
            m.update(with_sensor_param(cfg, "SIM_GPS_DISABLE", 1.0))
        if k == 2000:
            m.update(cfg)
        s = m.step(k * 0.01, x, a)
        counts[k // 1000] += s.gps is not None
        assert s.imu is not None  # the other sensors go on
    assert counts[0] == 50 and counts[1] == 0 and counts[2] >= 49


def test_freeze_and_step_bias() -> None:
    """From 3 s: the baro and the GPS hold their last values while their times go on; the
    gyro gets a step bias; the attitude a step."""
    cfg = Sensors(
        seed=9,
        imu=Imu(on=True, gyro_density_rad_s_rthz=N_GYRO, fault_start_s=3.0, gyro_step_rad_s=(0.1, 0.0, -0.1)),
        gps=Gps(on=True, noise_h_m=1.0, freeze=True, fault_start_s=3.0),
        attitude=Attitude(fault_start_s=3.0, step_rad=(0.0, 0.05, 0.0)),
        baro=Baro(on=True, noise_m=0.2, freeze=True, fault_start_s=3.0),
    )
    rec, masks = _run(cfg, 0.01, 600)
    t = np.arange(600) * 0.01
    after = t >= 3.0 - 1e-9
    baro = np.flatnonzero(masks & NEW_BARO)
    frozen = baro[rec[baro, OUT_BARO_T] >= 3.0 - 1e-9]
    assert np.all(rec[frozen, OUT_BARO_ALT] == rec[frozen[0] - 2, OUT_BARO_ALT])  # the 2.98 s sample
    assert np.all(np.diff(rec[frozen, OUT_BARO_T]) > 0.0)
    gps = np.flatnonzero(masks & NEW_GPS)
    late = gps[rec[gps, OUT_GPS_T] >= 3.0 - 1e-9]
    assert len(late) > 5 and np.all(rec[late, OUT_GPS_POS] == rec[late[0] - 20, OUT_GPS_POS])  # the 2.8 s fix
    early = gps[rec[gps, OUT_GPS_T] < 3.0 - 1e-9]
    assert len(np.unique(rec[early, OUT_GPS_POS])) == len(early)  # before the fault every fix is new
    gyro = rec[:, OUT_GYRO : OUT_GYRO + 3]
    assert abs(gyro[after, 0].mean() - 0.1) < 1e-3 and abs(gyro[~after, 0].mean()) < 1e-3
    assert np.all(rec[after, OUT_ATT + 1] == 0.05) and np.all(rec[~after, OUT_ATT + 1] == 0.0)


def test_rates_above_the_plant_rate_are_refused() -> None:
    with pytest.raises(ValueError, match="exceeds the plant rate"):
        SensorModel(Sensors(imu=Imu(on=True, rate_hz=200.0)), 0.01, G)
    SensorModel(Sensors(imu=Imu(on=False, rate_hz=200.0)), 0.01, G)  # off: the rate is not used
    with pytest.raises(ValueError, match=r"gps\.lag_s"):
        SensorModel(Sensors(gps=Gps(lag_s=-0.1)), 0.01, G)


def test_imu_at_a_lower_rate_than_the_plant() -> None:
    rec, masks = _run(Sensors(imu=Imu(on=True, rate_hz=50.0)), 0.01, 100)
    got = np.flatnonzero(masks & NEW_IMU)
    assert_allclose(rec[got, OUT_IMU_T], np.arange(50) * 0.02, atol=1e-12)


# --- configuration, presets, SIM_ parameters ----------------------------------------------------------


def test_defaults_are_off() -> None:
    s = Sensors()
    assert not s.on and not s.errors_on and not s.faults_on
    assert validate(s) is s


def test_presets_build_and_carry_the_documented_numbers() -> None:
    assert set(PRESETS) == {"gps-typical", "imu-consumer", "noisy", "consumer"}
    for name in PRESETS:
        s = validate(preset(name))
        assert s.name == name and s.errors_on and not s.faults_on
    g = preset("gps-typical").gps
    per_axis = math.hypot(g.wander_h_m, g.noise_h_m)
    assert abs(1.1774 * per_axis - 2.5) < 0.01  # 2.5 m CEP
    assert (g.rate_hz, g.lag_s, g.vel_noise_m_s, g.wander_tau_s) == (5.0, 0.1, 0.05, 60.0)
    assert preset("gps-typical").baro.noise_m == 0.2
    i = preset("imu-consumer").imu
    vals = sensor_sim_values(preset("imu-consumer"))
    assert_allclose(vals["SIM_GYR_RND"], 0.05, rtol=1e-12)  # deg/s at 100 Hz
    assert_allclose(vals["SIM_ACC_RND"], 0.0392266, rtol=1e-6)  # m/s^2
    assert_allclose(i.gyro_walk_rad_s_rts * 60.0, 10.0 * DEG / 3600.0, rtol=1e-12)  # 10 deg/h after 1 h
    c = preset("consumer")
    assert (c.gps, c.baro) == (preset("gps-typical").gps, preset("gps-typical").baro)
    assert (c.imu, c.mag) == (preset("imu-consumer").imu, preset("imu-consumer").mag)
    with pytest.raises(ValueError, match="unknown sensors preset"):
        preset("perfect")


def test_toml_round_trip_and_errors(tmp_path: Path) -> None:
    """The sensors live in a world file's [sensors] table; the world's seed drives them."""
    f = tmp_path / "s.toml"
    f.write_text('name = "t"\nseed = 4\n[sensors.gps]\non = true\nrate_hz = 10.0\nwander_h_m = 1.5\n'
                 "[sensors.imu]\ngyro_bias_rad_s = [0.01, 0.0, -0.01]\n")  # fmt: skip
    w = World.load(f)
    s = w.sensors
    assert s.gps.on and s.gps.rate_hz == 10.0 and s.gps.wander_h_m == 1.5 and s.seed == 4 and w.sensing
    assert s.imu.gyro_bias_rad_s == (0.01, 0.0, -0.01) and not w.on  # no physics changed
    f.write_text("[sensors.gps]\nrate_hz = 0.0\n")
    with pytest.raises(ConfigError, match="rate_hz"):
        World.load(f)
    f.write_text("[sensors.baro]\nnoise = 1.0\n")
    with pytest.raises(ConfigError, match="did you mean 'noise_m'"):
        World.load(f)
    f.write_text("seed = 2\n[sensors]\nseed = 3\n")
    with pytest.raises(ConfigError, match="no seed"):
        World.load(f)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_files_are_the_documented_numbers(name: str) -> None:
    """configs/world/NAME.toml holds exactly the preset's numbers (PRESETS documents them)."""
    w = World.load(name)
    assert w.sensors == dataclasses.replace(preset(name), name="ideal", seed=w.seed)
    assert w.seed == PRESETS[name]["seed"] and w.sensing and not w.on


def test_sim_param_round_trip() -> None:
    s = preset("noisy")
    assert set(sensor_sim_values(s)) == SIM_SENSOR_PARAM_NAMES
    assert SIM_SENSOR_PARAM_NAMES < SIM_PARAM_NAMES  # live knobs of the world file they sit in
    assert not SIM_SENSOR_PARAM_NAMES & {p.name for p in WORLD_SIM_PARAMS}  # no clash
    values = {
        "SIM_GPS_HZ": 10.0, "SIM_GPS_LAG_MS": 150.0, "SIM_GPS_NOISE": 3.3, "SIM_GPS_DISABLE": 1.0,
        "SIM_ACC_RND": 0.2, "SIM_GYR_RND": 0.3, "SIM_BARO_RND": 0.7, "SIM_BARO_DRIFT": -0.01,
    }  # fmt: skip
    for p in SIM_SENSOR_PARAMS:
        v = values[p.name]
        new = with_sensor_param(s, p.name, v)
        assert new != s
        assert np.float32(sensor_sim_values(new)[p.name]) == np.float32(v)
        others = {k: w for k, w in sensor_sim_values(new).items() if k != p.name}
        assert others == {k: w for k, w in sensor_sim_values(s).items() if k != p.name}
        # the same value again (or its float32 echo) leaves the configuration as it is
        assert with_sensor_param(new, p.name, float(np.float32(v))) is new
        with pytest.raises(ValueError, match=p.name):
            with_sensor_param(s, p.name, p.hi + 1.0)
        with pytest.raises(ValueError, match=p.name):
            with_sensor_param(s, p.name, math.nan)
    assert with_sensor_param(s, "SIM_GPS_LAG_MS", 200.0) is s
    assert with_sensor_param(s, "SIM_GPS_DISABLE", 1.0).gps.disabled
    assert with_sensor_param(s, "SIM_GYR_RND", 0.3).imu.gyro_density_rad_s_rthz == pytest.approx(
        math.radians(0.3) / 10.0
    )
    with pytest.raises(ValueError, match="0 or 1"):
        with_sensor_param(s, "SIM_GPS_DISABLE", 0.5)
    with pytest.raises(ValueError, match="unknown sensor parameter"):
        with_sensor_param(s, "SIM_GPS1_HZ", 5.0)
