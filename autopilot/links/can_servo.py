"""The autopilot's CAN servo output: one DroneCAN ArrayCommand per control tick.

:class:`CanServoSender` sends the four pitches (theta_m, theta_t, eps, eta [rad]) as one
``uavcan.equipment.actuator.ArrayCommand`` per ``send`` call, one
``COMMAND_TYPE_POSITION`` command per servo (actuator ids 1..4 by default), and a
``uavcan.protocol.NodeStatus`` once per ``status_period_s`` of the *given* time (1 Hz).
It reads no clock: the runner passes the tick time. A frame the bus refuses (full queue,
interface down, driver error) is counted, logged (at most once a second) and the rest of
that transfer is not sent (a receiver would drop a partial transfer anyway); the next
tick sends the next command. Encoding is dronecan's (see
:mod:`heli_sitl.links.dronecan_codec`); python-can is driven directly because
dronecan 1.0.27's own python-can driver does not work with python-can >= 4.4.

:func:`fly_over_can` closes the loop in one process over a CAN bus (python-can
``virtual`` by default): each tick ``controller.update`` -> ``sender.send`` -> bus ->
``endpoint.poll`` -> ``plant.set_pitches(held)`` -> ``plant.step``. Its record holds
the pitches the plant actually applied (float16-quantised), and the commanded ones.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from autopilot.metrics import FlightRecord
from autopilot.scenario import Scenario
from autopilot.tlc.controller import TLController
from heli_sitl.closing import Closing
from heli_sitl.links.can_bus import (
    CanBus,
    CanBusConfig,
    CanSendError,
    open_bus,
)
from heli_sitl.links.can_servo import DEFAULT_TIMEOUT_S, CanServoEndpoint
from heli_sitl.links.dronecan_codec import (
    DEFAULT_ACTUATOR_IDS,
    HEALTH_OK,
    HEALTH_WARNING,
    MODE_OPERATIONAL,
    ArrayCommandEncoder,
    CanFrame,
    NodeStatusEncoder,
)
from heli_sitl.plant import Plant
from heli_sitl.ratelog import RateLimitedLog
from heli_sitl.state import N_PITCH, FloatArray

log = logging.getLogger(__name__)

#: ArduPilot's default node id for the autopilot; any 1..127 works
DEFAULT_NODE_ID = 10
#: frames read and discarded per send, so a shared bus cannot grow this node's receive
#: queue without bound (the sender listens to nobody; on udp_multicast it hears itself)
RX_DRAIN_PER_SEND = 16

SENDER_STAT_KEYS = (
    "commands_sent",  # ArrayCommand transfers fully sent
    "frames_sent",
    "send_errors",  # ArrayCommand transfers cut short by a bus error
    "node_status_sent",
    "node_status_errors",
    "nonfinite_sent",  # commands with a NaN/inf value (the servo side refuses them)
    "rx_discarded",  # frames drained from this node's own receive queue
    "rx_errors",
)


class CanServoSender(Closing):
    """DroneCAN servo output; ``send(pitches_rad, t_s)`` once per control tick.

    ``bus`` is a config or spec string (opened here, closed by ``close``) or an open
    :class:`CanBus` (left to its owner).
    """

    def __init__(
        self,
        bus: CanBus | CanBusConfig | str,
        *,
        node_id: int = DEFAULT_NODE_ID,
        actuator_ids: Sequence[int] = DEFAULT_ACTUATOR_IDS,
        status_period_s: float = 1.0,
        start_s: float | None = None,
        log_interval_s: float = 1.0,
    ) -> None:
        if len(actuator_ids) != N_PITCH:
            raise ValueError(f"need {N_PITCH} actuator ids (theta_m, theta_t, eps, eta)")
        if not (math.isfinite(status_period_s) and status_period_s > 0.0):
            raise ValueError("status_period_s must be a positive number")
        self.commands = ArrayCommandEncoder(node_id, actuator_ids)
        self.status = NodeStatusEncoder(node_id)
        self.node_id = node_id
        self.actuator_ids = self.commands.actuator_ids
        self.status_period_s = float(status_period_s)
        self.start_s = start_s  # uptime origin; the first send's time if None
        self.stats: dict[str, int] = dict.fromkeys(SENDER_STAT_KEYS, 0)
        self._next_status_s: float | None = None
        self._errors_since_status = 0
        self._log = RateLimitedLog(log, log_interval_s)
        self._owns_bus = not isinstance(bus, CanBus)
        self.bus = bus if isinstance(bus, CanBus) else open_bus(bus)

    def send(self, pitches_rad: npt.ArrayLike, t_s: float) -> bool:
        """Send this tick's pitches [rad] (and NodeStatus when due); True if all of the
        command's frames went out. Never raises on a bus fault."""
        u = np.asarray(pitches_rad, dtype=float).reshape(-1)
        if u.shape != (N_PITCH,):
            raise ValueError(f"need {N_PITCH} pitches, got shape {np.shape(pitches_rad)}")
        if self.start_s is None:
            self.start_s = t_s
        self._drain(t_s)
        if not np.all(np.isfinite(u)):
            self.stats["nonfinite_sent"] += 1
            self._log(
                logging.WARNING, "nonfinite", t_s,
                "CAN servo out: non-finite pitches %s sent; the servos will refuse them",
                u.tolist(),
            )  # fmt: skip
        ok = self._send_frames(
            self.commands.encode(u.tolist()), "ArrayCommand", "send_errors", t_s
        )
        if ok:
            self.stats["commands_sent"] += 1
        else:
            self._errors_since_status += 1
        if self._next_status_s is None or t_s >= self._next_status_s:
            self._send_status(t_s)
        return ok

    def close(self) -> None:
        if self._owns_bus:
            self.bus.close()



    def _send_status(self, t_s: float) -> None:
        # uptime counts from start_s; health shows whether commands failed since the last one
        uptime_s = int(t_s - (self.start_s if self.start_s is not None else t_s))
        health = HEALTH_WARNING if self._errors_since_status else HEALTH_OK
        frames = self.status.encode(uptime_s, health=health, mode=MODE_OPERATIONAL)
        if self._send_frames(frames, "NodeStatus", "node_status_errors", t_s):
            self.stats["node_status_sent"] += 1
        self._errors_since_status = 0
        prev = self._next_status_s if self._next_status_s is not None else t_s
        nxt = prev + self.status_period_s
        # after a gap in time (a paused runner) restart the 1 Hz grid instead of bursting
        self._next_status_s = nxt if nxt > t_s else t_s + self.status_period_s

    def _send_frames(self, frames: list[CanFrame], what: str, error_key: str, t_s: float) -> bool:
        for f in frames:
            try:
                self.bus.send(f.can_id, f.data)
            except CanSendError as exc:
                self.stats[error_key] += 1
                self._log(
                    logging.ERROR, error_key, t_s,
                    "CAN servo out: %s send failed at t=%.3f s (%s); transfer dropped; %d so far",
                    what, t_s, exc, self.stats[error_key],
                )  # fmt: skip
                return False
            self.stats["frames_sent"] += 1
        return True

    def _drain(self, t_s: float) -> None:
        for _ in range(RX_DRAIN_PER_SEND):
            try:
                msg = self.bus.recv(0.0)
            except Exception as exc:
                # a receive fault must not stop the output; it is counted and logged
                self.stats["rx_errors"] += 1
                self._log(logging.WARNING, "rx", t_s, "CAN servo out: receive failed: %s", exc)
                return
            if msg is None:
                return
            self.stats["rx_discarded"] += 1


# ----------------------------------------------------------------- in-process closed loop


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
    pitches it received while it integrates to t + dt (as :func:`autopilot.closed_loop.
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
