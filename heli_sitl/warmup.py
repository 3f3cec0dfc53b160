"""Compile (or load) every compiled function once, in one process: ``python -m heli_sitl.warmup``.

``make test`` runs it first, so the many processes the integration tests start load the
machine code from the cache instead of all compiling it at the same time.
"""

from __future__ import annotations

import time

import numpy as np


class _Hold:
    """The smallest user controller: zero pitch (only its path through the loop matters)."""

    def __init__(self, airframe: object, rate_hz: float) -> None:
        pass

    def update(self, t_s: float, state: np.ndarray, reference: np.ndarray) -> np.ndarray:
        return np.zeros(4)

    def reset(self) -> None:
        pass


def main() -> None:
    t0 = time.perf_counter()
    from autopilot.controller_names import BUILT_IN
    from autopilot.scenario import Scenario
    from heli_common import frames
    from heli_plant.contact import apply_ground_contact
    from heli_plant.model import Plant
    from heli_sitl.engine.closed_loop import SimOptions, simulate

    sc = Scenario.load("paper")
    for kind in BUILT_IN:  # the compiled loop, once per controller kernel it receives
        simulate(sc, SimOptions(duration_s=0.1, controller=kind))
    x = sc.initial.state().to_array()
    f = frames.state_to_ned_fields(x)
    frames.state_from_ned_fields(*f[0:6].tolist(), *f[10:16].tolist())
    from heli_common.kinematics import wrap_pi

    wrap_pi(4.0)
    apply_ground_contact(np.zeros(12), np.zeros(12))
    # the ArduPilot JSON backend's per-frame path: servo PWM -> pitches, the answer
    from heli_common.vehicle.swashplate import Swashplate
    from heli_common.wire.ardupilot_json import json_state_from_plant, state_json
    from heli_plant.sensors.model import specific_force_over_step

    swash = Swashplate.load()
    swash.pwm_from_pitches(swash.pitches_from_pwm(np.full(4, 1500.0)).as_array())
    json_state_from_plant(0.0, x, specific_force_over_step(x, x, 0.01, 9.80665))
    state_json(0.0, [0.0] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 3, [1.0, 0.0, 0.0, 0.0])
    plant = Plant(sc.airframe, x)
    plant.set_pitches(np.zeros(4))
    plant.step(0.01)
    from autopilot.controllers import CONTROLLERS, build_controller

    ref = sc.trajectory.sample(np.zeros(1))[0]
    for kind in CONTROLLERS:
        build_controller(kind, sc.airframe, sc.gains, 100.0).update(0.0, x, ref)
    # a user's controller (Python, called tick by tick) and the flight from sensors with
    # the navigation filter: their compiled paths differ from the built-in flight's
    from autopilot.estimation.config import EstimatorConfig
    from heli_common.world.config import World

    simulate(sc, SimOptions(duration_s=0.1, controller=_Hold))
    simulate(sc, SimOptions(duration_s=0.1, world=World.load("noisy"), estimator=EstimatorConfig.load("ins")))
    simulate(sc, SimOptions(duration_s=0.1, world=World.load("everything")))
    # the Gymnasium environments' batched kernel (heli_sitl.engine.batch), and a policy flown
    # as a controller
    from heli_sitl.gym.env import HeliTrackEnv
    from heli_sitl.gym.policy import PolicyConfig, policy_controller

    env = HeliTrackEnv(duration_s=0.1)
    env.reset(seed=0)
    env.step(np.zeros(4))
    from heli_sitl.gym.vector import HeliTrackVectorEnv

    envs = HeliTrackVectorEnv(num_envs=2, duration_s=0.1)  # the parallel kernel, one run of vehicles a core
    envs.reset(seed=0)
    envs.step(np.zeros((2, 4)))
    flyer = policy_controller(lambda o: np.zeros(4), PolicyConfig.of(env))
    simulate(sc, SimOptions(duration_s=0.1, controller=flyer))
    print(f"heli_sitl.warmup: compiled code ready in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
