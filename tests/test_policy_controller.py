"""A policy flies wherever a controller flies (heli_sitl/gym/policy.py): the env's rollout,
in hs.simulate, in lockstep processes and in a campaign on Dask workers, from one object."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import heli_sitl as hs
from ground.plots import read_csv_columns
from heli_common.state import STATE_NAMES
from heli_sitl.gym.env import HeliTrackEnv
from heli_sitl.gym.policy import PolicyConfig, policy_controller, save_policy
from heli_sitl.launch.demo import DemoOptions, run_demo

DURATION_S = 12.0


def linear(scale: float) -> Callable[[np.ndarray], np.ndarray]:
    """A deterministic policy of the observation (a small linear map through tanh); a closure,
    so that cloudpickle carries it by value to a process that cannot import this module."""
    w = np.random.default_rng(1).normal(size=(4, 25)) * scale
    return lambda obs: np.asarray(np.tanh(w @ obs))


def rollout(env: HeliTrackEnv, policy: Callable[[np.ndarray], np.ndarray], seed: int) -> hs.FlightMetrics:
    obs, _ = env.reset(seed=seed)
    while True:
        obs, _, terminated, truncated, info = env.step(policy(obs))
        if terminated or truncated:
            m = info["metrics"]
            assert isinstance(m, hs.FlightMetrics)
            return m


CASES = [("residual", None), ("residual", "everything"), ("pitch", "noisy")]


@pytest.mark.parametrize(("mode", "world"), CASES)
def test_a_policy_flies_hs_simulate_as_it_flew_the_env(mode: str, world: str | None) -> None:
    """The same truth at every tick: in an ideal world, with servos and turbulence, and on the
    estimate from sensors; in pitch mode the policy (not a flyer) is lost as in the env."""
    env = HeliTrackEnv(action_mode=mode, world=world, duration_s=DURATION_S)
    policy = linear(0.02)
    m = rollout(env, policy, 3)
    rec = env.flight_record()
    f = hs.simulate(controller=policy_controller(policy, PolicyConfig.of(env)), world=world, seed=3,
                    duration_s=DURATION_S)  # fmt: skip
    assert f.record is not None and f.metrics is not None
    n = rec.x.shape[0]
    assert np.array_equal(rec.x, f.record.x[:n])
    assert np.array_equal(rec.pitches[:-1], f.record.pitches[: n - 1])
    assert m.lost == f.metrics.lost == (mode == "pitch")


@pytest.mark.processes
def test_a_saved_policy_flies_in_lockstep_processes_as_in_the_env(tmp_path: Path) -> None:
    """save_policy's name loads the policy in the autopilot process (--controller): the
    lockstep flight is the env's rollout, the positions on the sim link (float32) equal at
    every tick."""
    env = HeliTrackEnv(action_mode="residual", duration_s=DURATION_S)
    policy = linear(0.05)
    m = rollout(env, policy, 0)
    spec = save_policy(policy, PolicyConfig.of(env), tmp_path / "policy")
    f = hs.simulate(controller=spec, duration_s=DURATION_S)
    assert f.metrics is not None and f.metrics.rms_m == m.rms_m
    summary = run_demo(DemoOptions(mode="lockstep", out=tmp_path / "run", timeout_s=300, via_ground=False,
                                   duration_s=DURATION_S,
                                   extra_autopilot_args=("--controller", spec)))  # fmt: skip
    assert summary["gains"] == "policy"
    cols = read_csv_columns(tmp_path / "run" / "run.csv")
    x = env.flight_record().x
    assert cols["t_s"].size == x.shape[0]
    for k in range(3):
        wire = cols[STATE_NAMES[k]].astype(np.float32)
        assert np.array_equal(wire, x[:, k].astype(np.float32)), STATE_NAMES[k]
    # the same name in a campaign: its workers load the policy; the start as the env's flies
    # the env's flight (the campaign's metrics from the same record)
    camp = tmp_path / "policy.toml"
    camp.write_text(f'name = "policy"\nscenario = "paper"\nsampler = "grid"\nseed = 1\n'
                    f'duration_s = {DURATION_S}\n[[vary]]\nkey = "initial.yaw_error_rad"\n'
                    'dist = "grid"\nvalues = [0.0, 0.5]\n')  # fmt: skip
    out = subprocess.run(
        [sys.executable, "-m", "heli_sitl.cli", "campaign", str(camp), "--out", str(tmp_path / "camp"),
         "--controller", spec, "--workers", "1", "--quiet", "--no-figures"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    counts = json.loads((tmp_path / "camp" / "campaign.json").read_text())["counts"]
    assert counts["flights"] == 2 and counts["failed"] == 0
    import pyarrow.parquet as pq

    rows = pq.read_table(tmp_path / "camp" / "results.parquet").to_pylist()
    first = next(r for r in rows if r["initial.yaw_error_rad"] == 0.0)
    assert first["rms_10_m"] == m.rms_10_m
