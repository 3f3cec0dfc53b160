"""Linear margins of the TLC loops with servos (autopilot/analysis/margins.py), the
servo-aware gain set they chose (configs/gains_servo_aware.toml), and flights that check it.

(a) loop 4 alone reproduces the team's linear numbers, cross-checked by a numpy sweep;
(b) the servo-aware gains keep 45 deg of phase margin on every loop with sloppy servos;
(c) in-process flights of the paper scenario: the servo-aware gains fly `sloppy-servos`,
    the Table 2 gains still fly the calm world exactly as before.

Run as a script (``.venv/bin/python tests/test_margins.py``) it prints the margins table and
the flights over every world preset (docs/servo-aware-gains.md).
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from autopilot.analysis.margins import (
    DEFAULT_SERVOS,
    IDEAL_SERVOS,
    LOOP_CHANNELS,
    SERVO_MODELS,
    SLOPPY_SERVOS,
    ServoModel,
    format_table,
    loop4_discrete_margins,
    loop_margins,
    open_loop,
    servo_aware_gains,
)
from autopilot.scenario import Scenario
from autopilot.tlc.gains import Gains
from heli_common.world.config import World
from heli_sitl.engine.closed_loop import SimOptions, simulate

PRESETS = ("calm", "breezy", "gusty", "servos-default", "sloppy-servos", "heavy-10pct", "everything")
GAIN_FILES = ("gains_paper.toml", "gains_servo_aware.toml")


@pytest.fixture(scope="module")
def paper_gains() -> Gains:
    return Gains.load("gains_paper.toml")


@pytest.fixture(scope="module")
def servo_aware() -> Gains:
    return Gains.load("gains_servo_aware.toml")


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


# --- (a) loop 4 alone, the team's numbers


def numpy_loop4(zeta: float, w: float, servo: ServoModel) -> tuple[float, float]:
    """Crossover [rad/s] and phase margin [deg] of ``L(s) = exp(-s T)/(1 + tau s) (2 zeta w s
    + w^2)/s^2``, ``T = delay + dt/2``, by brute force: a dense sweep, the first |L| = 1 by
    linear interpolation of log|L| in log w, the phase unwrapped from low frequency."""
    om = np.logspace(-1.0, 3.0, 400_001)
    s = 1j * om
    t = servo.delay_s + 0.5 / servo.rate_hz
    lv = np.exp(-s * t) / (1.0 + servo.tau_s * s) * (2.0 * zeta * w * s + w * w) / s**2
    mag = np.log(np.abs(lv))
    i = int(np.flatnonzero((mag[:-1] > 0.0) & (mag[1:] <= 0.0))[0])
    f = mag[i] / (mag[i] - mag[i + 1])
    wc = float(np.exp(np.log(om[i]) + f * (np.log(om[i + 1]) - np.log(om[i]))))
    phase = np.unwrap(np.angle(lv))
    ph = float(phase[i] + f * (phase[i + 1] - phase[i]))
    return wc, math.degrees(ph) + 180.0


@pytest.mark.parametrize(
    ("servo", "crossover", "pm"),
    [(IDEAL_SERVOS, 18.6, 60.0), (DEFAULT_SERVOS, None, 30.0), (SLOPPY_SERVOS, None, 12.0)],
    ids=["ideal", "default", "sloppy"],
)
@pytest.mark.parametrize("method", ["exact", "pade"])
def test_loop4_alone_gives_the_teams_numbers(
    paper_gains: Gains, servo: ServoModel, crossover: float | None, pm: float, method: Any
) -> None:
    """Table 2's loop 4 (12 rad/s, 0.707) through the servo and the 100 Hz hold: crossover
    18.6 rad/s and 60 deg with ideal servos, 30 deg with default, 12 deg with sloppy ones;
    every channel alike; the same to 0.05 deg as an independent numpy sweep."""
    r = loop_margins(paper_gains, servo, method=method)
    m = r.get(4, "roll")
    assert m.phase_margin_deg == pytest.approx(pm, abs=2.5)
    if crossover is not None:
        assert m.crossover_rad_s == pytest.approx(crossover, abs=0.1)
    assert m.crossovers == 1 and m.stable
    for ch in LOOP_CHANNELS[4]:
        assert r.get(4, ch) == dataclasses.replace(m, channel=ch)
    wc, pm_np = numpy_loop4(0.707, 12.0, servo)
    assert m.crossover_rad_s == pytest.approx(wc, rel=1e-3)
    assert m.phase_margin_deg == pytest.approx(pm_np, abs=0.05)
    assert m.delay_margin_s == pytest.approx(math.radians(pm_np) / wc, rel=2e-3)


def test_loop4_without_the_hold_is_the_design_loop(paper_gains: Gains) -> None:
    """No servo, no hold (a very fast control rate): the continuous design loop, 65.5 deg at
    18.6 rad/s, 61 ms of delay margin, of which the 100 Hz hold takes 5 ms."""
    m = loop_margins(paper_gains, ServoModel(0.0, 0.0, rate_hz=1e7)).get(4, "pitch")
    assert m.crossover_rad_s == pytest.approx(18.64, abs=0.01)
    assert m.phase_margin_deg == pytest.approx(65.5, abs=0.1)
    assert m.delay_margin_s == pytest.approx(0.0613, abs=0.0005)
    held = loop_margins(paper_gains, IDEAL_SERVOS).get(4, "pitch")
    assert m.delay_margin_s - held.delay_margin_s == pytest.approx(0.005, abs=1e-4)


def test_the_simulators_discrete_loop4_has_about_4_deg_more_with_servos(paper_gains: Gains) -> None:
    """The exact discrete-time loop 4 of the simulator: with the hold alone it loses 1.4 deg
    more (the forward-Euler integral); with servos it has about 4 deg more than the
    continuous model, because the servo's end-of-step output leads a continuous lag by half a
    step. The continuous model (the team's) is the pessimistic one."""
    for servo, extra in ((IDEAL_SERVOS, -1.4), (DEFAULT_SERVOS, 3.8), (SLOPPY_SERVOS, 4.1)):
        cont = loop_margins(paper_gains, servo, method="pade").get(4, "roll")
        disc = loop4_discrete_margins(paper_gains, servo)
        assert disc.stable
        assert disc.phase_margin_deg - cont.phase_margin_deg == pytest.approx(extra, abs=0.3)


def test_table2_with_sloppy_servos_loses_loop3_at_loop4s_resonance(paper_gains: Gains) -> None:
    """With sloppy servos loop 4 keeps 12 deg, and its resonant closed loop lifts loop 3's
    open loop above 1 again near 17 rad/s where the phase is past -180: three crossovers, a
    negative phase margin, an unstable closure (continuous model). Half a step less delay
    (the simulator's servo timing) leaves it stable by 0.9 dB."""
    r = loop_margins(paper_gains, SLOPPY_SERVOS)
    m3 = r.get(3, "roll")
    assert not m3.stable and m3.crossovers == 3 and m3.phase_margin_deg < 0.0
    assert not r.all_stable
    assert loop_margins(paper_gains, DEFAULT_SERVOS).all_stable
    sim_timing = ServoModel(SLOPPY_SERVOS.delay_s - 0.005, SLOPPY_SERVOS.tau_s)
    m3s = loop_margins(paper_gains, sim_timing, method="pade").get(3, "roll")
    assert m3s.stable and 0.0 < m3s.gain_margin_db < 1.5


# --- (b) the servo-aware gains


@pytest.mark.parametrize("method", ["exact", "pade"])
def test_servo_aware_gains_keep_45_deg_on_every_loop_with_sloppy_servos(
    servo_aware: Gains, method: Any
) -> None:
    r = loop_margins(servo_aware, SLOPPY_SERVOS, method=method)
    assert r.all_stable
    for m in r.loops:
        assert m.phase_margin_deg >= 45.0, m
        assert m.crossovers == 1, m
        assert m.gain_margin_db >= 10.0, m
    assert r.min_phase_margin_deg == pytest.approx(46.3, abs=0.1)  # loop 4, as designed
    # and more with better servos
    for servo in (DEFAULT_SERVOS, IDEAL_SERVOS):
        assert loop_margins(servo_aware, servo, method=method).min_phase_margin_deg >= 56.0


def test_servo_aware_gains_keep_the_time_scale_separation(servo_aware: Gains) -> None:
    """Every outer loop at least 3x slower than the loop inside it: in omega, in crossover
    (with every servo model) and in the decay rate of the error dynamics."""
    w = [lg.omega_rad_s for lg in servo_aware.loops()]
    z = [lg.zeta for lg in servo_aware.loops()]
    for ch in (0, 1):  # x/roll, y/pitch: loop 1-2 x/y sit inside loops 3-4 roll/pitch
        for k in (0, 1, 2):
            assert w[k + 1][ch] / w[k][ch] >= 2.99
            decay_in = w[k + 1][ch] * min(z[k + 1][ch], 1.0)
            assert decay_in / (w[k][ch] * z[k][ch]) >= 2.99
    for servo in SERVO_MODELS.values():
        r = loop_margins(servo_aware, servo, method="pade")
        xo = [r.get(k, "x" if k <= 2 else "roll").crossover_rad_s for k in (1, 2, 3, 4)]
        assert all(xo[k + 1] / xo[k] >= 3.0 for k in range(3)), (servo, xo)


def test_the_shipped_servo_aware_gains_are_what_the_analysis_chooses(
    paper_gains: Gains, servo_aware: Gains
) -> None:
    g, steps = servo_aware_gains(paper_gains, SLOPPY_SERVOS, pm_min_deg=46.0, separation=3.0)
    # the design point (where the whole loop's margins are proven) is the file's claim, not the analysis'
    assert dataclasses.replace(g, design=servo_aware.design) == servo_aware
    assert [(s.loop, s.zeta, s.omega_rad_s) for s in steps] == [
        (4, 1.0, 4.8), (3, 0.707, 1.55), (2, 0.707, 0.515), (1, 0.707, 0.17),
    ]  # fmt: skip
    # z of loops 1-2 (no attitude loop inside), the differentiator and the limits: Table 2's
    for ours, table2 in zip(servo_aware.loops()[:2], paper_gains.loops()[:2], strict=True):
        assert ours.omega_rad_s[2] == table2.omega_rad_s[2] and ours.zeta == table2.zeta
    assert servo_aware.differentiator == paper_gains.differentiator
    assert servo_aware.limits == paper_gains.limits


def test_open_loop_is_the_loop_the_margins_come_from(servo_aware: Gains) -> None:
    m = loop_margins(servo_aware, SLOPPY_SERVOS).get(3, "pitch")
    for method in ("exact", "pade"):
        sys = open_loop(servo_aware, SLOPPY_SERVOS, 3, "pitch", method=method)
        resp = complex(sys(1j * m.crossover_rad_s))
        assert abs(resp) == pytest.approx(1.0, abs=1e-3)
        assert math.degrees(np.angle(resp)) + 180.0 == pytest.approx(m.phase_margin_deg, abs=0.1)


def test_the_margins_table_prints() -> None:
    text = format_table([loop_margins(Gains.load(), SLOPPY_SERVOS, method="pade")])
    assert "| paper Table 2 | 20 ms + 30 ms | 4 | roll/pitch/yaw | 16.92 | 12.2 |" in text
    assert "**no**" in text


# --- (c) flights


def circle_residual_m(gains: Gains, radius_m: float = 10.0, period_s: float = 80.0) -> float:
    """The steady position error on the paper's circle predicted by the loops alone (x/y): the
    pseudo-differentiator gives loop 1 the feed-forward velocity ``D(jW) V``, short by
    ``|1 - D(jW)| W r``, and loop 1 (inner loops ideal at this frequency) leaves
    ``|1 - D| W r / |jW + K1(jW)|`` of position error."""
    wo = 2.0 * math.pi / period_s
    s = 1j * wo
    d = gains.differentiator
    dd = d.omega_rad_s**2 / (s * s + 2.0 * d.zeta * d.omega_rad_s * s + d.omega_rad_s**2)
    lg = gains.loop1_position_kinematics
    k1 = (2.0 * lg.zeta[0] * lg.omega_rad_s[0] * s + lg.omega_rad_s[0] ** 2) / s
    return float(abs(1.0 - dd) * wo * radius_m / abs(s + k1))


def flight(scenario: Scenario, gains: Gains, preset: str) -> dict[str, Any]:
    """One paper-scenario flight in a world preset: the figures of the docs' table."""
    world = World.load(preset)
    rec = simulate(dataclasses.replace(scenario, gains=gains), SimOptions(world=world))
    s = rec.summary()
    rates = np.abs(np.diff(rec.pitches, axis=0)) * float(s["rate_hz"])
    limit = np.array([r if r > 0.0 else np.inf for r in world.servos.rate_rad_s])
    tilt = max(s["max_abs_phi_rad"], s["max_abs_theta_rad"])
    rms = s["rms_pos_err_m"]["45-120"]
    return {
        "rms_45_120_m": rms,
        "max_after_10_m": s["max_pos_err_m"]["10-120"],
        "max_phi_rad": s["max_abs_phi_rad"],
        "max_theta_rad": s["max_abs_theta_rad"],
        "saturated_ticks": s["saturated_ticks"],
        # commands that ask a servo to move faster than its rate limit (none without limits)
        "rate_limited_ticks": int(np.count_nonzero(np.any(rates > limit, axis=1))),
        "max_cyclic_rate_rad_s": float(rates[:, 2:4].max()),
        "outcome": "tumbles" if tilt > math.pi / 2 and rms > 1.0 else "rolls over" if tilt > 1.0 else "flies",
    }


def test_servo_aware_gains_fly_sloppy_servos(paper: Scenario, servo_aware: Gains) -> None:
    """Bound: the circle's steady error is the pseudo-differentiator's lag left over by loop 1,
    0.046 m for these gains (0.038 m for Table 2, which flies 0.040 m); the servos' dead band
    and lag add to it. 0.1 m is twice the prediction and five times below the 0.5 m at
    which the issue would call the path lost."""
    assert circle_residual_m(servo_aware) == pytest.approx(0.046, abs=0.001)
    f = flight(paper, servo_aware, "sloppy-servos")
    assert f["rms_45_120_m"] < 0.1, f
    assert f["max_after_10_m"] < 1.5, f
    assert max(f["max_phi_rad"], f["max_theta_rad"]) < 0.35, f
    assert f["saturated_ticks"] == 0, f
    assert f["rate_limited_ticks"] < 20, f


def test_table2_gains_with_servos_do_what_the_issue_says(paper: Scenario, paper_gains: Gains) -> None:
    """Default servos: the start transient rolls the vehicle over (rate limits) and it
    recovers; sloppy servos: it tumbles. The calm world is untouched: the paper's figure."""
    assert Scenario.load("paper").gains == paper_gains  # the scenario's gains stay Table 2
    assert circle_residual_m(paper_gains) == pytest.approx(0.038, abs=0.001)
    calm = flight(paper, paper_gains, "calm")
    assert calm["rms_45_120_m"] == pytest.approx(0.0402, abs=5e-5)
    assert calm["saturated_ticks"] == 15
    default = flight(paper, paper_gains, "servos-default")
    assert default["max_phi_rad"] > 1.5 and default["rms_45_120_m"] < 0.06
    sloppy = flight(paper, paper_gains, "sloppy-servos")
    assert sloppy["outcome"] == "tumbles"


def test_without_rate_limits_table2_survives_sloppy_servos(paper: Scenario, paper_gains: Gains) -> None:
    """The tumble needs the rate limit: the same servos without it fly (the linear loops are
    marginal, not unstable, at the simulator's servo timing), with many saturated ticks."""
    world = World.load("sloppy-servos")
    unlimited = dataclasses.replace(world, servos=dataclasses.replace(world.servos, rate_rad_s=(0.0,) * 4))
    rec = simulate(paper, SimOptions(world=unlimited))
    s = rec.summary()
    assert s["rms_pos_err_m"]["45-120"] < 0.1
    assert s["saturated_ticks"] > 100


# --- the tables of docs/servo-aware-gains.md


def margins_markdown() -> str:
    reports = [loop_margins(Gains.load(f), sv) for f in GAIN_FILES for sv in SERVO_MODELS.values()]
    return format_table(reports)


def flights_markdown() -> str:
    scenario = Scenario.load("paper")
    lines = [
        "| world | gains | RMS [45, 120] s [m] | max error after 10 s [m] | max abs phi [rad] | "
        "max abs theta [rad] | saturated ticks | rate-limited ticks | max cyclic rate [rad/s] | outcome |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for preset in PRESETS:
        for f in GAIN_FILES:
            g = Gains.load(f)
            r = flight(scenario, g, preset)
            lines.append(
                f"| {preset} | {g.name} | {r['rms_45_120_m']:.4f} | {r['max_after_10_m']:.3f} | "
                f"{r['max_phi_rad']:.3f} | {r['max_theta_rad']:.3f} | {r['saturated_ticks']} | "
                f"{r['rate_limited_ticks']} | {r['max_cyclic_rate_rad_s']:.2f} | {r['outcome']} |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    print(margins_markdown())
    print()
    print(flights_markdown())


@pytest.mark.parametrize("servo", ["ideal", "default", "sloppy"])
def test_the_pid_rate_loop_at_table2_is_the_tlc_s_loop4(servo: str, paper_gains: Gains) -> None:
    """The PID's Table 2 start puts a PI with the TLC's loop-4 omega and zeta on the same
    1/s behind the same servo: two independent derivations must give the same margins."""
    from autopilot.analysis.margins import SERVO_MODELS
    from autopilot.analysis.pid_margins import pid_loop_margins
    from autopilot.pid.gains import PidGains

    pid = pid_loop_margins(PidGains.load("starts/pid_table2.toml"), SERVO_MODELS[servo])
    tlc = loop_margins(paper_gains, SERVO_MODELS[servo], feedforward=False)
    for ch in ("roll", "pitch", "yaw"):
        p, t = pid.get(4, ch), tlc.get(4, ch)
        # kp = 17, ki = 144 against 2 zeta omega = 16.97, omega^2 = 144: 0.2 % apart
        assert p.crossover_rad_s == pytest.approx(t.crossover_rad_s, rel=3e-3)
        assert p.phase_margin_deg == pytest.approx(t.phase_margin_deg, abs=0.2)
        assert p.stable == t.stable


def test_the_pid_rate_derivative_adds_phase() -> None:
    from autopilot.analysis.margins import DEFAULT_SERVOS
    from autopilot.analysis.pid_margins import pid_loop_margins
    from autopilot.pid.gains import PidGains

    g = PidGains.load("starts/pid_table2.toml")
    with_d = dataclasses.replace(g, rate=dataclasses.replace(g.rate, kd=(0.3, 0.3, 0.3)))
    a = pid_loop_margins(g, DEFAULT_SERVOS).get(4, "roll")
    b = pid_loop_margins(with_d, DEFAULT_SERVOS).get(4, "roll")
    print(f"rate loop, 10 + 20 ms servos: PM {a.phase_margin_deg:.1f} deg, kd 0.3: {b.phase_margin_deg:.1f}")
    assert b.phase_margin_deg > a.phase_margin_deg + 5.0 and b.crossover_rad_s < a.crossover_rad_s


def test_heli_sitl_margins_loops_prints_the_loop_at_a_time_table(capsys: pytest.CaptureFixture[str]) -> None:
    """``heli-sitl margins --controller pid --loops``: the tuned PID's loops 1-4 behind each
    servo model, as pid_loop_margins computes them; the TLC's by loop_margins."""
    from autopilot.analysis.margins import SERVO_MODELS, format_table
    from autopilot.analysis.pid_margins import pid_loop_margins
    from autopilot.pid.gains import PidGains
    from heli_sitl.cli import main

    assert main(["margins", "--controller", "pid", "--loops"]) == 0
    out = capsys.readouterr().out
    pid = PidGains.load("gains_pid.toml")
    assert out.strip() == format_table([pid_loop_margins(pid, sv) for sv in SERVO_MODELS.values()]).strip()
    # the rate loop behind the default servos (10 ms + 20 ms): 45.5 deg, 43 ms of delay margin
    assert "| 10 ms + 20 ms | 4 | roll/pitch | 18.57 | 45.5 | 12.2 | 43 | yes |" in out
    assert main(["margins", "--loops"]) == 0
    assert "| paper Table 2 | 10 ms + 20 ms | 4 |" in capsys.readouterr().out
    assert main(["margins", "--loops", "--plant", "paper"]) == 2  # a linear plant of its own
    assert "--loops" in capsys.readouterr().err


def test_the_module_answers_help_and_refuses_a_missing_gain_file_by_name() -> None:
    cmd = [sys.executable, "-m", "autopilot.analysis.margins"]
    helped = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=120)
    assert helped.returncode == 0 and "servo models" in helped.stdout
    bad = subprocess.run([*cmd, "no_such_gains.toml"], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "no_such_gains.toml" in bad.stderr and "Traceback" not in bad.stderr
