"""Wind model (heli_plant.world): counter-based noise, mean wind, gusts, Dryden turbulence.

Everything is checked against theory: the noise's moments, the exact discretisation's
stationarity (Phi P Phi^T + Q_d = P, C P C^T = sigma^2), and long seeded runs of the compiled
filters against the MIL-F-8785C variances, one-sided spectra and the u autocorrelation.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
import scipy.stats
from numpy.testing import assert_allclose

from heli_common.jit import njit
from heli_common.state import FloatArray
from heli_common.world.gusts import gust_factor, mean_wind_nwu
from heli_plant.world import noise
from heli_plant.world.noise import STREAM_TURB_U, STREAM_TURB_V, normal, normal_pair
from heli_plant.world.wind import (
    B_L11,
    B_L21,
    B_L22,
    B_PHI11,
    B_PHI12,
    B_PHI21,
    B_PHI22,
    B_SIGMA,
    C_U_A,
    C_U_G,
    C_U_SIGMA,
    C_V,
    C_W,
    KT_M_S,
    N_DRYDEN_COEFFS,
    N_DRYDEN_STATE,
    dryden_coefficients,
    dryden_init,
    dryden_low_altitude,
    dryden_output,
    dryden_step,
    second_order_discrete,
    turbulence_nwu,
)

ROOT = Path(__file__).resolve().parent.parent

# --- compiled drivers (a Python loop over 1e6 steps would dominate the run time) ----------


@njit
def _draws(seed: int, stream: int, n: int) -> FloatArray:
    out = np.empty((n, 2))
    for k in range(n):
        a, b = normal_pair(seed, stream, k)
        out[k, 0] = a
        out[k, 1] = b
    return out


@njit
def _run(coeffs: FloatArray, seed: int, n: int) -> FloatArray:
    """n samples of (u_g, v_g, w_g): stationary start, then one step per sample."""
    state = np.empty(N_DRYDEN_STATE)
    dryden_init(coeffs, state, seed)
    out = np.empty((n, 3))
    for k in range(n):
        u, v, w = dryden_output(coeffs, state)
        out[k, 0] = u
        out[k, 1] = v
        out[k, 2] = w
        dryden_step(coeffs, state, seed, k)
    return out


# --- noise ---------------------------------------------------------------------------------

N_DRAWS = 200_000


def test_normal_moments_and_whiteness() -> None:
    x = _draws(12345, STREAM_TURB_U, N_DRAWS)
    tol = 4.0 / math.sqrt(N_DRAWS)
    for col in (x[:, 0], x[:, 1]):
        assert abs(col.mean()) < tol
        assert abs(col.var() - 1.0) < 4.0 * math.sqrt(2.0 / N_DRAWS)
        assert abs(np.corrcoef(col[:-1], col[1:])[0, 1]) < tol  # no lag-1 correlation
        assert scipy.stats.kstest(col, "norm").pvalue > 1e-4
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < tol  # the pair is independent
    # normal() is the first deviate of the pair
    assert normal(12345, STREAM_TURB_U, 7) == x[7, 0]


def test_normal_deterministic_and_seeds_streams_differ() -> None:
    n = 20_000
    a = _draws(1, STREAM_TURB_U, n)[:, 0]
    assert np.array_equal(a, _draws(1, STREAM_TURB_U, n)[:, 0])
    others = [_draws(2, STREAM_TURB_U, n)[:, 0], _draws(1, STREAM_TURB_V, n)[:, 0]]
    for b in others:
        assert not np.any(a == b)
        assert abs(np.corrcoef(a, b)[0, 1]) < 4.0 / math.sqrt(n)
    # negative and large counters/seeds are valid keys
    assert normal(-1, noise.STREAM_SENSOR_BASE, -1) != normal(-1, noise.STREAM_SENSOR_BASE, 0)
    assert math.isfinite(normal(2**63 - 1, 3, 2**62))


_PY_SCRIPT = """
import json
import numpy as np
from heli_plant.world.noise import normal
from heli_plant.world import wind
keys = json.loads(input())
vals = [normal(s, st, k) for s, st, k in keys]
c = wind.dryden_coefficients(*wind.dryden_low_altitude(12.0, 6.0), 3.0, 0.02)
state = np.zeros(wind.N_DRYDEN_STATE)
wind.dryden_init(c, state, 99)
out = []
for k in range(50):
    wind.dryden_step(c, state, 99, k)
    out.append(list(wind.dryden_output(c, state)))
