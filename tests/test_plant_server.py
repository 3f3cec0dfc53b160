"""The plant's lockstep loop (heli_plant.server) against an autopilot that answers every
state at once: whose silence the plant reports when one of its own steps is slow."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import pytest

from heli_common.vehicle.scenario_file import load_vehicle
from heli_common.wire.links import ServoCommand
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp
from heli_plant.model import Plant
from heli_plant.server import PlantServer, SimConfig


class AnsweringAutopilot:
    """A servo link whose autopilot answers each state at once: the plant's first look after
    publishing finds nothing yet (as over a socket), the next finds the answer."""

    carries_arming = True
    refused = 0

    def __init__(self) -> None:
        self.asked_t_us = -1

    def receive(self, current_t_us: int, wait_s: float = 0.0) -> list[ServoCommand]:
        if current_t_us != self.asked_t_us:
            self.asked_t_us = current_t_us
            return []
        return [ServoCommand(current_t_us, np.zeros(4), True)]


class SlowStep(Plant):
    """A plant whose ``slow``-th step takes ``pause_s`` of wall clock (code compiled on first
    use, a busy core): the plant's own time."""

    slow, pause_s, steps = 3, 1.3, 0

    def step(self, dt_s: float) -> np.ndarray:  # type: ignore[type-arg]
        self.steps += 1
        if self.steps == self.slow:
            time.sleep(self.pause_s)
        return super().step(dt_s)


def test_a_slow_step_of_the_plant_is_not_the_autopilots_silence(caplog: pytest.LogCaptureFixture) -> None:
    """A cold numba cache made a lockstep demo's plant compile mid-flight, and then log "no
    command from the autopilot for 1.00 s" though the autopilot had answered at once: its
    silence counted from the command before the slow step, not from the state sent after it."""
    airframe, x0, rate = load_vehicle("paper", on_ground=False)
    plant = SlowStep(airframe, x0, step_s=1.0 / rate)
    cfg = SimConfig("lockstep", rate, duration_s=5 / rate, timeout_s=1.0)
    with MavlinkUdp((LOOPBACK, 0), (LOOPBACK, 9)) as link, caplog.at_level(logging.WARNING):
        t0 = time.monotonic()
        stats = PlantServer(plant, link, cfg, AnsweringAutopilot()).run(threading.Event())
        wall = time.monotonic() - t0
    assert wall > SlowStep.pause_s  # the slow step happened
    assert stats.steps == 6 and stats.commands == 6  # every state answered
    assert stats.silent_events == 0 and not stats.autopilot_silent, caplog.text
    assert stats.resent_states == 0  # nor was the state re-sent as if the answer were late
    assert "no command from the autopilot" not in caplog.text
