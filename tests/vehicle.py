"""Start `heli-sitl up` for a test, every port its own and free (tests run side by side)."""

from __future__ import annotations

import sys
from typing import NamedTuple

from heli_common.mavlink.udp import free_udp_port
from heli_sitl.children import Child, spawn


class UpPorts(NamedTuple):
    gcs: int  # where ground stations listen
    api: int  # where API clients (MAVSDK) listen
    local_gcs: int
    local_api: int


def free_ports() -> UpPorts:
    ports: list[int] = []
    while len(ports) < 4:
        p = free_udp_port()
        if p not in ports:
            ports.append(p)
    return UpPorts(*ports)


def spawn_up(ports: UpPorts, *extra: str) -> Child:
    return spawn([sys.executable, "-m", "heli_sitl.cli", "up", "--gcs-port", str(ports.gcs),
                  "--api-port", str(ports.api), "--local-gcs-port", str(ports.local_gcs),
                  "--local-api-port", str(ports.local_api), *extra])  # fmt: skip
