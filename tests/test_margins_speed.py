"""Margins over the envelope (issue 44, item 4): the closed loop linearised in trimmed level
flight, one control tick of computation delay in it, disk margins loop at a time and all
inputs / all states at once (heli_sitl/engine/loop_linear.py, autopilot/analysis/envelope_margins.py).

(a) the margin code against python-control and against closed forms: a loop ``k z^-n`` whose
    balanced disk margin is ``2 (1 - k) / (1 + k)``, through the same delay and margin code;
    the structured bound on matrices whose ``mu`` is known; the worst input of the real loop at
    10 m/s against python-control's ``disk_margins`` on the loop python-control assembles;
(b) every shipped gain set (the TLC's and the PID's) at 0 and 10 m/s is not below the figures
    its gain file states.
"""

from __future__ import annotations

import math
from typing import Any

import control as ct
import numpy as np
import pytest

from autopilot.analysis.envelope_margins import (
    EnvelopeRow,
    mu_upper_bound,
    simultaneous_disk,
    siso_disk,
)
from autopilot.controllers import build_kernel_controller
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from heli_common.state import PITCH_NAMES
from heli_common.vehicle.plant_model import PlantModel
from heli_sitl.engine.loop_linear import (
    OMEGA_RAD_S,
    Discrete,
    LoopBlocks,
    closed_loop_eigenvalues,
    delayed,
    envelope_row,
    loop_at_a_time,
    loop_blocks_at,
    servo_model,
)

DT = 0.01
OMEGA = np.linspace(0.01, math.pi / DT, 2001)  # to the Nyquist frequency, inclusive

# the figures each gain file's header states (heli-sitl margins --envelope --gains FILE, its
# design plant and servos, one tick of computation delay): speed -> (worst input loop at a
# time, worst state loop at a time, all four inputs at once, all twelve states at once)
STATED: dict[str, dict[float, tuple[float, float, float, float]]] = {
    "gains_paper.toml": {0.0: (0.56, 0.59, 0.55, 0.31), 10.0: (0.56, 0.59, 0.55, 0.31)},
    "gains_tlc_rotor.toml": {0.0: (0.59, 0.61, 0.59, 0.40), 10.0: (0.53, 0.54, 0.52, 0.32)},
    "gains_tlc_rotor_tuned.toml": {0.0: (0.64, 0.76, 0.63, 0.38), 10.0: (0.66, 0.55, 0.65, 0.32)},
    "gains_pid.toml": {0.0: (0.42, 0.51, 0.40, 0.22), 10.0: (0.42, 0.51, 0.40, 0.21)},
    "gains_pid_rotor.toml": {0.0: (0.58, 0.49, 0.55, 0.24), 10.0: (0.38, 0.34, 0.33, 0.20)},
}

_BLOCKS: dict[tuple[str, float], LoopBlocks] = {}


def blocks_for(gains: str, speed_m_s: float) -> LoopBlocks:
    """The loop of ``gains`` at its design plant and servos, one tick of delay (cached)."""
    key = (gains, speed_m_s)
    if key not in _BLOCKS:
        pid = PidGains.load(gains) if gains.startswith("gains_pid") else None
        sc = Scenario.load("paper", gains=None if pid else gains)
        d = (pid or sc.gains).design
        _, sv = servo_model(d.servos)
        c = build_kernel_controller("pid" if pid else "tlc", sc.airframe, sc.gains, sc.run.rate_hz,
                                    pid_gains=pid)  # fmt: skip
        _BLOCKS[key] = delayed(loop_blocks_at(c, PlantModel.load(d.plant), sc.airframe, sv, speed_m_s), 1)
    return _BLOCKS[key]


def _static_loop(k: float, channels: int = 1) -> LoopBlocks:
    """Plant ``z^-1`` (one tick of hold), controller ``-k`` (negative feedback): ``L = k z^-1``."""
    eye = np.eye(channels)
    plant = Discrete(np.zeros((channels, channels)), eye, eye, np.zeros((channels, channels)), DT)
    ctrl = Discrete(np.zeros((0, 0)), np.zeros((0, channels)), np.zeros((channels, 0)), -k * eye, DT)
    return LoopBlocks(ctrl, plant, closed_loop_eigenvalues(ctrl, plant))


@pytest.mark.parametrize("ticks", [0, 1, 2])
@pytest.mark.parametrize("k", [0.3, 0.5, 0.8])
def test_a_delayed_static_loop_has_its_closed_form_disk_margin(k: float, ticks: int) -> None:
    """``L = k z^-(1 + ticks)``: ``|S - 1/2| = |z^n - k| / (2 |z^n + k|)`` peaks where ``z^n = -1``,
    ``alpha = 2 (1 - k) / (1 + k)`` (first at ``w = pi / (n dt)``); python-control agrees."""
    b = delayed(_static_loop(k), ticks)
    n = 1 + ticks
    assert np.max(np.abs(b.eigenvalues)) == pytest.approx(k ** (1.0 / n), rel=1e-9)
    loop_in, _ = b.loops(OMEGA)
    d = siso_disk(loop_at_a_time(loop_in, 0), OMEGA, "u")
    exact = 2.0 * (1.0 - k) / (1.0 + k)
    assert d.alpha == pytest.approx(exact, rel=1e-6)
    assert math.cos(n * d.omega_rad_s * DT) == pytest.approx(-1.0, abs=1e-5)  # where z^n = -1
    dm, dgm, dpm = ct.disk_margins(ct.tf([k], [1.0] + [0.0] * n, DT), OMEGA)
    assert float(dm) == pytest.approx(exact, rel=1e-6)
    assert d.gain_margin_db == pytest.approx(float(dgm), rel=1e-6)
    assert d.phase_margin_deg == pytest.approx(float(dpm), rel=1e-6)
    # the same loop on three channels at once, uncoupled: the simultaneous margin is the SISO one
    b3 = delayed(_static_loop(k, 3), ticks)
    l3, _ = b3.loops(OMEGA)
    assert simultaneous_disk(l3, OMEGA, ("a", "b", "c")).alpha == pytest.approx(exact, rel=1e-6)


