"""Run inside RotorPy's own venv (never the project's): environment steps per second of
RotorPy 3.0.0's batched ``QuadrotorEnv`` for a few batch sizes. Prints one JSON object on stdout.

``bench_gym.py`` creates that venv and starts this file with its interpreter; by hand::

    out/bench/venv-rotorpy/bin/python benchmarks/rotorpy_probe.py --envs 1 256 --seconds 3

The conditions are those of issue 49's reference figures: one thread, sim_rate 100 Hz,
``control_mode="cmd_motor_speeds"``, the Crazyflie's parameters as ``BatchedMultirotorParams``,
the environment's own defaults otherwise (random starts within 2 m, its hover reward,
``max_time`` 10 s, per-vehicle resets when a vehicle leaves its 4 m box or its time is up).
With zero actions (half the rotor speed range, below hover) the vehicles sink and leave their
box after 1-1.5 s (100-150 steps), and are reset one by one in Python, as in training. A
window holds those resets only once it reaches that step: N = 1 does (some 300 steps a
second), N = 256 partly, N = 4096 (a few steps a second) not at all, which favours RotorPy;
``resets`` in the JSON counts the vehicles reset within the reported window.
This file imports nothing of the project: it runs under RotorPy's interpreter.
"""

from __future__ import annotations

import os

# One thread, as the reference figures: set before torch loads its thread pools.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

SIM_RATE_HZ = 100
CONTROL_MODE = "cmd_motor_speeds"
# the initial rotor speed RotorPy's own examples hover the Crazyflie with, rad/s
HOVER_ROTOR_SPEED_RAD_S = 1788.53


def make_env(num_envs: int) -> Any:
    """RotorPy 3.0.0's batched environment, built as its own PPO example builds it."""
    import torch
    from rotorpy.learning.quadrotor_environments import QuadrotorEnv
    from rotorpy.vehicles.crazyflie_params import quad_params
    from rotorpy.vehicles.multirotor import BatchedMultirotorParams

    device = torch.device("cpu")
    n = num_envs
    x0 = {
        "x": torch.zeros(n, 3, device=device).double(),
        "v": torch.zeros(n, 3, device=device).double(),
        "q": torch.tensor([0, 0, 0, 1], device=device).repeat(n, 1).double(),
        "w": torch.zeros(n, 3, device=device).double(),
        "wind": torch.zeros(n, 3, device=device).double(),
        "rotor_speeds": torch.full((n, 4), HOVER_ROTOR_SPEED_RAD_S, device=device).double(),
    }
    params = BatchedMultirotorParams([quad_params] * n, n, device=device)
    return QuadrotorEnv(n, initial_states=x0, control_mode=CONTROL_MODE, quad_params=params,
                        device=device, sim_rate=SIM_RATE_HZ, render_mode="None")  # fmt: skip


def action_for(env: Any, kind: str) -> Any:
    """The constant (num_envs, 4) action: zeros, or the normalised hover rotor speed."""
    import numpy as np

    a = np.zeros((env.num_envs, 4))
    if kind == "hover":
        lo, hi = env.rotor_speed_min, env.rotor_speed_max  # (num_envs, 1) each, rad/s
        a[:] = 2.0 * (HOVER_ROTOR_SPEED_RAD_S - lo) / (hi - lo) - 1.0
    return a


def measure(num_envs: int, seconds: float, windows: int, min_steps: int, kind: str) -> dict[str, float]:
    """Steps ``num_envs`` vehicles with a constant action for ``windows`` consecutive windows of
    ``seconds / windows`` wall (and ``min_steps`` steps) each, after a short warm-up; returns
    the fastest window's figures (the others lost time to whatever else the machine ran) and
    the set-up cost."""
    t0 = time.perf_counter()
    env = make_env(num_envs)
    env.reset(seed=0)
    setup_s = time.perf_counter() - t0
    action = action_for(env, kind)
    for _ in range(3):  # first calls allocate and load
        env.step(action)
    best: dict[str, float] = {}
    for _ in range(windows):
        steps = resets = 0
        t0 = time.perf_counter()
        while True:
            _, _, dones, _ = env.step(action)
            resets += int(dones.sum())
            steps += 1
            wall = time.perf_counter() - t0
            if wall >= seconds / windows and steps >= min_steps:
                break
        if not best or steps / wall > best["steps"] / best["wall_s"]:
            best = {"steps": steps, "wall_s": wall, "resets": resets}
    env.close()
    return {
        "num_envs": num_envs,
        **best,
        "env_steps_per_s": num_envs * best["steps"] / best["wall_s"],
        "step_ms": best["wall_s"] / best["steps"] * 1e3,
        "setup_s": setup_s,
    }


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[1, 256, 4096], help="batch sizes")
    p.add_argument("--seconds", type=float, default=3.0, help="timed wall time per batch size, in all")
    p.add_argument("--windows", type=int, default=3, help="timed windows (the fastest counts)")
    p.add_argument("--min-steps", type=int, default=3, help="timed steps at least, per window")
    p.add_argument("--action", choices=("zero", "hover"), default="zero")
    args = p.parse_args(argv)

    import torch

    torch.set_num_threads(1)
    from importlib.metadata import version

    import rotorpy  # noqa: F401

    out: dict[str, Any] = {
        "rotorpy": version("rotorpy"),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "sim_rate_hz": SIM_RATE_HZ,
        "control_mode": CONTROL_MODE,
        "action": args.action,
        "runs": [measure(n, args.seconds, args.windows, args.min_steps, args.action) for n in args.envs],
    }
    json.dump(out, sys.stdout)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
