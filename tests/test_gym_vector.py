"""The vectorised HeliSitl/Track-v0 (heli_sitl/gym/vector.py): N vehicles in one compiled call
a step, vehicle k the single env of seed ``seed + k``, bit for bit, across autoresets, on any
number of threads."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import heli_sitl.gym  # noqa: F401  (registers the id)
from heli_common.jit import max_threads
from heli_sitl.gym.env import HeliTrackEnv
from heli_sitl.gym.vector import HeliTrackVectorEnv

N = 3
STEPS = 130  # two episodes of 0.5 s and the start of a third (or more: some are lost sooner)
KW: dict[str, object] = dict(world="everything", action_mode="pitch", duration_s=0.5)


def test_vehicle_k_is_the_single_env_of_seed_plus_k_bit_for_bit_across_autoresets() -> None:
    """Random pitches (vehicles lost and truncated in turn), turbulence and servos: every
    observation and reward of vehicle k is the single env's under the same actions, with
    Gymnasium's next-step autoreset (reward 0 and the first observation of the next episode,
    whose seed both draw from the generator of seed + k)."""
    envs = gym.make_vec("HeliSitl/Track-v0", num_envs=N, vectorization_mode="vector_entry_point", **KW)
    assert isinstance(envs, HeliTrackVectorEnv) and envs.observation_space.shape == (N, 25)
    rng = np.random.default_rng(0)
    obs, _ = envs.reset(seed=10)
    actions, observations, rewards, ends = [], [obs], [], []
    for _ in range(STEPS):
        actions.append(rng.uniform(-0.4, 0.6, (N, 4)))
        obs, r, terminated, truncated, _ = envs.step(actions[-1])
        observations.append(obs)
        rewards.append(r)
        ends.append(terminated | truncated)
    o, rw, e = np.array(observations), np.array(rewards), np.array(ends)
    assert e.sum() >= 2 * N and (np.array(rewards) == 0.0).sum() >= 2 * N
    for k in range(N):
        env = HeliTrackEnv(**KW)  # type: ignore[arg-type]
        got, _ = env.reset(seed=10 + k)
        mine, my_rewards = [got], []
        done = False
        for s in range(STEPS):
            if done:
                got, _ = env.reset()
                reward, done = 0.0, False
            else:
                got, reward, terminated, truncated, _ = env.step(actions[s][k])
                done = terminated or truncated
                assert done == e[s, k]
            mine.append(got)
            my_rewards.append(reward)
        assert np.array_equal(np.array(mine), o[:, k]) and np.array_equal(np.array(my_rewards), rw[:, k])


def test_a_recording_vector_env_reports_each_ended_flights_metrics() -> None:
    envs = HeliTrackVectorEnv(num_envs=2, action_mode="residual", duration_s=0.3, record=True)
    envs.reset(seed=0)
    for _ in range(30):
        _, _, _, truncated, info = envs.step(np.zeros((2, 4)))
    assert truncated.all() and info["_metrics"].all()
    assert not info["metrics"][0].lost and info["metrics"][1].rms_m == info["metrics"][0].rms_m


def test_two_threads_step_the_vehicles_bit_for_bit_as_one() -> None:
    """The parallel kernel cut into two shards on two threads (turbulence, sensors and the
    estimator on; random pitches, so that vehicles are lost and restarted mid-run) gives the
    very observations, rewards and episode ends of one thread."""
    if max_threads() < 2:
        pytest.skip("one core (or NUMBA_NUM_THREADS=1): no second thread to compare with")
    n, steps = 5, 70
    kw: dict[str, object] = dict(world="everything", action_mode="pitch", duration_s=0.3)
    actions = np.random.default_rng(1).uniform(-0.4, 0.6, (steps, n, 4))
    runs = []
    for threads in (1, 2):
        envs = HeliTrackVectorEnv(num_envs=n, num_threads=threads, **kw)  # type: ignore[arg-type]
        assert envs.fleet.shards == threads
        out = [envs.reset(seed=3)[0]]
        for a in actions:
            obs, r, terminated, truncated, _ = envs.step(a)
            out += [obs, r, terminated, truncated]
        runs.append(out)
    ends = np.array(runs[0][3::4]) | np.array(runs[0][4::4])
    assert ends.sum() >= n  # every vehicle's episode ended at least once on the way
    assert all(np.array_equal(a, b) for a, b in zip(runs[0], runs[1], strict=True))