def test_the_structured_bound_is_exact_where_mu_is_known() -> None:
    """``mu`` of a diagonal complex perturbation: ``max |m_ii|`` for a diagonal matrix, ``sum |a_i
    b_i|`` for a rank-one ``a b^T`` (where the D-scaled bound is exact); above the spectral
    radius and below the largest singular value always."""
    rng = np.random.default_rng(7)
    m = np.diag([0.3 + 0.4j, -1.2, 0.5j])
    assert mu_upper_bound(m)[0] == pytest.approx(1.2, rel=1e-6)
    a = rng.normal(size=5) + 1j * rng.normal(size=5)
    b = rng.normal(size=5) + 1j * rng.normal(size=5)
    r1 = np.outer(a, b)
    assert mu_upper_bound(r1)[0] == pytest.approx(float(np.sum(np.abs(a * b))), rel=1e-4)
    for _ in range(5):
        g = rng.normal(size=(6, 6)) + 1j * rng.normal(size=(6, 6))
        mu = mu_upper_bound(g)[0]
        assert np.max(np.abs(np.linalg.eigvals(g))) <= mu * (1 + 1e-9) <= np.linalg.norm(g, 2) * (1 + 1e-9)


def test_the_worst_input_at_10_m_s_is_python_controls_disk_margin() -> None:
    """The rotor-aware tuned set in level flight at 10 m/s, one tick of delay: the worst pitch
    input's loop-at-a-time margin from the batched responses equals python-control's
    ``disk_margins`` on the loop python-control assembles from the same blocks."""
    b = blocks_for("gains_tlc_rotor_tuned.toml", 10.0)
    row = envelope_row(b, 10.0)
    i = PITCH_NAMES.index(row.input_at_a_time.channel)
    loop = -(b.controller.to_control() * b.plant.to_control())  # u -> x -> u, negative feedback
    others = np.eye(4)
    others[i, i] = 0.0
    closed: Any = ct.feedback(loop, ct.ss([], [], [], others, DT))
    siso = closed[i, i]
    # python-control's frequency response of a 100-state system is slow: every fourth point
    # of the table's grid, the batched responses on the same points
    omega = OMEGA_RAD_S[::4]
    dm, _dgm, _dpm = ct.disk_margins(siso, omega)
    loop_in, _ = b.loops(omega)
    ours = siso_disk(loop_at_a_time(loop_in, i), omega, row.input_at_a_time.channel)
    assert ours.alpha == pytest.approx(float(dm), rel=1e-6)
    assert row.input_at_a_time.alpha <= ours.alpha * (1 + 1e-12)  # the finer grid finds no less


def _figures(row: EnvelopeRow) -> tuple[float, float, float, float]:
    return (row.input_at_a_time.alpha, row.output_at_a_time.alpha, row.inputs_at_once.alpha,
            row.outputs_at_once.alpha)  # fmt: skip


@pytest.mark.parametrize("speed", [0.0, 10.0])
@pytest.mark.parametrize("gains", sorted(STATED))
def test_each_shipped_set_keeps_its_stated_margins(gains: str, speed: float) -> None:
    row = envelope_row(blocks_for(gains, speed), speed)
    assert row.stable
    stated = STATED[gains][speed]
    got = _figures(row)
    for name, g, s in zip(("input", "state", "all inputs", "all states"), got, stated, strict=True):
        assert g >= 0.98 * s, f"{gains} at {speed} m/s: {name} {g:.3f} below 0.98 x the stated {s}"


def test_heli_sitl_margins_envelope_prints_and_writes_the_table(
    tmp_path: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    from autopilot.analysis.envelope_margins import CSV_COLUMNS
    from heli_sitl.cli import main

    assert main(["margins", "--envelope", "--design"]) == 2  # the envelope takes the design point itself
    assert main(["margins", "--speed-m-s", "40"]) == 2
    capsys.readouterr()
    out = tmp_path / "env"
    assert main(["margins", "--gains", "gains_paper.toml", "--speed-m-s", "0", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "computation delay 1 tick (10 ms)" in printed and "skew 0" in printed
    lines = (out / "margins_envelope.csv").read_text().splitlines()
    assert lines[0].split(",") == list(CSV_COLUMNS) and len(lines) == 2
    row = dict(zip(CSV_COLUMNS, lines[1].split(","), strict=True))
    assert row["stable"] == "True" and row["input_at_a_time_channel"] == "theta_t"
    assert float(row["input_at_a_time"]) >= 0.98 * STATED["gains_paper.toml"][0.0][0]
    assert (out / "margins_envelope.md").read_text().count("| 0 |") == 1
