"""The autopilot's end of the sim link: plant state in (NED/FRD -> NWU/FLU), pitches out."""

from __future__ import annotations

import dataclasses

from heli_common import frames, servo_map
from heli_common.closing import Closing
from heli_common.mavlink.fast import ActuatorOutputStatus, SimCodec, WindCov
from heli_common.mavlink.sim_protocol import MAV_MODE_FLAG_SAFETY_ARMED, StateAssembler, StateSample, receive
from heli_common.mavlink.udp import Address, MavlinkUdp
from heli_common.state import FloatArray


class SimLink(Closing):
    def __init__(self, local: Address, plant: Address, limits: FloatArray) -> None:
        self.udp = MavlinkUdp(local, plant, system_id=1, component_id=1, accept_system=1)
        self.codec = SimCodec(system_id=1, component_id=1)
        self.limits = limits
        self.assembler = StateAssembler()
        # the world's truth of the latest state (see StateSample), by its time stamp
        self._air: tuple[int, tuple[float, float, float]] | None = None
        self._servo: tuple[int, tuple[float, float, float, float]] | None = None

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        """The newest complete state queued (waiting up to ``timeout_s`` for one)."""
        newest: StateSample | None = None
        for msg in receive(self.udp, self.codec, timeout_s, spin_s):
            if isinstance(msg, WindCov):
                self._air = (msg.time_usec, frames.ned_to_nwu(msg.wind_ned_m_s))
                continue
            if isinstance(msg, ActuatorOutputStatus):
                a = msg.actuator
                self._servo = (msg.time_usec, (a[0], a[1], a[2], a[3]))
                continue
            s = self.assembler.feed(msg)
            if s is not None:
                newest = s
        if newest is not None and self._air is not None and self._air[0] == newest.t_us:
            servo = self._servo[1] if self._servo is not None and self._servo[0] == newest.t_us else None
            newest = dataclasses.replace(newest, air_nwu_m_s=self._air[1], servo_rad=servo)
        return newest

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        controls = [0.0] * 16
        controls[:4] = servo_map.to_normalized(pitches_rad, self.limits).tolist()
        mode = MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        self.udp.send_bytes(self.codec.encode_actuators(t_us, controls, mode))
        self.udp.stats.tx_messages += 1

    def close(self) -> None:
        self.udp.close()


