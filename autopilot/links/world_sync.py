"""The world's live knobs, forwarded: a SIM_ parameter a ground station sets on the
autopilot goes to the plant (component 51) as a PARAM_SET on the sim link, at the start
of the next control tick, before that tick's command, so the plant's next step flies it.

The autopilot's table is what ground stations read, so both processes must start from the
same world (the launchers give both the same ``--world``). Only changes are sent, each on
:data:`REPEATS` consecutive ticks (the plant ignores a value it already has), so a lost
datagram does not lose a setting and a plant's own world is never overwritten unasked.
"""

from __future__ import annotations

from autopilot.params_table import ParamTable
from heli_common.state import FloatArray
from heli_common.wire.mavlink.udp import MavlinkUdp, mavlink2

PLANT_COMPONENT = 51
REPEATS = 3


class WorldSync:
    """A TickService: sends the table's changed SIM_ values to the plant."""

    def __init__(self, table: ParamTable, link: MavlinkUdp, plant_system: int = 1) -> None:
        self.table = table
        self.link = link
        self.plant_system = plant_system
        self._known = table.sim_values()  # what the plant started with
        self._generation = table.generation
        self._pending: dict[str, int] = {}  # name -> sends left
        self.sent = 0

    def at_tick_start(self, t_s: float, x: FloatArray) -> None:
        # every tick: only a look at the table's generation unless something changed
        if self.table.generation != self._generation:
            self._generation = self.table.generation
            for name, v in self.table.sim_values().items():
                if v != self._known[name]:
                    self._known[name] = v
                    self._pending[name] = REPEATS
        if not self._pending:
            return
        values = self._known
        for name in list(self._pending):
            msg = mavlink2.MAVLink_param_set_message(
                self.plant_system, PLANT_COMPONENT, name.encode("ascii"), values[name],
                mavlink2.MAV_PARAM_TYPE_REAL32,
            )  # fmt: skip
            self.link.send(msg)
            self.sent += 1
            self._pending[name] -= 1
            if self._pending[name] == 0:
                del self._pending[name]

    def after_tick(self, *args: object) -> None:
        pass

    def between_ticks(self, t_s: float, x: FloatArray) -> None:
        pass

    def warm_up(self, x: FloatArray) -> None:
        pass
