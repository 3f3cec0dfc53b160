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

from autopilot.links.can_servo import DEFAULT_NODE_ID, CanServoSender
from autopilot.metrics import FlightRecord
from autopilot.scenario import Scenario
from autopilot.tlc.controller import TLController
from heli_common.can.bus import CanBusConfig
from heli_common.can.dronecan_codec import DEFAULT_ACTUATOR_IDS
from heli_common.state import N_PITCH, FloatArray
from heli_sitl.plant.can_endpoint import DEFAULT_TIMEOUT_S, CanServoEndpoint
from heli_sitl.plant.model import Plant


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

    Tick k is at t = k / rate; the controller sees the state at t, the plant holds the
    pitches it received while it integrates to t + dt (as :func:`heli_sitl.closed_loop.
    simulate`, but through the sender, the bus and the servo endpoint). ``on_tick(k, t)``
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
    n = round(duration * rate_hz)
    t = np.arange(n + 1) / rate_hz
    refs = scenario.trajectory.sample(t)
    xs = np.empty((n + 1, plant.x.size))
    applied = np.empty((n + 1, N_PITCH))
    commanded = np.empty((n + 1, N_PITCH))
    diags = np.empty((n + 1, ctrl.diag.size))
    dt = 1.0 / rate_hz
    # both ends open their own bus on the channel, as two nodes would
    with CanServoEndpoint(
        bus, limits=scenario.airframe.limits, actuator_ids=actuator_ids, timeout_s=timeout_s
    ) as endpoint, CanServoSender(bus, node_id=node_id, actuator_ids=actuator_ids) as sender:
        wall0 = time.perf_counter()
        for k in range(n + 1):
            tk = float(t[k])
            xs[k] = plant.x
            commanded[k] = ctrl.update(tk, plant.x, refs[k])
            diags[k] = ctrl.diag
            sender.send(commanded[k], tk)
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
    record = FlightRecord.from_ticks(
        t, xs, refs, applied, diags, wall,
        {
            "rate_hz": rate_hz,
            "feedforward": ctrl.feedforward.value,
            "plant_substeps": plant.substeps,
            "servo_link": f"can {bus.describe()}",
        },
    )  # fmt: skip
    return CanFlight(record, commanded, sender_stats, endpoint_stats)
