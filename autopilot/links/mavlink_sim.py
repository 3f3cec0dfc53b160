"""The autopilot's end of the sim link: plant state in (NED/FRD -> NWU/FLU), pitches out."""

from __future__ import annotations

from heli_sitl.mavlink_link import Address, MavlinkUdp
from heli_sitl.sim_protocol import StateAssembler, StateSample, command_message
from heli_sitl.state import FloatArray


class SimLink:
    def __init__(self, local: Address, plant: Address, limits: FloatArray) -> None:
        self.udp = MavlinkUdp(local, plant, system_id=1, component_id=1, accept_system=1)
        self.limits = limits
        self.assembler = StateAssembler()

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        """The newest complete state queued (waiting up to ``timeout_s`` for one)."""
        newest: StateSample | None = None
        for msg, _ in self.udp.recv(timeout_s, spin_s):
            s = self.assembler.feed(msg)
            if s is not None:
                newest = s
        return newest

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        self.udp.send(command_message(t_us, pitches_rad, self.limits, armed))

    def close(self) -> None:
        self.udp.close()

    def __enter__(self) -> SimLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
