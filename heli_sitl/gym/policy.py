"""A policy flies wherever a controller flies: in-process, in the autopilot process, in a campaign.

A policy is any callable ``obs -> action`` of the environment it was trained in
(:class:`~heli_sitl.gym.env.HeliTrackEnv`: the observation of ``env.observation_names``, an
action in [-1, 1]^4). :func:`policy_controller` turns it, with the env's configuration
(:class:`PolicyConfig`: the action mode, the residual's scale and the built-in law it rides
on), into a controller class of the bench's contract (:mod:`autopilot.user_controller`)::

    cls = policy_controller(policy, PolicyConfig.of(env))
    hs.simulate(controller=cls)                       # the env's flight, bit for bit

Another process cannot receive an object, only a name: :func:`save_policy` writes the policy
(pickled with cloudpickle: lambdas and closures too) and a two-line module beside it, and
returns its ``"path/policy_controller.py:Policy"``, which every command takes::

    spec = save_policy(policy, PolicyConfig.of(env), "out/my_policy")
    hs.simulate(controller=spec)
    #   heli-sitl demo --controller out/my_policy/policy_controller.py:Policy
    #   heli-sitl campaign robustness --controller out/my_policy/policy_controller.py:Policy

The controller computes the observation and the command with the environment's own compiled
functions (:mod:`heli_sitl.engine.batch`), so the flight is the env's rollout, bit for bit,
where the policy is deterministic.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from autopilot.control import KernelController
from autopilot.controllers import build_kernel_controller
from autopilot.pid.gains import PidGains
from autopilot.tlc.gains import Gains
from heli_common.state import N_PITCH, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_sitl.engine.batch import EP_SCALE, N_OBS, command_from_action, fill_observation, normalise_pitches

Policy = Callable[[FloatArray], Any]
PICKLE = "policy.pkl"
MODULE = "policy_controller.py"


@dataclass(frozen=True)
class PolicyConfig:
    """What a policy needs of the env it was trained in to fly outside it."""

    action_mode: str  # "residual" or "pitch"
    residual_scale: float
    base: str  # the built-in law a residual rides on: "tlc" or "pid"
    gains: Gains  # the TLC's (the scenario's)
    feedforward: str
    pid_gains: PidGains | None
    observation_names: tuple[str, ...]

    @classmethod
    def of(cls, env: Any) -> PolicyConfig:
        """The configuration of ``env`` (a HeliTrackEnv or its vector form, wrapped or not)."""
        e = env.unwrapped
        f, sc = e.flight, e.flight.scenario
        return cls(e.action_mode, float(e.fleet.ep[EP_SCALE]), f.base, sc.gains, sc.run.feedforward,
                   f.pid_gains, tuple(e.observation_names))  # fmt: skip


class PolicyController:
    """The controller of a policy (the class attributes ``policy`` and ``config`` set by
    :func:`policy_controller`): the built-in law's command (residual mode), the observation,
    the policy's action, the pitches, as the environment computes them."""

    policy: ClassVar[Policy]
    config: ClassVar[PolicyConfig]
    name = "policy"

    def __init__(self, airframe: Airframe, rate_hz: float) -> None:
        cfg = self.config
        if len(cfg.observation_names) != N_OBS:
            raise ValueError(f"policy: trained on {len(cfg.observation_names)} observations, the env "
                             f"gives {N_OBS}")  # fmt: skip
        self.residual = cfg.action_mode == "residual"
        self.base: KernelController[Any] = build_kernel_controller(
            cfg.base, airframe, cfg.gains, rate_hz, cfg.feedforward, cfg.pid_gains)  # fmt: skip
        lim = np.array(airframe.limits.as_tuple(), dtype=float)
        self.lo, self.hi = lim[:, 0].copy(), lim[:, 1].copy()
        self.last_a = np.zeros(N_PITCH)
        self.cmd = np.zeros(N_PITCH)
        self.obs = np.zeros(N_OBS)

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
        base = np.zeros(N_PITCH)
        if self.residual:
            base = self.base.update(t_s, state, reference)
            normalise_pitches(base, self.lo, self.hi, self.cmd)
        else:
            self.cmd[:] = self.last_a
        fill_observation(state, reference, self.cmd, self.obs)
        action = np.asarray(type(self).policy(self.obs.copy()), dtype=float).reshape(N_PITCH)
        a, u = np.empty(N_PITCH), np.empty(N_PITCH)
        command_from_action(action, base, self.lo, self.hi, self.residual, self.config.residual_scale, a, u)
        self.last_a = a
        return u  # clipped to the limits by the bench (UserController), as the env clips it

    def reset(self) -> None:
        self.base.reset()
        self.last_a = np.zeros(N_PITCH)


def policy_controller(policy: Policy, config: PolicyConfig, name: str = "policy") -> type[PolicyController]:
    """A controller class flying ``policy`` (for ``hs.simulate(controller=...)`` in this process)."""
    body = {"policy": staticmethod(policy), "config": config, "name": name}
    return type("Policy", (PolicyController,), body)


def save_policy(policy: Policy, config: PolicyConfig, directory: str | Path, name: str = "policy") -> str:
    """``policy`` and ``config`` pickled in ``directory`` with the module that loads them;
    returns the controller's name for every command: ``"<directory>/policy_controller.py:Policy"``."""
    import cloudpickle  # type: ignore[import-untyped]

    d = Path(directory).resolve()
    d.mkdir(parents=True, exist_ok=True)
    try:
        data = cloudpickle.dumps((policy, config, name))
    except (TypeError, pickle.PicklingError) as exc:
        raise ValueError(f"policy: it does not pickle ({exc}): keep in it only what it needs to act "
                         "(a network, or the path of its saved file), not an env or a model holding "
                         "one") from exc
    (d / PICKLE).write_bytes(data)
    (d / MODULE).write_text(
        '"""A policy flown as a controller (heli_sitl.gym.policy): policy.pkl beside this file."""\n\n'
        "from pathlib import Path\n\nfrom heli_sitl.gym.policy import load_policy_controller\n\n"
        f'Policy = load_policy_controller(Path(__file__).with_name("{PICKLE}"))\n'
    )
    return f"{d / MODULE}:Policy"


def load_policy_controller(path: str | Path) -> type[PolicyController]:
    """The controller class of a policy :func:`save_policy` wrote (its pickle's path)."""
    policy, config, name = pickle.loads(Path(path).read_bytes())
    return policy_controller(policy, config, name)
