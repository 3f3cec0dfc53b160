"""What each wire mode (heli_common.wire.mavlink.modes) asks of the flight logic, and which wire
mode each flight mode is reported as."""

from __future__ import annotations

from collections.abc import Callable

from autopilot.flight import commands as c
from autopilot.flight.modes import Mode
from heli_common.wire.mavlink import modes as wm

COMMAND: dict[wm.WireMode, Callable[[], c.Command]] = {
    wm.HOLD: c.Hold, wm.MISSION: c.SelectMission, wm.RETURN: c.ReturnToLaunch, wm.LAND: c.Land,
    wm.TAKEOFF: c.Takeoff, wm.OFFBOARD: c.StartOffboard,
}  # fmt: skip
REPORTED: dict[Mode, wm.WireMode] = {
    Mode.IDLE: wm.HOLD, Mode.HOLD: wm.HOLD, Mode.AUTO: wm.MISSION, Mode.RTL: wm.RETURN,
    Mode.LAND: wm.LAND, Mode.GUIDED: wm.OFFBOARD, Mode.TAKEOFF: wm.TAKEOFF,
}  # fmt: skip
