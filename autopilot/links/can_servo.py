"""The autopilot's CAN servo output: one DroneCAN ArrayCommand per control tick.

:class:`CanServoSender` sends the four pitches (theta_m, theta_t, eps, eta [rad]) as one
``uavcan.equipment.actuator.ArrayCommand`` per ``send`` call, one
``COMMAND_TYPE_POSITION`` command per servo (actuator ids 1..4 by default), and a
``uavcan.protocol.NodeStatus`` once per ``status_period_s`` of the *given* time (1 Hz),
and answers ``uavcan.protocol.GetNodeInfo`` (name ``org.heli-tlc-sitl.autopilot``, the
project's version, a unique id: :mod:`heli_common.wire.can.node`), so the DroneCAN GUI
tool and ArduPilot list it as a node. Requests are read on each ``send``, at most
``RX_PER_SEND`` frames (every frame waiting, at a tick's traffic): a request is answered
in the tick it arrives. Not on ``udp_multicast``, where this node hears its own three
frames a tick and reading them back (msgpack) would cost more than sending them: that bus
is no DroneCAN tool's anyway (``mcast:N`` is). It reads no clock: the runner passes the
tick time. A frame the bus refuses (full queue,
interface down, driver error) is counted, logged (at most once a second) and the rest of
that transfer is not sent (a receiver would drop a partial transfer anyway); the next
tick sends the next command. Encoding is dronecan's (see
:mod:`heli_common.wire.can.dronecan_codec`); python-can is driven directly because
dronecan 1.0.27's own python-can driver does not work with python-can >= 4.4.

A command re-sent (:meth:`CanServoSender.repeat`; the lockstep runner answers a state the
plant re-sent, its answer having been lost or late) goes out as the same transfer, its
frames and transfer id unchanged: DroneCAN numbers each source's transfers of a data type
0..31, so a receiver tells a repeated transfer from the next command (the plant drops it,
:mod:`heli_plant.can_endpoint`). An ArrayCommand carries no time stamp: a repeat sent as
a new transfer would be applied to the plant's next tick, and the lockstep flight would run
a tick behind from there on.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from heli_common.closing import Closing
from heli_common.ratelog import RateLimitedLog
from heli_common.state import N_PITCH, FloatArray
from heli_common.wire.can.bus import (
    CanBus,
    CanBusConfig,
    CanSendError,
    open_bus,
)
from heli_common.wire.can.dronecan_codec import (
    DEFAULT_ACTUATOR_IDS,
    HEALTH_OK,
    HEALTH_WARNING,
    MODE_OPERATIONAL,
    ArmingStatusEncoder,
    ArrayCommandEncoder,
    CanFrame,
    NodeStatusEncoder,
)
from heli_common.wire.can.node import (
    NodeIdentity,
    NodeInfoResponder,
    get_node_info_request,
    project_version,
)

log = logging.getLogger(__name__)

#: ArduPilot's default node id for the autopilot; any 1..127 works
DEFAULT_NODE_ID = 10
#: frames read per send, for GetNodeInfo requests; the rest are discarded (a ``virtual``
#: bus's receive queue is unbounded: a shared bus must not grow it). A tick's traffic on
#: the bus is a few frames; the plant's servo status adds 80 a second.
RX_PER_SEND = 32
AUTOPILOT_NODE_NAME = "org.heli-tlc-sitl.autopilot"

SENDER_STAT_KEYS = (
    "commands_sent",  # ArrayCommand transfers fully sent
    "frames_sent",
    "send_errors",  # ArrayCommand transfers cut short by a bus error
    "node_status_sent",
    "node_status_errors",
    "nonfinite_sent",  # commands with a NaN/inf value (the servo side refuses them)
    "rx_discarded",  # frames drained from this node's own receive queue
    "rx_errors",
    "arming_status_sent",  # uavcan.equipment.safety.ArmingStatus, on change and at 2 Hz
    "node_info_answered",  # uavcan.protocol.GetNodeInfo requests answered
    "node_info_errors",  # answers cut short by a bus error
    "commands_repeated",  # the last ArrayCommand transfer sent again, same transfer id
)
ARMING_STATUS_PERIOD_S = 0.5


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
        self.arming = ArmingStatusEncoder(node_id)
        self._armed_sent: bool | None = None
        self._next_arming_s = -math.inf
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
        self._listens = self.bus.config.interface != "udp_multicast"
        self.identity = NodeIdentity(AUTOPILOT_NODE_NAME, project_version())
        self.node_info = NodeInfoResponder(node_id, self.identity)
        self._health = HEALTH_OK
        self._last_command: list[CanFrame] = []  # the frames of the last ArrayCommand sent

    def send(self, pitches_rad: npt.ArrayLike, t_s: float, armed: bool | None = None) -> bool:
        """Send this tick's pitches [rad] (and NodeStatus when due; ArmingStatus, when
        ``armed`` is given, before the command whenever it changes and at 2 Hz); True if
        all of the command's frames went out. Never raises on a bus fault."""
        u = np.asarray(pitches_rad, dtype=float).reshape(-1)
        if u.shape != (N_PITCH,):
            raise ValueError(f"need {N_PITCH} pitches, got shape {np.shape(pitches_rad)}")
        if self.start_s is None:
            self.start_s = t_s
        if self._listens:
            self._listen(t_s)
        if armed is not None and (armed != self._armed_sent or t_s >= self._next_arming_s):
            if self._send_frames(self.arming.encode(armed), "ArmingStatus", "send_errors", t_s):
                self.stats["arming_status_sent"] += 1
                self._armed_sent = armed
            self._next_arming_s = t_s + ARMING_STATUS_PERIOD_S
        if not np.all(np.isfinite(u)):
            self.stats["nonfinite_sent"] += 1
            self._log(
                logging.WARNING, "nonfinite", t_s,
                "CAN servo out: non-finite pitches %s sent; the servos will refuse them",
                u.tolist(),
            )  # fmt: skip
        self._last_command = self.commands.encode(u.tolist())
        ok = self._send_frames(self._last_command, "ArrayCommand", "send_errors", t_s)
        if ok:
            self.stats["commands_sent"] += 1
        else:
            self._errors_since_status += 1
        if self._next_status_s is None or t_s >= self._next_status_s:
            self._send_status(t_s)
        return ok

    def repeat(self, t_s: float) -> bool:
        """Send the last ArrayCommand again as the same transfer (its transfer id unchanged:
        a receiver that has it drops the repeat); True if all its frames went out."""
        if not self._last_command:
            return False
        ok = self._send_frames(self._last_command, "ArrayCommand", "send_errors", t_s)
        if ok:
            self.stats["commands_repeated"] += 1
        return ok

    def close(self) -> None:
        if self._owns_bus:
            self.bus.close()

    def _send_status(self, t_s: float) -> None:
        # uptime counts from start_s; health shows whether commands failed since the last one
        uptime_s = int(t_s - (self.start_s if self.start_s is not None else t_s))
        health = HEALTH_WARNING if self._errors_since_status else HEALTH_OK
        self._health = health
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

    def _listen(self, t_s: float) -> None:
        """Answer the GetNodeInfo requests waiting; discard every other frame."""
        for _ in range(RX_PER_SEND):
            try:
                msg = self.bus.recv(0.0)
            except Exception as exc:
                # a receive fault must not stop the output; it is counted and logged
                self.stats["rx_errors"] += 1
                self._log(logging.WARNING, "rx", t_s, "CAN servo out: receive failed: %s", exc)
                return
            if msg is None:
                return
            req = None
            if msg.is_extended_id and not msg.is_remote_frame and not msg.is_error_frame:
                req = get_node_info_request(msg.arbitration_id, bytes(msg.data), self.node_id)
            if req is None:
                self.stats["rx_discarded"] += 1
                continue
            uptime_s = int(t_s - (self.start_s if self.start_s is not None else t_s))
            frames = self.node_info.respond(req, uptime_s, health=self._health, mode=MODE_OPERATIONAL)
            if self._send_frames(frames, "GetNodeInfo response", "node_info_errors", t_s):
                self.stats["node_info_answered"] += 1


class CanServoOutput:
    """The runner's :class:`heli_common.wire.links.ServoOutput` over DroneCAN: the pitches of
    each tick, stamped with its time, and the arming state as DroneCAN ArmingStatus."""

    def __init__(self, sender: CanServoSender) -> None:
        self.sender = sender
        self._last: tuple[int, tuple[float, ...], bool] | None = None

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        """A new command, or, for the tick's own command sent again (the same time, pitches
        and arming: the lockstep runner answering a re-sent state), the same transfer."""
        this = (t_us, tuple(np.asarray(pitches_rad, dtype=float).reshape(-1).tolist()), armed)
        if this == self._last and self.sender.repeat(t_us / 1e6):
            return
        self._last = this
        self.sender.send(pitches_rad, t_us / 1e6, armed=armed)
