"""Run inside a private network namespace (udp_multicast must not leave the machine): the
per-tick cost of the servo command over DroneCAN and over MAVLink, and lockstep over each,
measured back to back in one process tree. Prints one JSON object on stdout.

``python -m benchmarks.can_probe`` is started by ``bench_processes.bench_lockstep_can``
under ``unshare --net``; it is not meant to be run on the host.
"""

from __future__ import annotations

import contextlib
import json
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from autopilot.flight_metrics import FlightMetrics
from autopilot.links.can_servo import CanServoSender
from autopilot.links.mavlink_sim import SimLink
from heli_common.vehicle.airframe import Airframe
from heli_common.wire.can.bus import CanBusConfig, open_bus
from heli_common.wire.servo_map import limits_array
from heli_sitl.launch.demo import DemoOptions, run_demo

N_SENDS = 3000


def _pitches(n: int) -> np.ndarray:
    lim = limits_array(Airframe.load().limits.as_tuple())
    return np.random.default_rng(0).uniform(lim[:, 0], lim[:, 1], size=(n, 4))


def mavlink_send_us() -> float:
    """Median cost of one HIL_ACTUATOR_CONTROLS: normalise, pack, send (a socket drains it)."""
    u = _pitches(N_SENDS)
    lim = limits_array(Airframe.load().limits.as_tuple())
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        sink.setblocking(False)
        link = SimLink(("127.0.0.1", 0), sink.getsockname(), lim)
        try:
            times = np.empty(N_SENDS)
            for k in range(N_SENDS):
                t0 = time.perf_counter()
                link.send_pitches(k * 10_000, u[k], True)
                times[k] = time.perf_counter() - t0
                with contextlib.suppress(BlockingIOError):
                    sink.recv(4096)
        finally:
            link.close()
    return float(np.median(times) * 1e6)


def can_send_us() -> float:
    """Median cost of one tick's ArrayCommand over udp_multicast: encode, three frames out."""
    u = _pitches(N_SENDS)
    bus = CanBusConfig("udp_multicast")
    with open_bus(bus) as rx, CanServoSender(bus) as tx:
        times = np.empty(N_SENDS)
        for k in range(N_SENDS):
            t0 = time.perf_counter()
            tx.send(u[k], k / 100.0, armed=True)
            times[k] = time.perf_counter() - t0
            while rx.recv(0.0) is not None:  # keep the receiver's buffer from overflowing
                pass
    return float(np.median(times) * 1e6)


def lockstep(servo_link: str) -> dict[str, object]:
    """The paper flight (120 s at 100 Hz) in lockstep, the GCS link streaming, over one link."""
    with tempfile.TemporaryDirectory() as d:
        bus = "udp_multicast" if servo_link == "can" else None
        opts = DemoOptions(out=Path(d), via_ground=False, mode="lockstep", servo_link=servo_link, can_bus=bus)
        return run_demo(opts)


def main() -> int:
    lockstep("mavlink")  # warm both processes' compile caches
    out: dict[str, float] = {"mavlink_send_us": mavlink_send_us(), "can_send_us": can_send_us()}
    # interleaved, twice each (the faster kept): a shared machine's slow minute hits both alike
    walls: dict[str, list[float]] = {"mavlink": [], "can": []}
    for _ in range(2):
        for link in ("mavlink", "can"):
            s = lockstep(link)
            walls[link].append(float(s["wall_s"]))  # type: ignore[arg-type]
            if link == "can":
                out["can_rms_45_120_m"] = FlightMetrics.from_summary(s).rms_45_m
    out["mavlink_lockstep_rtf"] = 120.0 / min(walls["mavlink"])
    out["can_lockstep_rtf"] = 120.0 / min(walls["can"])
    json.dump(out, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
