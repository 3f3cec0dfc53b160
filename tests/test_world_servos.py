"""Servo chain (heli_common.world.servo_model) against the analytic responses of its elements."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from heli_common.state import EPS, ETA, N_PITCH, THETA_M, THETA_T, FloatArray
from heli_common.world.servo_model import (
    N_SERVO_PARAM,
    SP_ALPHA,
    SP_DELAY_STEPS,
    SP_RATE_STEP,
    SS_FIFO,
    SS_POSITION,
    SS_RING_INDEX,
    SS_TARGET,
    fifo_slots,
    rate_limit_from_speed,
    servo_parameters,
    servo_state,
    servo_step,
)

H = 0.0025  # plant step [s]
LIMIT = 1.0  # wide limits [rad]: off unless a test narrows them


def params(
    delay: float | list[float] = 0.0,
    rate: float | list[float] = math.inf,
    tau: float | list[float] = 0.0,
    lo: float | list[float] = -LIMIT,
    hi: float | list[float] = LIMIT,
    quantum: float | list[float] = 0.0,
    deadband: float | list[float] = 0.0,
    h: float = H,
) -> FloatArray:
    """Every element off unless given; a scalar applies to every channel."""

    def each(v: float | list[float]) -> list[float]:
        return v if isinstance(v, list) else [v] * N_PITCH

    return servo_parameters(
        each(delay), each(rate), each(tau), each(lo), each(hi), each(quantum), each(deadband), h
    )


def run(p: FloatArray, commands: FloatArray, initial: FloatArray | None = None) -> FloatArray:
    """Step the chain through ``commands`` (n x N_PITCH); the outputs, one row per step."""
    x0 = commands[0] if initial is None else initial
    s = servo_state(p, np.array(x0, dtype=float))
    out = np.empty_like(commands)
    for n in range(commands.shape[0]):
        servo_step(p, s, commands[n], out[n])
    return out


def step_commands(n: int, size: float) -> FloatArray:
    """A step of ``size`` on every channel at step 0, from 0."""
    return np.full((n, N_PITCH), size)


def test_all_off_is_bit_identical() -> None:
    rng = np.random.default_rng(1)
    cmd = rng.uniform(-0.5, 0.5, (2000, N_PITCH))
    cmd[100:200] = cmd[99]  # held stretches too
    out = run(params(), cmd, initial=np.zeros(N_PITCH))
    assert_array_equal(out, cmd)
    assert np.array_equal(out.view(np.int64), cmd.view(np.int64))  # bit for bit, signs of zero included


def test_at_rest_no_start_up_transient() -> None:
    """Everything but quantisation on (a quantum moves an off-grid start by design): a command
    that stays where the servos start leaves them there exactly."""
    p = params(delay=[0.0, 0.01, 0.005, 0.0175], rate=1.33, tau=0.02, deadband=1e-4, lo=-0.3, hi=0.3)
    x0 = np.array([0.1, -0.05, 0.02, -0.2])
    out = run(p, np.tile(x0, (500, 1)))
    assert_array_equal(out, np.tile(x0, (500, 1)))


def test_state_layout() -> None:
    p = params(delay=[0.0, 0.01, 0.0025, 0.0])
    assert p.shape == (N_PITCH, N_SERVO_PARAM)
    assert_array_equal(p[:, SP_DELAY_STEPS], [0, 4, 1, 0])
    assert fifo_slots(p) == 4
    x0 = np.array([0.1, 0.2, 0.3, 0.4])
    s = servo_state(p, x0)
    assert s.shape == (SS_FIFO + 4 * N_PITCH,)
    assert s[SS_RING_INDEX] == 0.0
    assert_array_equal(s[SS_POSITION : SS_POSITION + N_PITCH], x0)
    assert_array_equal(s[SS_TARGET : SS_TARGET + N_PITCH], x0)
    assert_array_equal(s[SS_FIFO:].reshape(4, N_PITCH), np.tile(x0, (4, 1)))
    assert servo_state(params(), x0).shape == (SS_FIFO,)  # no delay, no FIFO


def test_delay_holds_exactly_delay_steps() -> None:
    """Per-channel delays share one ring: each output is the command ``delay_steps`` ago."""
    delays = [0, 1, 4, 7]
    p = params(delay=[d * H for d in delays])
    assert_array_equal(p[:, SP_DELAY_STEPS], delays)
    out = run(p, step_commands(20, 0.3), initial=np.zeros(N_PITCH))
    for ch, d in enumerate(delays):
        assert_array_equal(out[:d, ch], 0.0)  # not before step index d
        assert_array_equal(out[d:, ch], 0.3)  # exactly the command from step index d on
    # an arbitrary sequence: a pure shift
    rng = np.random.default_rng(2)
    cmd = rng.uniform(-0.5, 0.5, (300, N_PITCH))
    out = run(p, cmd, initial=np.zeros(N_PITCH))
    for ch, d in enumerate(delays):
        assert_array_equal(out[d:, ch], cmd[: cmd.shape[0] - d, ch])
        assert_array_equal(out[:d, ch], 0.0)


def test_big_step_slope_is_the_rate_limit() -> None:
    rates = [
        rate_limit_from_speed(0.14, 0.255),
        rate_limit_from_speed(0.12, 0.446),
        rate_limit_from_speed(0.14, 0.178),
        rate_limit_from_speed(0.14, 0.178),
    ]
    p = params(rate=rates)
    assert_allclose(p[:, SP_RATE_STEP], np.array(rates) * H, rtol=1e-15)
    size = np.array([0.3, -0.5, 0.2, -0.2])
    cmd = np.tile(size, (600, 1))
    out = run(p, cmd, initial=np.zeros(N_PITCH))
    for ch in range(N_PITCH):
        n_ramp = int(abs(size[ch]) / (rates[ch] * H))  # whole steps at full rate
        y = np.concatenate([[0.0], out[:, ch]])
        assert_allclose(np.diff(y[: n_ramp + 1]), math.copysign(rates[ch] * H, size[ch]), rtol=0, atol=1e-12)
        assert_array_equal(out[n_ramp:, ch], size[ch])  # the last, shorter move lands on the command
        assert 0.0 < abs(y[n_ramp + 1] - y[n_ramp]) <= rates[ch] * H


def test_big_step_with_lag_slope_tends_to_the_rate_limit() -> None:
    rate, tau = 1.33, 0.02
    out = run(params(rate=rate, tau=tau), step_commands(200, 0.3), initial=np.zeros(N_PITCH))[:, 0]
    slope = np.diff(out) / H
    assert np.all(slope <= rate * (1 + 1e-12))
    n = 80  # 0.2 s = 10 tau into a 0.226 s ramp: the lag's transient, exp(-t/tau) < 2e-4, has gone
    assert_allclose(slope[n - 10 : n], rate, rtol=2e-4)
    assert np.all(slope >= 0.0)
    assert out[-1] == pytest.approx(0.3, abs=1e-6)  # 13 tau past the ramp: settled on the command


def test_lag_alone_is_the_first_order_curve() -> None:
    tau = 0.02
    p = params(tau=tau)
    assert p[0, SP_ALPHA] == pytest.approx(1.0 - math.exp(-H / tau), rel=1e-15)
    out = run(p, step_commands(80, 0.01), initial=np.zeros(N_PITCH))
    t = (np.arange(80) + 1) * H  # step n ends at (n + 1) h
    for ch in range(N_PITCH):
        assert_allclose(out[:, ch], 0.01 * (1.0 - np.exp(-t / tau)), rtol=1e-12)
    n_tau = round(tau / H) - 1
    assert out[n_tau, 0] / 0.01 == pytest.approx(1.0 - math.exp(-1.0), rel=1e-12)  # 63.2 % at tau


def test_delay_plus_lag_reaches_63_percent_at_delay_plus_tau() -> None:
    tau, t_d = 0.02, 0.01
    d = round(t_d / H)
    out = run(params(delay=t_d, tau=tau), step_commands(80, 0.01), initial=np.zeros(N_PITCH))[:, THETA_M]
    assert_array_equal(out[:d], 0.0)
    t = (np.arange(80) + 1) * H
    assert_allclose(out[d:], 0.01 * (1.0 - np.exp(-(t[d:] - t_d) / tau)), rtol=1e-12)
    n = round((t_d + tau) / H) - 1  # the step that ends at T_d + tau
    assert out[n] / 0.01 == pytest.approx(0.632, abs=5e-4)


def _phase_lag(y: FloatArray, t_s: npt.ArrayLike, w: float) -> float:
    """Phase lag [rad] of ``y`` behind sin(w t), from a least-squares fit of a sinusoid."""
    t = np.asarray(t_s, dtype=float)
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return float(-math.atan2(b, a))


@pytest.mark.parametrize("w", [12.0, 18.6])
def test_phase_lag_of_a_small_sinusoid(w: float) -> None:
    """tau = 0.02 s, T_d = 0.01 s (4 steps), h = 2.5 ms, the cyclic rate limit on but not
    reached. Fit over whole periods after 1 s (50 tau) of transient.

    The continuous lag atan(w tau) + w T_d is that of the positions at the step ends (where the
    exact discretisation is exact) behind the held command (a zero-order hold, whose
    fundamental is centred mid-step). What a plant that holds each output over the next step
    sees is half a step less, w h / 2 (1.3 deg at 18.6 rad/s): the exact discrete transfer."""
    tau, t_d, amp = 0.02, 0.01, 0.01
    p = params(delay=t_d, tau=tau, rate=rate_limit_from_speed(0.14, 0.178))
    n_warm = round(1.0 / H)
    n_fit = round(3 * (2 * math.pi / w) / H)  # three whole periods (to within a step)
    n = np.arange(n_warm + n_fit)
    cmd = np.tile(amp * np.sin(w * n * H)[:, None], (1, N_PITCH))
    out = run(p, cmd, initial=np.zeros(N_PITCH))
    assert np.max(np.abs(np.diff(out[:, 0]))) < p[0, SP_RATE_STEP]  # the rate limit does not bite
    k = n[n_warm:]
    analytic = math.atan(w * tau) + w * t_d
    for ch in (THETA_M, THETA_T, EPS, ETA):
        y = out[n_warm:, ch]
        lag_held = _phase_lag(y, (k + 1) * H, w) - _phase_lag(cmd[n_warm:, ch], (k + 0.5) * H, w)
        assert math.degrees(abs(lag_held - analytic)) < 1.0
        assert math.degrees(abs(lag_held - analytic)) < 0.05  # in fact much closer
        # sample against sample: the exact discrete transfer z^-d a / (1 - (1 - a) z^-1)
        lag_samples = _phase_lag(y, k * H, w) - _phase_lag(cmd[n_warm:, ch], k * H, w)
        a, z = p[ch, SP_ALPHA], np.exp(1j * w * H)
        discrete = -np.angle(z ** -round(t_d / H) * a / (1 - (1 - a) / z))
        assert_allclose(lag_samples, discrete, rtol=0, atol=1e-9)
        assert math.degrees(abs(lag_samples - (analytic - w * H / 2))) < 0.05


def test_quantisation_rounds_to_the_nearest_multiple() -> None:
    q = 0.004
    cmd = np.tile(np.linspace(-0.1, 0.1, 401)[:, None] + 1e-5, (1, N_PITCH))  # no exact halves
    out = run(params(quantum=q), cmd, initial=np.zeros(N_PITCH))
    assert_allclose(out, q * np.round(cmd / q), rtol=0, atol=1e-15)
    assert np.all(np.abs(out - cmd) <= q / 2 + 1e-15)
    assert len(np.unique(np.round(out[:, 0] / q))) == 51


def test_dead_band() -> None:
    d = 0.002
    p = params(deadband=d)
    seq = [0.0015, -0.0019, 0.0021, 0.0035, 0.0005, -0.0001]
    # the target moves only when the command leaves +-d around it, then goes to the command
    want = [0.0, 0.0, 0.0021, 0.0021, 0.0021, -0.0001]
    out = run(p, np.tile(np.array(seq)[:, None], (1, N_PITCH)), initial=np.zeros(N_PITCH))
    assert_array_equal(out[:, 0], want)
    # with a rate limit, a move stops once within the band of the command
    rate = 1.0
    out = run(params(deadband=d, rate=rate), step_commands(40, 0.0201), initial=np.zeros(N_PITCH))[:, 0]
    assert_allclose(out[:8], (np.arange(8) + 1) * rate * H, rtol=1e-12)  # 0.0025 ... 0.02
    assert_allclose(out[8:], 0.02, rtol=1e-12)  # 0.0001 short of the command: inside the band


def test_quantum_and_dead_band_of_one_pwm_microsecond() -> None:
    """Command noise below the quantum, or inside the band, leaves the servo still; a move
    beyond both lands on the quantised command."""
    us = 0.178 * math.radians(90) / 1000  # 1 us of a 1000 us, 90-deg servo throw through k = 0.178
    x0 = np.full(N_PITCH, us * 179)
    rng = np.random.default_rng(3)
    for noise_us, q, d in [(0.45, us, 0.0), (0.95, 0.0, us)]:
        cmd = np.tile((x0[0] + rng.uniform(-noise_us, noise_us, 300) * us)[:, None], (1, N_PITCH))
        assert_array_equal(run(params(quantum=q, deadband=d), cmd, initial=x0), np.tile(x0, (300, 1)))
    cmd = np.full((3, N_PITCH), x0[0] + 2.3 * us)
    out = run(params(quantum=us, deadband=us), cmd, initial=x0)
    assert_allclose(out, us * 181, rtol=1e-14)


def test_limits_clip_without_wind_up() -> None:
    lo, hi = -0.1, 0.15
    p = params(lo=lo, hi=hi, rate=2.0)
    cmd = np.concatenate([np.full(100, 0.5), np.full(200, -0.5)])
    out = run(p, np.tile(cmd[:, None], (1, N_PITCH)), initial=np.zeros(N_PITCH))[:, 0]
    assert np.all((out >= lo) & (out <= hi))
    assert_array_equal(out[80:100], hi)
    assert out[100] == pytest.approx(hi - 2.0 * H, abs=1e-12)  # leaves the stop at once
    assert_array_equal(out[-20:], lo)
    # all else off: the output is the command clipped
    rng = np.random.default_rng(4)
    c = rng.uniform(-0.5, 0.5, (200, N_PITCH))
    assert_array_equal(run(params(lo=lo, hi=hi), c, initial=np.zeros(N_PITCH)), np.clip(c, lo, hi))


def test_nan_command_is_outside_the_contract_but_holds() -> None:
    """servo_step assumes finite commands (the plant refuses others before holding them); a
    NaN happens to fail the dead-band test, so the servo holds."""
    p = params(tau=0.02)
    s = servo_state(p, np.full(N_PITCH, 0.1))
    out = np.empty(N_PITCH)
    servo_step(p, s, np.full(N_PITCH, np.nan), out)
    assert_array_equal(out, 0.1)


def test_rate_limit_from_speed() -> None:
    assert rate_limit_from_speed(0.14, 0.178) == pytest.approx(1.33, abs=0.005)
    assert rate_limit_from_speed(0.14, 0.255) == pytest.approx(1.91, abs=0.005)
    assert rate_limit_from_speed(0.12, 0.446) == pytest.approx(3.89, abs=0.005)
    assert rate_limit_from_speed(0.0, 0.178) == math.inf
    for t60, k in [(-0.1, 0.178), (math.nan, 0.178), (0.14, 0.0), (0.14, math.inf)]:
        with pytest.raises(ValueError):
            rate_limit_from_speed(t60, k)


GOOD = {
    "delay_s": 0.01,
    "rate_rad_s": 1.33,
    "tau_s": 0.02,
    "lo_rad": -0.2,
    "hi_rad": 0.2,
    "quantum_rad": 0.0,
    "deadband_rad": 0.0,
}


@pytest.mark.parametrize(
    ("item", "bad"),
    [
        ("delay_s", -0.01),
        ("delay_s", math.inf),
        ("delay_s", math.nan),
        ("rate_rad_s", 0.0),
        ("rate_rad_s", -1.0),
        ("rate_rad_s", math.nan),
        ("tau_s", -0.02),
        ("tau_s", math.inf),
        ("lo_rad", -math.inf),
        ("hi_rad", math.nan),
        ("lo_rad", 0.2),
        ("hi_rad", -0.3),
        ("quantum_rad", -1e-4),
        ("deadband_rad", -1e-4),
        ("deadband_rad", math.inf),
    ],
)
@pytest.mark.parametrize(("channel", "name"), [(THETA_T, "theta_t"), (ETA, "eta")])
def test_validation_names_channel_and_item(item: str, bad: float, channel: int, name: str) -> None:
    args = {k: [v] * N_PITCH for k, v in GOOD.items()}
    args[item][channel] = bad
    with pytest.raises(ValueError, match=rf"servo {name}: (lo_rad|{item})"):
        servo_parameters(**args, step_s=H)


def test_validation_of_shapes_step_and_start() -> None:
    args = {k: [v] * N_PITCH for k, v in GOOD.items()}
    for h in (0.0, -H, math.inf, math.nan):
        with pytest.raises(ValueError, match="step_s"):
            servo_parameters(**args, step_s=h)
    args["tau_s"] = [0.02] * 3
    with pytest.raises(ValueError, match="tau_s"):
        servo_parameters(**args, step_s=H)
    p = params(lo=-0.2, hi=0.2)
    with pytest.raises(ValueError, match="servo eps: initial_rad"):
        servo_state(p, np.array([0.0, 0.0, 0.25, 0.0]))
    with pytest.raises(ValueError, match="servo theta_m: initial_rad"):
        servo_state(p, np.array([np.nan, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        servo_state(p, np.zeros(3))
    with pytest.raises(ValueError, match="shape"):
        servo_state(p[:, :3], np.zeros(N_PITCH))
