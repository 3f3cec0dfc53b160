"""A residual PPO policy on the TLC (stable-baselines3, CPU): trained for a wall-clock budget on the
paper's spiral in light turbulence, then flown against the plain TLC on a held-out trajectory (the
figure eight) in the same world, as a controller of the bench (heli_sitl.gym.policy).

Not part of the test suite. Needs torch (the CPU build) and stable-baselines3, which the project
does not install::

    pip install --target /tmp/sb3 torch stable-baselines3     # then drop its numpy and gymnasium
    PYTHONPATH=/tmp/sb3 .venv/bin/python docs/examples/ppo_residual.py --budget-s 300 --out out/ppo

Writes ``learning_curve.csv`` (timesteps, wall seconds, mean episode reward of the last episodes),
``policy/`` (:func:`~heli_sitl.gym.policy.save_policy`: fly it with ``--controller
out/ppo/policy/policy_controller.py:Policy`` anywhere) and ``result.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env

import heli_sitl as hs
from heli_sitl.gym.env import HeliTrackEnv
from heli_sitl.gym.policy import PolicyConfig, save_policy

WORLD = "light-turbulence"
TRAIN: dict[str, Any] = dict(scenario="paper", world=WORLD, duration_s=30.0, action_mode="residual",
                             residual_scale=0.05)  # fmt: skip
HELD_OUT: dict[str, Any] = dict(scenario="figure_eight", world=WORLD, seed=12345)


class Budget(BaseCallback):
    """Stops training after ``budget_s`` of wall time; keeps the learning curve (the mean
    reward of the episodes ended since the last row)."""

    def __init__(self, budget_s: float) -> None:
        super().__init__()
        self.budget_s = budget_s
        self.t0 = time.perf_counter()
        self.rows: list[tuple[int, float, float, int]] = []
        self._returns: list[float] = []

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:
                self._returns.append(float(info["episode"]["r"]))
        return time.perf_counter() - self.t0 < self.budget_s

    def _on_rollout_end(self) -> None:
        if self._returns:
            wall = time.perf_counter() - self.t0
            self.rows.append((self.num_timesteps, wall, float(np.mean(self._returns)), len(self._returns)))
            print(f"{self.num_timesteps:>8} steps {self.rows[-1][1]:6.0f} s  mean episode reward "
                  f"{self.rows[-1][2]:8.1f} ({len(self._returns)} episodes)", flush=True)
            self._returns = []


class SavedPPO:
    """The trained policy as a callable obs -> action that pickles as its file's path (the model
    itself holds the training envs, which do not pickle), loaded on first use in any process."""

    def __init__(self, path: Path) -> None:
        self.path = str(Path(path).resolve())
        self.model: PPO | None = None

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self.model is None:
            self.model = PPO.load(self.path, device="cpu")
        return np.asarray(self.model.predict(obs, deterministic=True)[0])

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "model": None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget-s", type=float, default=300.0, help="training wall time [s]")
    ap.add_argument("--out", type=Path, default=Path("out/ppo_residual"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    vec = make_vec_env(lambda: HeliTrackEnv(**TRAIN), n_envs=4, seed=args.seed)
    model = PPO("MlpPolicy", vec, n_steps=1024, batch_size=256, learning_rate=3e-4, gamma=0.99,
                policy_kwargs=dict(net_arch=[64, 64], log_std_init=-1.0), seed=args.seed, device="cpu",
                verbose=0)  # fmt: skip
    budget = Budget(args.budget_s)
    model.learn(total_timesteps=10**9, callback=budget)
    with (args.out / "learning_curve.csv").open("w") as f:
        f.write("timesteps,wall_s,mean_episode_reward,episodes\n")
        for row in budget.rows:
            f.write(",".join(f"{v:g}" for v in row) + "\n")

    model.save(args.out / "ppo.zip")
    policy = SavedPPO(args.out / "ppo.zip")
    config = PolicyConfig.of(HeliTrackEnv(**TRAIN))
    spec = save_policy(policy, config, args.out / "policy", name="TLC + PPO residual")
    tlc = hs.simulate(**HELD_OUT)
    ppo = hs.simulate(controller=spec, **HELD_OUT)
    result: dict[str, Any] = {"budget_s": args.budget_s, "timesteps": budget.num_timesteps,
                              "held_out": HELD_OUT}
    for name, fl in (("tlc", tlc), ("tlc+ppo", ppo)):
        assert fl.metrics is not None
        m = fl.metrics
        result[name] = {"status": fl.status.value, "rms_0_m": m.rms_0_m, "rms_10_m": m.rms_10_m,
                        "max_tilt_rad": m.max_tilt_rad, "pitch_travel_rad": m.pitch_travel_rad}
        print(f"{name:8} on the held-out figure eight: {fl.status}, RMS [10, end] {m.rms_10_m:.4f} m, "
              f"pitch travel {m.pitch_travel_rad:.1f} rad")  # fmt: skip
    (args.out / "result.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
