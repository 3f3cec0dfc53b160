"""The closed loop in one process over a CAN bus (python-can ``virtual`` by default).

Each tick ``controller.update`` -> ``sender.send`` -> bus -> ``endpoint.poll`` ->
``plant.set_pitches(held)`` -> ``plant.step``. Its record holds the pitches the plant
actually applied (float16-quantised), and the commanded ones.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from autopilot.flight.commands import Arm, FlyTrajectory
from autopilot.flight.manager import FlightConfig, FlightManager
from autopilot.links.can_servo import DEFAULT_NODE_ID, CanServoOutput, CanServoSender
from autopilot.metrics import FlightRecord
from autopilot.runner import Recorder, Runner, RunnerConfig
from autopilot.scenario import Scenario
from autopilot.tlc.controller import TLController
from heli_common.defaults import HOME
from heli_common.state import N_PITCH, FloatArray
from heli_common.wire.can.bus import CanBusConfig
from heli_common.wire.can.dronecan_codec import DEFAULT_ACTUATOR_IDS
from heli_plant.can_endpoint import DEFAULT_TIMEOUT_S, CanServoEndpoint
from heli_plant.model import Plant


@dataclass(frozen=True)
class CanFlight:
    """A closed-loop flight over CAN: ``record.pitches`` are the pitches the plant applied."""

    record: FlightRecord
    commanded: FloatArray  # (N, 4) controller output per tick [rad]
    sender_stats: dict[str, int]
    endpoint_stats: dict[str, int]


_channel_ids = itertools.count()


def fly_over_can(
    scenario: Scenario,
    *,
    bus: CanBusConfig | None = None,
    duration_s: float | None = None,
    node_id: int = DEFAULT_NODE_ID,
    actuator_ids: Sequence[int] = DEFAULT_ACTUATOR_IDS,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    on_tick: Callable[[int, float], Any] | None = None,
) -> CanFlight:
    """Fly ``scenario`` with the controller and plant in this process, the pitches going
    over a CAN bus (a fresh python-can ``virtual`` channel unless ``bus`` is given).

    Tick k is at t = k / rate: the autopilot's runner ticks on the state at t (the same
    tick as in the autopilot process), the plant holds the pitches it received while it
    integrates to t + dt (as :func:`heli_sitl.engine.closed_loop.simulate`, but through the
    runner, the sender, the bus and the servo endpoint). ``on_tick(k, t)``
    runs after each tick's send (e.g. to spin another node on the bus).
    """
    run = scenario.run
    rate_hz = run.rate_hz
    duration = duration_s if duration_s is not None else run.duration_s
    if bus is None:
        bus = CanBusConfig("virtual", f"heli-sitl-fly-{next(_channel_ids)}")
    ctrl = TLController(scenario.airframe, scenario.gains, rate_hz, run.feedforward)
    plant = Plant(
        scenario.airframe, scenario.initial.state().to_array(), substeps=run.plant_substeps
    )
    manager = FlightManager(FlightConfig(home=HOME))
    for cmd in (FlyTrajectory(scenario.trajectory), Arm()):
        reply = manager.execute(cmd, 0.0, plant.x)
        assert reply.accepted, reply
    n = round(duration * rate_hz)
    applied = np.empty((n + 1, N_PITCH))
    dt = 1.0 / rate_hz
    recorder = Recorder(capacity=n + 1)
    # both ends open their own bus on the channel, as two nodes would
    with CanServoEndpoint(
        bus, limits=scenario.airframe.limits, actuator_ids=actuator_ids, timeout_s=timeout_s
    ) as endpoint, CanServoSender(bus, node_id=node_id, actuator_ids=actuator_ids) as sender:
        # the autopilot's own tick (flight logic, control law, recorder) sends over CAN;
        # this loop only advances simulation time and the plant
        runner = Runner(ctrl, manager, None, CanServoOutput(sender), RunnerConfig("lockstep", rate_hz),
                        recorder=recorder)  # fmt: skip
        wall0 = time.perf_counter()
        for k in range(n + 1):
            tk = k / rate_hz
            runner.tick(tk, plant.x, round(tk * 1e6))
            if on_tick is not None:
                on_tick(k, tk)
            held = endpoint.poll(tk)
            if held is not None:
                plant.set_pitches(held)
            applied[k] = plant.u
            if k < n:
                plant.step(dt)
        wall = time.perf_counter() - wall0
        sender_stats, endpoint_stats = dict(sender.stats), dict(endpoint.stats)
    commanded = recorder.rows_array()[:, 22 : 22 + N_PITCH].copy()
    record = recorder.record(wall, {
        "rate_hz": rate_hz,
        "scenario": run.name,
        "feedforward": ctrl.feedforward.value,
        "plant_substeps": plant.substeps,
        "servo_link": f"can {bus.describe()}",
    }, pitches=applied)  # fmt: skip
    return CanFlight(record, commanded, sender_stats, endpoint_stats)
