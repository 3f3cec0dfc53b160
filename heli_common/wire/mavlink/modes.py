"""The vehicle's flight modes on the wire: its own custom-mode numbers, the MAVLink standard
modes, and the names a ground station lists. Shared by the vehicle and the ground tools.

The custom-mode numbers are this vehicle's own, documented here; they use PX4's layout
(``custom_mode = main << 16 | sub << 24``) because MAVSDK decodes every non-ArduPilot
vehicle's HEARTBEAT that way (and stops streaming offboard setpoints unless it reads
OFFBOARD), but the vehicle reports MAV_AUTOPILOT_GENERIC: it does not claim to be PX4.
Ground stations reach the modes three ways, all served by the vehicle:

* MAV_CMD_DO_SET_MODE with param2 = main and param3 = sub (MAVSDK), or param2 = the whole
  custom mode (QGroundControl, from AVAILABLE_MODES; pymavlink/MAVProxy with the mode map
  in ``configs/pymavlink_custom_mode_map.json``), and the SET_MODE message;
* MAV_CMD_DO_SET_STANDARD_MODE with a MAV_STANDARD_MODE;
* AVAILABLE_MODES / CURRENT_MODE / AVAILABLE_MODES_MONITOR (the standard modes
  microservice) tell a ground station what exists and what is current.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import development as dev

from heli_common.wire.mavlink.udp import Message

MSG_ID_AVAILABLE_MODES: int = dev.MAVLINK_MSG_ID_AVAILABLE_MODES
MSG_ID_CURRENT_MODE: int = dev.MAVLINK_MSG_ID_CURRENT_MODE
MSG_ID_AVAILABLE_MODES_MONITOR: int = dev.MAVLINK_MSG_ID_AVAILABLE_MODES_MONITOR
CMD_DO_SET_STANDARD_MODE: int = dev.MAV_CMD_DO_SET_STANDARD_MODE


def custom_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


def main_sub(custom: int) -> tuple[int, int]:
    """custom_mode -> (main, sub) numbers."""
    return (custom >> 16) & 0xFF, (custom >> 24) & 0xFF


@dataclass(frozen=True)
class WireMode:
    name: str  # as a ground station lists it (at most 35 characters)
    custom_mode: int
    standard_mode: int  # MAV_STANDARD_MODE (0: none of the standard ones)


HOLD = WireMode("HOLD", custom_mode(4, 3), dev.MAV_STANDARD_MODE_POSITION_HOLD)
MISSION = WireMode("MISSION", custom_mode(4, 4), dev.MAV_STANDARD_MODE_MISSION)
RETURN = WireMode("RETURN", custom_mode(4, 5), dev.MAV_STANDARD_MODE_SAFE_RECOVERY)
LAND = WireMode("LAND", custom_mode(4, 6), dev.MAV_STANDARD_MODE_LAND)
TAKEOFF = WireMode("TAKEOFF", custom_mode(4, 2), dev.MAV_STANDARD_MODE_TAKEOFF)
OFFBOARD = WireMode("OFFBOARD", custom_mode(6, 0), dev.MAV_STANDARD_MODE_NON_STANDARD)
MODES: tuple[WireMode, ...] = (HOLD, MISSION, RETURN, LAND, TAKEOFF, OFFBOARD)
BY_NAME = {m.name: m for m in MODES}
BY_CUSTOM = {m.custom_mode: m for m in MODES}
BY_STANDARD = {m.standard_mode: m for m in MODES if m.standard_mode}


def from_do_set_mode(param2: float, param3: float) -> WireMode | None:
    """DO_SET_MODE's mode: the whole custom mode in param2, or main/sub in param2/param3."""
    if not (0 <= param2 < 2**32) or param2 != int(param2):
        return None
    if param2 > 255:
        return BY_CUSTOM.get(int(param2))
    if not (0 <= param3 <= 255) or param3 != int(param3):
        return None
    return BY_CUSTOM.get(custom_mode(int(param2), int(param3)))


def available_modes(index: int) -> Message:
    """AVAILABLE_MODES for mode ``index`` (1-based, as the microservice counts)."""
    m = MODES[index - 1]
    return dev.MAVLink_available_modes_message(len(MODES), index, m.standard_mode, m.custom_mode, 0,
                                               m.name.encode())  # fmt: skip


def current_mode(m: WireMode) -> Message:
    return dev.MAVLink_current_mode_message(m.standard_mode, m.custom_mode, m.custom_mode)


def available_modes_monitor() -> Message:
    return dev.MAVLink_available_modes_monitor_message(0)  # the set of modes never changes