print(json.dumps({"normal": vals, "turb": out}))
"""

_KEYS = [
    (s, st, k) for s in (0, 1, -5, 2**62, 987654321) for st in (1, 2, 3, 4, 16) for k in (-1, 0, 1, 10**12)
]


def test_plain_python_matches_compiled() -> None:
    """NUMBA_DISABLE_JIT=1 (plain Python ints, masked) gives the very same numbers."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    proc = subprocess.run(
        [sys.executable, "-c", _PY_SCRIPT],
        input=json.dumps(_KEYS),
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=60,
        check=True,
    )
    got = json.loads(proc.stdout)
    assert got["normal"] == [normal(s, st, k) for s, st, k in _KEYS]
    c = dryden_coefficients(*dryden_low_altitude(12.0, 6.0), 3.0, 0.02)
    state = np.zeros(N_DRYDEN_STATE)
    dryden_init(c, state, 99)
    ref = []
    for k in range(50):
        dryden_step(c, state, 99, k)
        ref.append(list(dryden_output(c, state)))
    assert_allclose(np.array(got["turb"]), np.array(ref), rtol=1e-13, atol=1e-15)


# --- mean wind, MIL-F-8785C parameters, axes, gusts -----------------------------------------


def test_mean_wind_mapping() -> None:
    s = 5.0
    assert_allclose(mean_wind_nwu(s, 0.0, 0.0), [-s, 0.0, 0.0], atol=1e-12)  # from north: blows south
    assert_allclose(mean_wind_nwu(s, 90.0, 0.0), [0.0, s, 0.0], atol=1e-12)  # from east: blows west (+y)
    assert_allclose(mean_wind_nwu(s, 180.0, 0.0), [s, 0.0, 0.0], atol=1e-12)  # ArduPilot default DIR
    assert_allclose(mean_wind_nwu(s, 270.0, 0.0), [0.0, -s, 0.0], atol=1e-12)
    assert_allclose(mean_wind_nwu(s, 37.0, 90.0), [0.0, 0.0, s], atol=1e-12)  # pure updraft
    w = mean_wind_nwu(s, 123.0, 30.0)
    assert_allclose(np.linalg.norm(w), s)
    assert_allclose(w[2], s * 0.5)


def test_dryden_low_altitude_spec_numbers() -> None:
    # The reference numbers were evidently computed with W20 = 15 kt = 7.7167 m/s (quoted as
    # 7.72): with exactly 7.72 m/s sigma_u at 10 m is 1.458, not 1.457.
    w20 = 15.0 * KT_M_S
    for h, l_ref, s_ref in ((3.0, 23.1, 1.515), (10.0, 67.4, 1.457), (30.0, 152.5, 1.327)):
        l_u, l_v, l_w, s_u, s_v, s_w = dryden_low_altitude(h, w20)
        assert abs(l_u - l_ref) <= 0.05 and abs(s_u - s_ref) <= 0.0005, (h, l_u, s_u)
        assert l_v == l_u and s_v == s_u
        assert abs(s_w - 0.772) <= 0.0005
        assert l_w == pytest.approx(max(h, 10 * 0.3048), rel=1e-15)
    assert dryden_low_altitude(10.0, 7.72)[5] == pytest.approx(0.772)
    assert dryden_low_altitude(10.0, 7.72)[3] == pytest.approx(1.4580, abs=5e-5)
    # clipped to [10, 1000] ft; SI form of the lengths with 0.000823/0.3048 per metre
    assert dryden_low_altitude(0.0, 7.0) == dryden_low_altitude(3.048, 7.0)
    assert dryden_low_altitude(1e4, 7.0) == dryden_low_altitude(304.8, 7.0)
    h = 50.0
    assert_allclose(dryden_low_altitude(h, 7.0)[0], h / (0.177 + 0.000823 / 0.3048 * h) ** 1.2)


def test_turbulence_axes() -> None:
    for psi in (0.0, 0.7, 2.0, -2.5):
        e_u = np.array(turbulence_nwu(1.0, 0.0, 0.0, psi, False))
        e_v = np.array(turbulence_nwu(0.0, 1.0, 0.0, psi, False))
        e_w = np.array(turbulence_nwu(0.0, 0.0, 1.0, psi, False))
        assert_allclose(e_u, [-math.cos(psi), math.sin(psi), 0.0], atol=1e-15)  # downwind
        assert_allclose(e_v, np.cross([0.0, 0.0, 1.0], e_u), atol=1e-15)
        assert_allclose(e_w, [0.0, 0.0, 1.0])
        assert_allclose(np.cross(e_u, e_v), e_w, atol=1e-15)  # right-handed
        # u along the mean wind from the same direction
        m = mean_wind_nwu(1.0, math.degrees(psi), 0.0)
        assert_allclose(e_u, m, atol=1e-12)
    assert_allclose(turbulence_nwu(1.0, 0.0, 0.0, 1.3, True), [1.0, 0.0, 0.0])  # calm: u north
    assert_allclose(turbulence_nwu(0.0, 1.0, 0.0, 1.3, True), [0.0, 1.0, 0.0], atol=1e-15)


