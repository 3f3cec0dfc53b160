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


# Both real-time loops under SCHED_FIFO where the OS permits it (root, CAP_SYS_NICE; a
# warning elsewhere), as a user flies beside other work: the suite's CPU-bound files would
# otherwise delay the vehicle's ticks and its answers, and a ground station's figures
# measured on the vehicle's clock (first PARAM_VALUE 0.49 s against 0.03-0.10 s alone,
# a fresh clone beside four busy processes) would measure the machine's load
RT_PRIORITY = ("--rt-priority", "10")


def spawn_up(ports: UpPorts, *extra: str) -> Child:
    rt = () if "--rt-priority" in extra else RT_PRIORITY
    return spawn([sys.executable, "-m", "heli_sitl.cli", "up", "--gcs-port", str(ports.gcs),
                  "--api-port", str(ports.api), "--local-gcs-port", str(ports.local_gcs),
                  "--local-api-port", str(ports.local_api), *rt, *extra])  # fmt: skip
