"""The plant's CAN servo input: DroneCAN ArrayCommand in, held pitches out.

The endpoint stands for the four pitch servos on the bus. ``poll(now_s)`` drains the bus,
reassembles and checks every transfer (:mod:`heli_common.wire.can.dronecan_codec`) and
returns the pitches held now, in the order theta_m, theta_t, eps, eta [rad] (None until
the first valid command). The caller hands them to ``Plant.set_pitches``.

What reaches a servo, and what does not (every refusal is counted in ``stats`` and
logged, at most once a second per kind; the previous pitches stay held):

* Only ``uavcan.equipment.actuator.ArrayCommand`` (1010) from the configured source node
  (any node if ``source_node_id`` is None) is applied; ``NodeStatus`` is tracked in
  ``autopilot_status``; other types are counted as foreign and ignored.
* A transfer with a lost, repeated or reordered frame (tail byte start/end/toggle/transfer
  id), a wrong transfer CRC, or a payload dronecan cannot decode is dropped.
* The four servos move together: a transfer is applied only if it carries exactly one
  ``COMMAND_TYPE_POSITION`` command for each of the four configured actuator ids.
  Commands for other actuator ids are normal on a shared bus (other actuators); they are
  ignored and counted as ``unknown_actuator``. Four commands are 16 bytes, never a single
  frame, so every applied command has passed the transfer CRC (single-frame DroneCAN
  transfers carry none; a corrupted end flag can make one out of a first frame, and that
  can never hold four commands).
* A non-finite value refuses the whole transfer (as ``heli_plant.model.accept_pitches``).
* A transfer received again (the same source and transfer id within
  :data:`TRANSFER_ID_TIMEOUT_S`: the lockstep autopilot re-sending its answer to a state the
  plant re-sent) is dropped (``repeated_transfer``): a command carries no time stamp, and
  applied again it would become the next tick's command.
* Limits: a value beyond a servo limit by more than one float16 step at that limit
  (~6e-4 rad at 0.6 rad) refuses the whole transfer (``out_of_limits``): the sender's
  limits differ from the plant's, or it is faulty, and a silently clipped command would
  hide that. A value past the limit by less than that is float16 rounding of a command
  the controller itself saturated at the limit (0.6 rad becomes 0.60009765625); it is
  clipped to the limit (``clipped`` counts it) through ``accept_pitches``, the same gate
  as the MAVLink path.

Timeout: ``silent(now_s)`` is True when no command was applied in the last ``timeout_s``
(counted from the first poll when none has been). Refused transfers do not keep the link
alive: a stream of bad commands leaves the servos as stale as silence does. The endpoint
keeps holding the last pitches, as the MAVLink path does; what to do about a silent link
is the plant process's decision. Each entry into silence is counted (``timeouts``) and
logged, as is the recovery.

The servos are a DroneCAN node too (``node_id``, 20 by default; None: a silent
listener), as the field's tools expect of one (:mod:`heli_common.wire.can.node`): at the
end of each ``poll`` it sends ``uavcan.protocol.NodeStatus`` when one is due (1 Hz of
``now_s``; health WARNING while the command stream is silent), and
``uavcan.equipment.actuator.Status`` for each servo every ``actuator_status_period_s``
(10 Hz of ``now_s``): ``actuator_id``, ``position`` = the pitch the servo holds [rad]
(the last command applied; NaN before the first), ``force`` and ``speed`` NaN and
``power_rating_pct`` 127 (unknown: the plant's servo model, when a world has one, is
not read here, so the lag of ``--world servos-*`` is not in the feedback). It answers
``uavcan.protocol.GetNodeInfo`` (name ``org.heli-tlc-sitl.servos``) in the poll that
reads the request. Frames from its own node id (a bus that loops them back) are skipped.
What it sends and skips is counted in ``node_stats``, apart from ``stats`` (the command
path's). A send the bus refuses is counted and logged, never raised.

No clock is read for any decision: times come in as ``now_s``. Only ``poll(wait_s=...)``
reads the monotonic clock, to bound how long it blocks waiting for a command.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

import can
import numpy as np

from heli_common.closing import Closing
from heli_common.ratelog import RateLimitedLog
from heli_common.state import N_PITCH, PITCH_NAMES, FloatArray
from heli_common.vehicle.airframe import PitchLimits
from heli_common.wire.can.bus import CanBus, CanBusConfig, CanBusError, CanSendError, open_bus
from heli_common.wire.can.dronecan_codec import (
    ARMING_STATUS_DTID,
    ARMING_STATUS_FULL,
    ARRAY_COMMAND_DTID,
    COMMAND_TYPE_POSITION,
    DEFAULT_ACTUATOR_IDS,
    HEALTH_OK,
    HEALTH_WARNING,
    MODE_OPERATIONAL,
    NODE_STATUS_DTID,
    CanFrame,
    DropReason,
    NodeStatusEncoder,
    Reassembler,
    ReceivedTransfer,
    array_command_entries,
    check_actuator_ids,
    check_node_id,
)
from heli_common.wire.can.node import (
    ActuatorStatusEncoder,
    NodeIdentity,
    NodeInfoResponder,
    frame_source,
    get_node_info_request,
    project_version,
)
from heli_plant.model import accept_pitches

log = logging.getLogger(__name__)

#: ten control periods at 100 Hz
DEFAULT_TIMEOUT_S = 0.1
LOCKSTEP_SPIN_S = 0.002  # a lockstep wait polls this long before it sleeps
#: one float16 step (2**-10 relative): the margin past a limit still taken as rounding
LIMIT_TOLERANCE_REL = 2.0**-10
#: the servos' node id (the autopilot's is 10) and name
DEFAULT_PLANT_NODE_ID = 20
SERVOS_NODE_NAME = "org.heli-tlc-sitl.servos"
NODE_STATUS_PERIOD_S = 1.0
#: a transfer id seen again from the same source within this long is the same transfer
#: (libcanard's TRANSFER_TIMEOUT_USEC, 2 s); later, 32 transfers on, it is a new one
TRANSFER_ID_TIMEOUT_S = 2.0
#: uavcan.equipment.actuator.Status per servo: 10 Hz, 8 frames (4 servos x 2) a publication
ACTUATOR_STATUS_PERIOD_S = 0.1

NODE_STAT_KEYS = (
    "own_frames",  # frames of this node's id read back from the bus: skipped
    "node_status_sent",
    "actuator_status_sent",  # publications (one Status per servo each)
    "node_info_answered",
    "send_errors",  # transfers of this node the bus refused (cut short)
)

STAT_KEYS = (
    "frames_rx",  # CAN frames read from the bus
    "transfers_rx",  # complete, checked transfers of a handled type
    "commands_applied",  # ArrayCommands that set the held pitches
    "node_status_rx",
    "arming_status_rx",
    "clipped",  # applied, with a value within float16 rounding past a limit
    *(r.value for r in DropReason),  # frame/transfer-level drops (see DropReason)
    "foreign_source",  # ArrayCommand from another node than source_node_id
    "repeated_transfer",  # an ArrayCommand transfer received again (same source and transfer id)
    "unknown_actuator",  # commands (not transfers) for actuator ids not ours: ignored
    "missing_actuator",  # transfers without a command for one of our servos
    "duplicate_actuator",
    "wrong_command_type",  # not COMMAND_TYPE_POSITION
    "nonfinite",
    "out_of_limits",
    "bus_errors",  # the bus raised on receive
    "poll_frame_limit",  # polls that stopped at max_frames_per_poll with frames left
    "timeouts",  # entries into silence
)


@dataclass(frozen=True)
class NodeStatusInfo:
    source_node_id: int
    uptime_s: int
    health: int
    mode: int
    vendor_status: int
    received_s: float


class CanServoEndpoint(Closing):
    """Plant-side DroneCAN servo input; see the module doc for what is applied.

    ``bus`` is a config or spec string (the endpoint opens the bus and closes it on
    ``close``) or an open :class:`CanBus` (left to its owner).
    """

    def __init__(
        self,
        bus: CanBus | CanBusConfig | str,
        *,
        limits: PitchLimits,
        actuator_ids: Sequence[int] = DEFAULT_ACTUATOR_IDS,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        source_node_id: int | None = None,
        max_frames_per_poll: int = 1000,
        log_interval_s: float = 1.0,
        node_id: int | None = DEFAULT_PLANT_NODE_ID,
        actuator_status_period_s: float = ACTUATOR_STATUS_PERIOD_S,
    ) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0.0):
            raise ValueError(f"timeout_s must be a positive number, got {timeout_s}")
        if max_frames_per_poll < 1:
            raise ValueError("max_frames_per_poll must be >= 1")
        self.actuator_ids = check_actuator_ids(actuator_ids, N_PITCH)
        self._index = {aid: i for i, aid in enumerate(self.actuator_ids)}
        self.source_node_id = None if source_node_id is None else check_node_id(source_node_id)
        self.timeout_s = float(timeout_s)
        self.max_frames_per_poll = max_frames_per_poll
        self.lo = np.array([lim[0] for lim in limits.as_tuple()], dtype=float)
        self.hi = np.array([lim[1] for lim in limits.as_tuple()], dtype=float)
        self.tol_lo = np.abs(self.lo) * LIMIT_TOLERANCE_REL
        self.tol_hi = np.abs(self.hi) * LIMIT_TOLERANCE_REL

        self.held: FloatArray | None = None
        self.last_accept_s: float | None = None
        self.first_poll_s: float | None = None
        self.autopilot_status: NodeStatusInfo | None = None
        self.stats: dict[str, int] = dict.fromkeys(STAT_KEYS, 0)
        self._silent = False
        self._now_s = 0.0
        self._log = RateLimitedLog(log, log_interval_s)
        self._reassembler = Reassembler((ARRAY_COMMAND_DTID, NODE_STATUS_DTID, ARMING_STATUS_DTID),
                                        self._on_drop)  # fmt: skip
        self.armed = False  # the autopilot's latest uavcan.equipment.safety.ArmingStatus
        # the last ArrayCommand transfer (source node, transfer id, when): a repeat is dropped
        self._last_command: tuple[int, int, float] | None = None

        if not (math.isfinite(actuator_status_period_s) and actuator_status_period_s > 0.0):
            raise ValueError("actuator_status_period_s must be a positive number")
        self.node_id = None if node_id is None else check_node_id(node_id)
        if self.node_id is not None and self.node_id == self.source_node_id:
            raise ValueError(f"the servos' node id {node_id} is the autopilot's (source_node_id)")
        self.node_stats: dict[str, int] = dict.fromkeys(NODE_STAT_KEYS, 0)
        self.actuator_status_period_s = float(actuator_status_period_s)
        self._next_node_status_s: float | None = None
        self._next_actuator_status_s: float | None = None
        if self.node_id is not None:
            self._node_status = NodeStatusEncoder(self.node_id)
            self._actuator_status = ActuatorStatusEncoder(self.node_id)
            identity = NodeIdentity(SERVOS_NODE_NAME, project_version())
            self.node_info = NodeInfoResponder(self.node_id, identity)

        # load (or compile) the numba gate now: the first command must not stall the
        # receiver for seconds while frames pile up in the bus's queue
        accept_pitches(np.zeros(N_PITCH), self.lo, self.hi, np.zeros(N_PITCH))

        self._owns_bus = not isinstance(bus, CanBus)
        self.bus = bus if isinstance(bus, CanBus) else open_bus(bus)

    # --------------------------------------------------------------------- public API

    def poll(self, now_s: float, *, wait_s: float = 0.0) -> FloatArray | None:
        """Read every frame waiting (at most ``max_frames_per_poll``), apply the valid
        commands, update the timeout; return a copy of the held pitches [rad] or None if no
        command was ever applied. With ``wait_s`` > 0, block up to that long for a command
        (lockstep use across processes); ``now_s`` is still the time stamp used."""
        self._now_s = now_s
        if self.first_poll_s is None:
            self.first_poll_s = now_s
        applied0 = self.stats["commands_applied"]
        start = time.monotonic()
        deadline = start + max(wait_s, 0.0)
        # while waiting, poll without sleeping for a short while first: the three frames of
        # a command arrive tens of microseconds apart, and a process put to sleep between
        # them pays a scheduler wake-up per frame
        spin_until = start + min(wait_s, LOCKSTEP_SPIN_S)
        frames = 0
        while frames < self.max_frames_per_poll:
            timeout_s = 0.0
            waiting = wait_s > 0.0 and self.stats["commands_applied"] == applied0
            if waiting:
                now = time.monotonic()
                if now >= deadline:
                    waiting = False
                elif now >= spin_until:
                    timeout_s = deadline - now
            try:
                msg = self.bus.recv(timeout_s)
            except CanBusError as exc:
                self.stats["bus_errors"] += 1
                self._log(
                    logging.ERROR, "bus_error", now_s,
                    "CAN servo: receive failed (%s); %d bus errors so far",
                    exc, self.stats["bus_errors"],
                )  # fmt: skip
                break
            if msg is None:
                if waiting:
                    if timeout_s == 0.0:  # spinning: let a process waiting for this core run
                        os.sched_yield()
                    continue
                break
            frames += 1
            if self.node_id is not None and msg.is_extended_id and self._node_frame(msg, now_s):
                continue
            self.stats["frames_rx"] += 1
            received = self._reassembler.feed_message(msg)
            if received is not None:
                self._handle(received, now_s)
        else:
            self.stats["poll_frame_limit"] += 1
            self._log(
                logging.WARNING, "poll_frame_limit", now_s,
                "CAN servo: more than %d frames waiting in one poll; the rest wait for the next",
                self.max_frames_per_poll,
            )  # fmt: skip
        self._update_silence(now_s)
        if self.node_id is not None:
            self._publish(now_s)
        return None if self.held is None else self.held.copy()

    def silent(self, now_s: float) -> bool:
        """No command applied in the last ``timeout_s`` (from the first poll if none yet)."""
        ref = self.last_accept_s if self.last_accept_s is not None else self.first_poll_s
        return ref is not None and now_s - ref > self.timeout_s

    def close(self) -> None:
        if self._owns_bus:
            self.bus.close()

    # --------------------------------------------------------------------- the node

    def _node_frame(self, msg: can.Message, now_s: float) -> bool:
        """Handle a frame that is this node's business: True if it was (its own frame read
        back, a GetNodeInfo request for it), False for the command path."""
        can_id = msg.arbitration_id
        if frame_source(can_id) == self.node_id:
            self.node_stats["own_frames"] += 1
            return True
        assert self.node_id is not None
        req = get_node_info_request(can_id, bytes(msg.data), self.node_id)
        if req is None:
            return False
        self.stats["frames_rx"] += 1
        frames = self.node_info.respond(req, self._uptime_s(now_s), health=self._health(now_s))
        if self._send_node(frames, "GetNodeInfo response", now_s):
            self.node_stats["node_info_answered"] += 1
        return True

    def _uptime_s(self, now_s: float) -> int:
        return int(now_s - (self.first_poll_s if self.first_poll_s is not None else now_s))

    def _health(self, now_s: float) -> int:
        return HEALTH_WARNING if self.silent(now_s) else HEALTH_OK

    def _publish(self, now_s: float) -> None:
        """NodeStatus and the servos' Status when due (grids of ``now_s`` that restart
        after a gap instead of bursting)."""
        if self._next_node_status_s is None or now_s >= self._next_node_status_s:
            frames = self._node_status.encode(self._uptime_s(now_s), health=self._health(now_s),
                                              mode=MODE_OPERATIONAL)  # fmt: skip
            if self._send_node(frames, "NodeStatus", now_s):
                self.node_stats["node_status_sent"] += 1
            self._next_node_status_s = _next_on_grid(self._next_node_status_s, now_s, NODE_STATUS_PERIOD_S)
        if self._next_actuator_status_s is None or now_s >= self._next_actuator_status_s:
            held = self.held if self.held is not None else np.full(N_PITCH, math.nan)
            frames = self._actuator_status.encode_all(self.actuator_ids, held.tolist())
            if self._send_node(frames, "actuator Status", now_s):
                self.node_stats["actuator_status_sent"] += 1
            self._next_actuator_status_s = _next_on_grid(
                self._next_actuator_status_s, now_s, self.actuator_status_period_s
            )

    def _send_node(self, frames: list[CanFrame], what: str, now_s: float) -> bool:
        for f in frames:
            try:
                self.bus.send(f.can_id, f.data)
            except CanSendError as exc:
                self.node_stats["send_errors"] += 1
                self._log(
                    logging.WARNING, "node_send", now_s,
                    "CAN servo node: %s not sent (%s); %d so far",
                    what, exc, self.node_stats["send_errors"],
                )  # fmt: skip
                return False
        return True

    # --------------------------------------------------------------------- internals

    def _on_drop(self, reason: DropReason, detail: str) -> None:
        self.stats[reason.value] += 1
        # a foreign type is ordinary traffic on a shared bus: worth a note, not a warning
        level = logging.INFO if reason is DropReason.FOREIGN_TYPE else logging.WARNING
        self._log(
            level, reason.value, self._now_s, "CAN servo: dropped (%s) %s; %d so far",
            reason.value, detail, self.stats[reason.value],
        )  # fmt: skip

    def _refuse(self, kind: str, detail: str, level: int = logging.WARNING) -> None:
        self.stats[kind] += 1
        self._log(
            level, kind, self._now_s,
            "CAN servo: command refused (%s) %s; holding %s; %d so far",
            kind, detail, self._held_text(), self.stats[kind],
        )  # fmt: skip

    def _held_text(self) -> str:
        if self.held is None:
            return "no pitches yet"
        return ", ".join(f"{n}={v:.4f}" for n, v in zip(PITCH_NAMES, self.held, strict=True))

    def _handle(self, tr: ReceivedTransfer, now_s: float) -> None:
        self.stats["transfers_rx"] += 1
        if tr.data_type_id == ARMING_STATUS_DTID:
            if self.source_node_id is None or tr.source_node_id == self.source_node_id:
                self.stats["arming_status_rx"] += 1
                self.armed = int(tr.payload.status) == ARMING_STATUS_FULL
            return
        if tr.data_type_id == NODE_STATUS_DTID:
            p = tr.payload
            self.stats["node_status_rx"] += 1
            if self.source_node_id is None or tr.source_node_id == self.source_node_id:
                self.autopilot_status = NodeStatusInfo(
                    tr.source_node_id, int(p.uptime_sec), int(p.health), int(p.mode),
                    int(p.vendor_specific_status_code), now_s,
                )  # fmt: skip
            return
        who = f"from node {tr.source_node_id}, transfer {tr.transfer_id}"
        if self.source_node_id is not None and tr.source_node_id != self.source_node_id:
            self._refuse("foreign_source", f"{who}: expected node {self.source_node_id}")
            return
        last = self._last_command
        if (last is not None and last[:2] == (tr.source_node_id, tr.transfer_id)
                and now_s - last[2] <= TRANSFER_ID_TIMEOUT_S):  # fmt: skip
            # the same transfer sent again (the lockstep autopilot answering a re-sent state):
            # this tick's command is already held, and a command carries no time stamp, so
            # applied again it would become the next tick's
            self.stats["repeated_transfer"] += 1
            return
        self._last_command = (tr.source_node_id, tr.transfer_id, now_s)
        values = np.full(N_PITCH, math.nan)
        seen = [False] * N_PITCH
        unknown: list[int] = []
        for aid, ctype, v in array_command_entries(tr.payload):
            i = self._index.get(aid)
            if i is None:
                unknown.append(aid)
                continue
            if ctype != COMMAND_TYPE_POSITION:
                self._refuse("wrong_command_type", f"{who}: actuator {aid} command type {ctype}")
                return
            if seen[i]:
                self._refuse("duplicate_actuator", f"{who}: actuator {aid} twice")
                return
            values[i], seen[i] = v, True
        if unknown:
            self.stats["unknown_actuator"] += len(unknown)
            self._log(
                logging.INFO, "unknown_actuator", now_s,
                "CAN servo: ignored commands for actuator ids %s (ours: %s); %d so far",
                unknown, list(self.actuator_ids), self.stats["unknown_actuator"],
            )  # fmt: skip
        if not all(seen):
            missing = [a for a, s in zip(self.actuator_ids, seen, strict=True) if not s]
            self._refuse("missing_actuator", f"{who}: no command for actuator ids {missing}")
            return
        if not np.all(np.isfinite(values)):
            self._refuse("nonfinite", f"{who}: values {values.tolist()}")
            return
        beyond = (values < self.lo - self.tol_lo) | (values > self.hi + self.tol_hi)
        if beyond.any():
            bad = ", ".join(
                f"{PITCH_NAMES[i]}={values[i]:.4f} not in [{self.lo[i]}, {self.hi[i]}]"
                for i in np.flatnonzero(beyond)
            )
            self._refuse("out_of_limits", f"{who}: {bad}")
            return
        held = np.zeros(N_PITCH) if self.held is None else self.held
        if not accept_pitches(values, self.lo, self.hi, held):  # unreachable: checked finite
            self._refuse("nonfinite", f"{who}: values {values.tolist()}")
            return
        if np.any((values < self.lo) | (values > self.hi)):
            self.stats["clipped"] += 1
        first = self.held is None
        self.held = held
        self.last_accept_s = now_s
        if first:
            log.info("CAN servo: first command applied, %s: %s", who, self._held_text())
        self.stats["commands_applied"] += 1

    def _update_silence(self, now_s: float) -> None:
        silent = self.silent(now_s)
        if silent and not self._silent:
            self.stats["timeouts"] += 1
            since = self.last_accept_s if self.last_accept_s is not None else self.first_poll_s
            log.warning(
                "CAN servo: no valid command for %.3f s (timeout %.3f s: the autopilot has ended its "
                "flight, or the bus is down); holding %s",
                now_s - (since if since is not None else now_s), self.timeout_s,
                self._held_text(),
            )  # fmt: skip
        elif self._silent and not silent:
            log.info("CAN servo: valid commands again after a timeout")
        self._silent = silent


def _next_on_grid(prev: float | None, now_s: float, period_s: float) -> float:
    nxt = (prev if prev is not None else now_s) + period_s
    return nxt if nxt > now_s else now_s + period_s
