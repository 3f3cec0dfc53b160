"""Start `heli-sitl up` for a test, every port its own (tests run side by side: tests/ports.py)."""

from __future__ import annotations

import sys
from typing import NamedTuple

from ports import new_port

from heli_sitl.launch.children import Child, spawn


class UpPorts(NamedTuple):
    gcs: int  # where ground stations listen
    api: int  # where API clients (MAVSDK) listen
    local_gcs: int
    local_api: int


def free_ports() -> UpPorts:
    return UpPorts(new_port(), new_port(), new_port(), new_port())


def spawn_up(ports: UpPorts, *extra: str) -> Child:
    return spawn([sys.executable, "-m", "heli_sitl.cli", "up", "--gcs-port", str(ports.gcs),
                  "--api-port", str(ports.api), "--local-gcs-port", str(ports.local_gcs),
                  "--local-api-port", str(ports.local_api), *extra])  # fmt: skip
