"""``HeliSitl/Track-v0``: one helicopter tracking a scenario's trajectory, a Gymnasium env.

>>> import gymnasium as gym, heli_sitl.gym
>>> env = gym.make("HeliSitl/Track-v0", action_mode="residual")   # on the paper's TLC
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Every step is one control tick of the in-process flight (the compiled pieces of
:mod:`heli_sitl.engine.closed_loop`, through :func:`heli_sitl.engine.batch.batch_step`): a
zero residual on the TLC flies ``hs.simulate()``'s flight bit for bit, and ``reset(seed=s)``
flies ``hs.simulate(..., seed=s)``'s world (its noise and turbulence). See docs/gym.md.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from autopilot.envelope import DEFAULT as DEFAULT_ENVELOPE
from autopilot.envelope import Envelope
from autopilot.estimation.config import EstimatorConfig
from autopilot.scenario import Scenario
from heli_common.state import N_PITCH, FloatArray
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_sitl.api import PID, TLC, TrajectoryLike
from heli_sitl.engine.batch import N_OBS
from heli_sitl.gym.fleet import DEFAULT_WEIGHTS, Fleet, FlightSpec, RewardWeights
from heli_sitl.gym.observation import observation_names

# reward_fn(state, reference, action) -> reward, each batched over vehicles: the true states
# (N, 12) after the step, their reference rows (N, 9), the actions clipped to [-1, 1] (N, 4)
RewardFn = Callable[[FloatArray, FloatArray, FloatArray], FloatArray]
SEED_DRAW = 2**31  # a seed drawn from the env's generator is below this


class HeliTrackEnv(gym.Env[FloatArray, Any]):
    """The bench's flight as a Gymnasium env; arguments as :func:`heli_sitl.api.simulate`
    takes them (preset names, files or objects), plus:

    * ``action_mode``: ``"residual"`` (the action, in [-1, 1]^4, adds ``residual_scale`` times
      each pitch's half range to the built-in ``controller``'s command) or ``"pitch"`` (the
      action is the four pitches, -1 and 1 the limits, as the sim link normalises them);
    * ``reward_weights`` (:class:`RewardWeights`) or ``reward_fn`` (:data:`RewardFn`);
    * ``envelope``: leaving it terminates the episode; the scenario's end truncates it, and
      ``info["metrics"]`` then holds the flight's :class:`~autopilot.flight_metrics.FlightMetrics`.

    The observation is named by :attr:`observation_names`."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
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
        render_mode: str | None = None,
    ) -> None:
        self.flight = FlightSpec.resolve(scenario, plant, world, controller, estimator, duration_s,
                                         trajectory)  # fmt: skip
        self.fleet = Fleet(self.flight, 1, action_mode, residual_scale, envelope, reward_weights, record=True)
        self.action_mode = action_mode
        self.residual_scale = float(residual_scale)
        self.reward_fn = reward_fn
        self.render_mode = render_mode
        self.observation_names = observation_names(action_mode)
        self.action_space = spaces.Box(-1.0, 1.0, (N_PITCH,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (N_OBS,), np.float64)
        self.flight_seed: int | None = None  # the world seed of the episode flying
        self._done = True

    @property
    def dt_s(self) -> float:
        return self.flight.dt_s

    @property
    def max_steps(self) -> int:
        """The steps of an episode flown to the scenario's end."""
        return self.flight.n_ticks

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """A new flight at tick 0; ``seed`` (the world's seed, as ``hs.simulate(seed=...)``)
        also seeds the generator later episodes draw their seeds from. ``options``: none yet."""
        super().reset(seed=seed)
        self.flight_seed = seed if seed is not None else draw_seed(self.np_random)
        self.fleet.start(0, self.flight_seed)
        self.fleet.step()
        self._done = False
        return self.fleet.obs[0].copy(), {"seed": self.flight_seed}

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise gym.error.ResetNeeded("the flight has ended: call reset()")
        f = self.fleet
        f.actions[0] = action
        f.step()
        terminated, truncated = bool(f.terminated[0]), bool(f.truncated[0])
        reward = float(f.reward[0])
        if self.reward_fn is not None:
            reward = float(np.asarray(self.reward_fn(f.rows["x"], f.refs[f.ticks], f.last_a)).reshape(-1)[0])
        info: dict[str, Any] = {}
        if terminated or truncated:
            self._done = True
            info["metrics"] = f.metrics(0)
        return f.obs[0].copy(), reward, terminated, truncated, info

    def flight_record(self) -> Any:
        """The episode's :class:`~autopilot.metrics.FlightRecord` so far (truth, reference, commands)."""
        return self.fleet.flight_record(0)


def draw_seed(rng: np.random.Generator) -> int:
    """The world seed of an episode reset without one: the next from the env's generator."""
    return int(rng.integers(0, SEED_DRAW))
