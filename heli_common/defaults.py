"""What every command agrees on by default: UDP ports, home, exit codes. Defined once here.

Ports follow PX4 SITL's numbers (sim link 4560, ground stations 14550, API clients 14540,
the vehicle's own ends 18570 and 14580); ``instance`` N adds 10 N to every one of them, as
ArduPilot's ``-I N`` does, so several vehicles can run on one host.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from heli_common.geo import GeoPoint

#: PX4 SITL's default home (Zurich), so a user's ground-station maps look familiar
HOME = GeoPoint(47.397742, 8.545594, 488.0)
PORT_STRIDE_PER_INSTANCE = 10


@dataclass(frozen=True)
class Ports:
    plant: int = 4560  # the plant's sim-link socket
    autopilot: int = 4561  # the autopilot's sim-link socket
    gcs: int = 14550  # where ground stations listen (QGroundControl, MAVProxy, heli-ground)
    api: int = 14540  # where API clients listen (MAVSDK)
    local_gcs: int = 18570  # the vehicle's end of the ground-station link
    local_api: int = 14580  # the vehicle's end of the API link


def ports(instance: int = 0) -> Ports:
    """The default ports of vehicle ``instance`` (0, 1, ...)."""
    base = Ports()
    k = PORT_STRIDE_PER_INSTANCE * instance
    return Ports(*(p + k for p in (base.plant, base.autopilot, base.gcs, base.api, base.local_gcs,
                                  base.local_api)))  # fmt: skip


class Exit(enum.IntEnum):
    """Exit status of every command."""

    OK = 0
    FAILURE = 1  # the vehicle, a link or a child process failed
    USAGE = 2  # bad input: options, config files, mission files, keys
    PORT_BUSY = 3  # a UDP port is already bound (another instance running?)
    INTERRUPTED = 130  # Ctrl-C