def test_gust_profile() -> None:
    v_m, start, rise, hold, fall = 3.0, 1.0, 2.0, 4.0, 3.0
    assert gust_factor(0.999, start, rise, hold, fall) == 0.0
    assert gust_factor(start, start, rise, hold, fall) == 0.0
    assert v_m * gust_factor(start + rise / 2, start, rise, hold, fall) == pytest.approx(v_m / 2)
    assert gust_factor(start + rise, start, rise, hold, fall) == pytest.approx(1.0)  # peak
    assert gust_factor(start + rise + hold, start, rise, hold, fall) == 1.0
    assert gust_factor(start + rise + hold + fall / 2, start, rise, hold, fall) == pytest.approx(0.5)
    assert gust_factor(start + rise + hold + fall + 1e-9, start, rise, hold, fall) == 0.0
    t = np.linspace(0.0, 15.0, 150_001)
    g = np.array([gust_factor(ti, start, rise, hold, fall) for ti in t])
    assert g.min() == 0.0 and g.max() == 1.0
    assert np.abs(np.diff(g)).max() < 1e-3  # continuous (max slope pi/(2 rise) * dt)
    dt = t[1] - t[0]
    assert (g > 0).sum() * dt == pytest.approx(rise + hold + fall, abs=2 * dt)  # duration
    # 8785C form: the gust stays
    assert gust_factor(1e6, start, rise, math.inf, fall) == 1.0
    # steps for zero durations
    assert gust_factor(1.0, 1.0, 0.0, 1.0, 0.0) == 1.0
    assert gust_factor(2.0 + 1e-9, 1.0, 0.0, 1.0, 0.0) == 0.0


# --- exact discretisation -------------------------------------------------------------------


