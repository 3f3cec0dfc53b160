"""The plant's servo inputs: HIL_ACTUATOR_CONTROLS on the MAVLink sim link, or DroneCAN.

Both meet :class:`heli_common.wire.links.ServoInput`, so the plant server never branches on
the medium.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from heli_common.state import FloatArray
from heli_common.wire.links import ServoCommand
from heli_common.wire.mavlink.fast import HilActuatorControls, ParamSet, SimCodec
from heli_common.wire.mavlink.sim_protocol import MAV_MODE_FLAG_SAFETY_ARMED, decode_command, receive
from heli_common.wire.mavlink.udp import MavlinkUdp
from heli_common.wire.servo_map import ServoMap

if TYPE_CHECKING:  # python-can and dronecan's DSDL cost a plant on MAVLink 0.3 s to import
    from heli_plant.can_endpoint import CanServoEndpoint

# the endpoint's counts of whole commands it refused
REFUSAL_KEYS = ("missing_actuator", "duplicate_actuator", "wrong_command_type", "nonfinite", "out_of_limits")
LOCKSTEP_SPIN_S = 0.002  # poll this long before sleeping (see MavlinkUdp.wait)


Setting = Callable[[str, float], None]


class MavlinkServoInput:
    """HIL_ACTUATOR_CONTROLS: time-stamped, with the arming flag in ``mode``. A PARAM_SET
    for this component on the same link is a world setting, handed to ``on_setting`` in
    the order it came (before a command that followed it)."""

    carries_arming = True

    def __init__(
        self,
        link: MavlinkUdp,
        codec: SimCodec,
        limits: FloatArray | ServoMap,
        on_setting: Setting | None = None,
    ) -> None:
        self.link = link
        self.codec = codec
        self.limits = limits
        self.on_setting = on_setting
        self._refused = 0

    @property
    def refused(self) -> int:
        return self._refused

    def receive(self, current_t_us: int, wait_s: float = 0.0) -> list[ServoCommand]:
        if wait_s > 0.0:
            self.link.wait(wait_s, spin_s=LOCKSTEP_SPIN_S)
        out = []
        for msg in receive(self.link, self.codec):
            if isinstance(msg, ParamSet):
                if self.on_setting is not None and msg.target_component == self.codec.compid:
                    self.on_setting(msg.param_id, msg.param_value)
                continue
            if not isinstance(msg, HilActuatorControls):
                continue
            cmd = decode_command(msg, self.limits)
            if cmd is None:
                self._refused += 1
                continue
            t_us, pitches = cmd
            out.append(ServoCommand(t_us, pitches, bool(msg.mode & MAV_MODE_FLAG_SAFETY_ARMED)))
        return out


class CanServoInput:
    """DroneCAN ArrayCommand: no time stamp (a command answers the state last published);
    the arming state is the autopilot's latest ArmingStatus on the bus (it is sent before
    the command it qualifies)."""

    carries_arming = True

    def __init__(self, endpoint: CanServoEndpoint) -> None:
        self.endpoint = endpoint

    @property
    def refused(self) -> int:
        st = self.endpoint.stats
        return sum(st[k] for k in REFUSAL_KEYS)

    def receive(self, current_t_us: int, wait_s: float = 0.0) -> list[ServoCommand]:
        before = self.endpoint.stats["commands_applied"]
        held = self.endpoint.poll(time.monotonic(), wait_s=wait_s)
        if held is None or self.endpoint.stats["commands_applied"] == before:
            return []
        return [ServoCommand(current_t_us, held, self.endpoint.armed)]
