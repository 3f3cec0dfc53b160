"""``HeliSitl/Track-v0`` vectorised: N helicopters stepped by one compiled call a step.

>>> envs = gym.make_vec("HeliSitl/Track-v0", num_envs=256, vectorization_mode="vector_entry_point")
>>> obs, info = envs.reset(seed=0)                      # vehicle k: world seed 0 + k
>>> obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())

Vehicle k flies exactly what :class:`~heli_sitl.gym.env.HeliTrackEnv` flies after
``reset(seed=seed + k)``, episode after episode (its own generator draws the next seeds).
Autoreset is Gymnasium's default, next-step: the step after a vehicle's episode ends resets
it (its action ignored, reward 0, neither terminated nor truncated) and returns its first
observation.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from autopilot.envelope import DEFAULT as DEFAULT_ENVELOPE
from autopilot.envelope import Envelope
from autopilot.estimation.config import EstimatorConfig
from autopilot.scenario import Scenario
from heli_common.config import ConfigError
from heli_common.jit import max_threads
from heli_common.state import N_PITCH, FloatArray
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_sitl.api import PID, TLC, TrajectoryLike
from heli_sitl.engine.batch import N_OBS
from heli_sitl.gym.env import RewardFn, draw_seed
from heli_sitl.gym.fleet import DEFAULT_WEIGHTS, Fleet, FlightSpec, RewardWeights
from heli_sitl.gym.observation import observation_names


class HeliTrackVectorEnv(VectorEnv[FloatArray, FloatArray, FloatArray]):
    """``num_envs`` vehicles of one configuration (the arguments of
    :class:`~heli_sitl.gym.env.HeliTrackEnv`); ``record``: keep each vehicle's flight record
    and report ``info["metrics"]`` (an object array, None where no episode ended) at the end of
    an episode (2.4 MB a vehicle for the paper's 120 s). ``num_threads``: the vehicles are
    stepped on that many threads (numba's; default: every core the process may run on,
    :func:`heli_common.jit.max_threads`), with the same results for any number."""

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        scenario: str | Path | Scenario = "paper",
        plant: str | Path | PlantModel = "paper",
        world: str | Path | World | None = None,
        controller: TLC | PID | str = "tlc",
        estimator: str | Path | EstimatorConfig | None = None,
        duration_s: float | None = None,
        trajectory: str | Path | TrajectoryLike | None = None,
        action_mode: str = "residual",
        residual_scale: float = 0.1,
        envelope: Envelope = DEFAULT_ENVELOPE,
        reward_weights: RewardWeights = DEFAULT_WEIGHTS,
        reward_fn: RewardFn | None = None,
        record: bool = False,
        render_mode: str | None = None,
        num_threads: int | None = None,
    ) -> None:
        self.flight = FlightSpec.resolve(scenario, plant, world, controller, estimator, duration_s,
                                         trajectory)  # fmt: skip
        self.num_threads = max_threads() if num_threads is None else num_threads
        self.fleet = Fleet(self.flight, num_envs, action_mode, residual_scale, envelope, reward_weights,
                           record, self.num_threads)  # fmt: skip
        self.num_envs = num_envs
        self.action_mode = action_mode
        self.reward_fn = reward_fn
        self.render_mode = render_mode
        self.observation_names = observation_names(action_mode)
        self.single_action_space = spaces.Box(-1.0, 1.0, (N_PITCH,), np.float32)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (N_OBS,), np.float64)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]
        self.flight_seeds = np.zeros(num_envs, dtype=np.int64)
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def _start(self, v: int, seed: int) -> None:
        self.flight_seeds[v] = seed
        self.fleet.start(v, seed)

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Every vehicle at tick 0; ``seed`` an integer (vehicle k: ``seed + k``), one per
        vehicle, or None (drawn)."""
        seeds: list[int | None]
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + k for k in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ConfigError(f"seed: expected {self.num_envs} seeds, got {len(seeds)}")
        if seed is not None or not hasattr(self, "_np_random"):
            self._np_random, self._np_random_seed = seeding.np_random(seed if isinstance(seed, int) else None)
        for v, s in enumerate(seeds):
            self._rngs[v] = seeding.np_random(s)[0]
            self._start(v, s if s is not None else draw_seed(self._rngs[v]))
        self.fleet.step()
        self._autoreset[:] = False
        return self.fleet.obs.copy(), {"seed": self.flight_seeds.copy()}

    def step(
        self, actions: Any
    ) -> tuple[FloatArray, FloatArray, np.ndarray[Any, Any], np.ndarray[Any, Any], dict[str, Any]]:
        f = self.fleet
        f.actions[:] = actions
        restarted = np.flatnonzero(self._autoreset)
        for v in restarted:
            self._start(int(v), draw_seed(self._rngs[v]))
        f.step()
        rewards = f.reward.copy()
        if self.reward_fn is not None:
            r = self.reward_fn(f.rows["x"], f.refs[f.ticks], f.last_a)
            rewards = np.asarray(r, dtype=float).reshape(-1)
            rewards[restarted] = 0.0
        terminated, truncated = f.terminated.copy(), f.truncated.copy()
        ended = terminated | truncated
        self._autoreset = ended
        info: dict[str, Any] = {}
        if f.record and ended.any():
            metrics = np.full(self.num_envs, None, dtype=object)
            for v in np.flatnonzero(ended):
                metrics[v] = f.metrics(int(v))
            info = {"metrics": metrics, "_metrics": ended.copy()}
        return f.obs.copy(), rewards, terminated, truncated, info