def _textbook(coeffs: FloatArray, base: int, b: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(Phi, Q_d, P) of a second-order block in the textbook state x = (x1, x1')."""
    phi_z = np.array(
        [[coeffs[base + B_PHI11], coeffs[base + B_PHI12]], [coeffs[base + B_PHI21], coeffs[base + B_PHI22]]]
    )
    chol = np.array([[coeffs[base + B_L11], 0.0], [coeffs[base + B_L21], coeffs[base + B_L22]]])
    d = np.diag([b**1.5 / 2.0, b**0.5 / 2.0])
    d_inv = np.linalg.inv(d)
    return d @ phi_z @ d_inv, d @ (chol @ chol.T) @ d, np.diag([b**3 / 4.0, b / 4.0])


@pytest.mark.parametrize(("v_m_s", "dt_s"), [(1.0, 0.01), (5.0, 0.05), (12.0, 0.5), (1.0, 0.001)])
def test_discretisation_is_stationary(v_m_s: float, dt_s: float) -> None:
    l_u, l_v, l_w, s_u, s_v, s_w = dryden_low_altitude(20.0, 8.0)
    c = dryden_coefficients(l_u, l_v, l_w, s_u, s_v, s_w, v_m_s, dt_s)
    assert c.shape == (N_DRYDEN_COEFFS,) and c.dtype == np.float64
    # u: a = exp(-V dt/L_u), a^2 + g^2 = 1 (stationary unit variance)
    assert_allclose(c[C_U_A], math.exp(-v_m_s * dt_s / l_u), rtol=1e-15)
    assert_allclose(c[C_U_A] ** 2 + c[C_U_G] ** 2, 1.0, rtol=1e-15)
    for base, length, sigma in ((C_V, l_v, s_v), (C_W, l_w, s_w)):
        b = length / v_m_s
        phi, q_d, p = _textbook(c, base, b)
        e = math.exp(-dt_s / b)
        phi_ref = e * np.array([[1 + dt_s / b, dt_s], [-dt_s / b**2, 1 - dt_s / b]])
        assert_allclose(phi, phi_ref, rtol=1e-13, atol=1e-300)
        assert_allclose(phi @ p @ phi.T + q_d, p, rtol=1e-12, atol=1e-15 * p.max())
        c_row = sigma * math.sqrt(length / v_m_s) / b**2 * np.array([1.0, math.sqrt(3.0) * b])
        assert_allclose(c_row @ p @ c_row, sigma**2, rtol=1e-13)
        # Q_d independently, by Van Loan's matrix exponential of [[-A, B B^T], [0, A^T]] dt
        a = np.array([[0.0, 1.0], [-1.0 / b**2, -2.0 / b]])
        m = np.zeros((4, 4))
        m[:2, :2] = -a
        m[:2, 2:] = np.diag([0.0, 1.0])
        m[2:, 2:] = a.T
        ex = scipy.linalg.expm(m * dt_s)
        q_vl = ex[2:, 2:].T @ ex[:2, 2:]
        assert_allclose(q_d, q_vl, rtol=1e-8, atol=1e-14 * np.abs(q_vl).max())


def test_output_row_and_small_steps() -> None:
    """Output row C D = sigma (1, sqrt 3)/2 in normalised coordinates; u is sigma_u z_u."""
    c = dryden_coefficients(10.0, 20.0, 30.0, 1.0, 2.0, 3.0, 1.0, 0.01)
    for i, ref in enumerate(np.eye(N_DRYDEN_STATE)):
        out = np.zeros(3)
        out[[0, 1, 1, 2, 2][i]] = [1.0, 1.0, math.sqrt(3.0), 1.5, 1.5 * math.sqrt(3.0)][i]
        assert_allclose(dryden_output(c, ref), out, atol=1e-15)
    # tiny tau: Q_d keeps its leading terms (4 tau^3/3, 2 tau^2, 4 tau) instead of cancelling
    tau = 1e-7
    _, q = second_order_discrete(tau)
    assert_allclose(q, [[4 * tau**3 / 3, 2 * tau**2], [2 * tau**2, 4 * tau]], rtol=1e-6)


def test_zero_sigma_gives_exact_zero() -> None:
    c = dryden_coefficients(30.0, 30.0, 10.0, 0.0, 0.0, 0.0, 2.0, 0.01)
    assert not np.any(_run(c, 5, 1000))


def test_seeded_sequences() -> None:
    c = dryden_coefficients(*dryden_low_altitude(10.0, 7.0), 3.0, 0.01)
    a = _run(c, 7, 2000)
    assert np.array_equal(a, _run(c, 7, 2000))
    b = _run(c, 8, 2000)
    assert not np.any(a == b)


# --- long seeded runs against the continuous model ----------------------------------------

H_M, W20, V_M_S, DT_S, N_STEPS = 10.0, 15.0 * KT_M_S, 5.0, 0.05, 1_000_000


@pytest.fixture(scope="module")
def long_run() -> tuple[FloatArray, tuple[float, float, float, float, float, float]]:
    params = dryden_low_altitude(H_M, W20)
    return _run(dryden_coefficients(*params, V_M_S, DT_S), 2024, N_STEPS), params


def _phi_u(omega: FloatArray, sigma: float, length: float, v_m_s: float) -> FloatArray:
    """MIL-F-8785C u spectrum per rad/s, one-sided: Phi(Omega = omega/V)/V."""
    lo = length * omega / v_m_s
    return sigma**2 * (2 * length / math.pi) / (1 + lo**2) / v_m_s


def _phi_vw(omega: FloatArray, sigma: float, length: float, v_m_s: float) -> FloatArray:
    """MIL-F-8785C v (and w, with L_w) spectrum per rad/s, one-sided."""
    lo = length * omega / v_m_s
    return sigma**2 * (length / math.pi) * (1 + 3 * lo**2) / (1 + lo**2) ** 2 / v_m_s


def test_long_run_variance(long_run: tuple[FloatArray, tuple[float, ...]]) -> None:
    x, (l_u, l_v, l_w, s_u, s_v, s_w) = long_run
    t_total = N_STEPS * DT_S
    for col, length, sigma in ((0, l_u, s_u), (1, l_v, s_v), (2, l_w, s_w)):
        rel = x[:, col].var() / sigma**2 - 1.0
        assert abs(rel) < 4.0 * math.sqrt(2.0 * (length / V_M_S) / t_total), (col, rel)
        assert abs(x[:, col].mean()) < 4.0 * sigma * math.sqrt(2.0 * (length / V_M_S) / t_total)


def _aliased(
    phi: Callable[..., FloatArray],
    f: FloatArray,
    sigma: float,
    length: float,
    v_m_s: float,
    fs: float,
    m_max: int = 4000,
) -> FloatArray:
    """One-sided PSD per Hz of the continuous process sampled at fs: sum over the aliases."""
    m = np.arange(-m_max, m_max + 1)[:, None]
    psd: FloatArray = (
        2 * math.pi * phi(2 * math.pi * np.abs(f[None, :] + m * fs), sigma, length, v_m_s)
    ).sum(axis=0)
    return psd


def _discrete_psd(
    coeffs: FloatArray, f: FloatArray, dt_s: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One-sided PSD per Hz of (u, v, w) of the discrete filters held in ``coeffs``."""
    z = np.exp(2j * math.pi * f * dt_s)
    a, g = coeffs[C_U_A], coeffs[C_U_G]
    psd_u = 2 * dt_s * (coeffs[C_U_SIGMA] * g) ** 2 / np.abs(z - a) ** 2
    out = [psd_u]
    for base in (C_V, C_W):
        phi = np.array(
            [
                [coeffs[base + B_PHI11], coeffs[base + B_PHI12]],
                [coeffs[base + B_PHI21], coeffs[base + B_PHI22]],
            ]
        )
        chol = np.array([[coeffs[base + B_L11], 0.0], [coeffs[base + B_L21], coeffs[base + B_L22]]])
        row = coeffs[base + B_SIGMA] * np.array([0.5, 0.5 * math.sqrt(3.0)])
        h = np.array([row @ np.linalg.solve(zi * np.eye(2) - phi, chol) for zi in z])
        out.append(2 * dt_s * np.sum(np.abs(h) ** 2, axis=1))
    return out[0], out[1], out[2]


@pytest.mark.parametrize(("v_m_s", "dt_s"), [(1.0, 0.01), (5.0, 0.05), (12.0, 0.5)])
def test_discrete_spectrum_is_the_sampled_continuous_one(v_m_s: float, dt_s: float) -> None:
    """Exactness: the filters' spectrum equals the aliased Dryden spectrum, even for coarse steps."""
    params = dryden_low_altitude(10.0, 8.0)
    l_u, l_v, l_w, s_u, s_v, s_w = params
    fs = 1.0 / dt_s
    f = np.linspace(0.001 * fs, 0.5 * fs, 60)
    got = _discrete_psd(dryden_coefficients(*params, v_m_s, dt_s), f, dt_s)
    for psd, phi, sigma, length in zip(
        got, (_phi_u, _phi_vw, _phi_vw), (s_u, s_v, s_w), (l_u, l_v, l_w), strict=True
    ):
        assert_allclose(psd, _aliased(phi, f, sigma, length, v_m_s, fs), rtol=2e-4)


def test_long_run_spectrum(long_run: tuple[FloatArray, tuple[float, ...]]) -> None:
    """Welch PSD vs 2 pi Phi(2 pi f): within 10 % (the ~4 % excess near 0.2 f_s is aliasing,
    which the sampled process must have: against the aliased spectrum the median is within 2 %)."""
    x, (l_u, l_v, l_w, s_u, s_v, s_w) = long_run
    fs = 1.0 / DT_S
    for col, phi, length, sigma in ((0, _phi_u, l_u, s_u), (1, _phi_vw, l_v, s_v), (2, _phi_vw, l_w, s_w)):
        f, pxx = scipy.signal.welch(x[:, col], fs=fs, nperseg=2**14)
        band = (f >= 0.01) & (f <= 0.2 * fs)
        ratio = pxx[band] / (2 * math.pi * phi(2 * math.pi * f[band], sigma, length, V_M_S))
        assert 0.9 <= np.median(ratio) <= 1.1, (col, np.median(ratio))
        ratio_aliased = pxx[band] / _aliased(phi, f[band], sigma, length, V_M_S, fs, m_max=1000)
        assert 0.98 <= np.median(ratio_aliased) <= 1.02, (col, np.median(ratio_aliased))


def test_long_run_u_autocorrelation(long_run: tuple[FloatArray, tuple[float, ...]]) -> None:
    x, (l_u, *_) = long_run
    u = x[:, 0] - x[:, 0].mean()
    b = l_u / V_M_S
    tol = 4.0 * math.sqrt(b / (N_STEPS * DT_S))
    for lag_s in (0.25 * b, 0.5 * b, b, 2.0 * b):
        lag = round(lag_s / DT_S)
        rho = np.dot(u[:-lag], u[lag:]) / np.dot(u, u)
        assert abs(rho - math.exp(-lag * DT_S / b)) < tol, (lag_s, rho)
