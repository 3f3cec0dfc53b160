"""DroneCAN's ``mcast:N`` against python-can's ``udp_multicast``, in one run: frame rate,
latency, and what the bench's DroneCAN nodes cost the control loop. Prints JSON.

Run it inside a private network namespace only (multicast must not leave the machine)::

    sudo unshare --net bash -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && \\
        .venv/bin/python -m benchmarks.can_mcast_probe'

It refuses to run where the group's route is not on ``lo``. Everything is bounded: a
fixed number of frames, each wait at most a second. Not part of ``make bench`` (which
runs on the host): a standalone probe, reported in docs/can.md.

* ``send_us``: median cost of ``bus.send`` of one 8-byte frame (a peer drains the group);
* ``latency_us``: median and p99 of a ping-pong between two processes, half the round trip;
* ``frames_per_s``: a burst of ``N_BURST`` frames as fast as one process sends them, how
  many per second the other process received, and the share lost (the kernel's socket
  buffer drops what the receiver has not read);
* ``servo_send_us``: the autopilot's ``CanServoSender.send`` per tick (4 pitches: three
  frames; on mcast it also listens for GetNodeInfo), and the same not listening;
* ``endpoint_poll_us``: the plant's ``CanServoEndpoint.poll`` of one tick's command, with
  its node (NodeStatus, actuator Status at 10 Hz of the given time) and without.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import subprocess
import sys
import time
from typing import Any

import numpy as np

from autopilot.links.can_servo import CanServoSender
from heli_common.vehicle.airframe import PitchLimits
from heli_common.wire.can.bus import CanBusConfig, open_bus
from heli_plant.can_endpoint import CanServoEndpoint

BUSES = {"mcast": CanBusConfig("mcast", "0"), "udp_multicast": CanBusConfig("udp_multicast")}
N_SEND = 3000
N_PING = 1000
N_BURST = 20000
N_TICKS = 3000
LIMITS = PitchLimits((-0.6, 0.6), (-0.8, 0.8), (-0.5, 0.5), (-0.5, 0.5))
U = (0.1, -0.2, 0.3, -0.05)


def _in_private_netns() -> bool:
    route = subprocess.run(["ip", "route", "get", "239.65.82.0"], capture_output=True, text=True)
    return route.returncode == 0 and " dev lo " in route.stdout + " "


def _echo(cfg: CanBusConfig, ready: Any, n: int) -> None:
    with open_bus(cfg) as bus:
        ready.set()
        echoed = 0
        while echoed < n:
            msg = bus.recv(1.0)
            if msg is None:
                return
            if msg.arbitration_id == 0x100:  # a ping: answer it
                bus.send(0x200, bytes(msg.data))
                echoed += 1


def _count(cfg: CanBusConfig, ready: Any, out: Any) -> None:
    with open_bus(cfg) as bus:
        ready.set()
        got, first, last = 0, 0.0, 0.0
        while True:
            msg = bus.recv(1.0)
            if msg is None:
                break
            now = time.perf_counter()
            first = first or now
            last = now
            got += 1
        out.put((got, last - first))


def send_us(cfg: CanBusConfig) -> float:
    with open_bus(cfg) as a, open_bus(cfg) as b:
        times = np.empty(N_SEND)
        for k in range(N_SEND):
            t0 = time.perf_counter()
            a.send(0x1234, b"12345678")
            times[k] = time.perf_counter() - t0
            while b.recv(0.0) is not None:
                pass
    return float(np.median(times) * 1e6)


def latency_us(cfg: CanBusConfig) -> tuple[float, float]:
    ctx = mp.get_context("spawn")
    ready = ctx.Event()
    p = ctx.Process(target=_echo, args=(cfg, ready, N_PING))
    p.start()
    try:
        ready.wait(20.0)
        rtt = []
        with open_bus(cfg) as bus:
            time.sleep(0.2)
            for k in range(N_PING):
                t0 = time.perf_counter()
                bus.send(0x100, k.to_bytes(4, "little"))
                deadline = t0 + 1.0
                while time.perf_counter() < deadline:
                    msg = bus.recv(max(0.0, deadline - time.perf_counter()))
                    if msg is not None and msg.arbitration_id == 0x200:
                        rtt.append(time.perf_counter() - t0)
                        break
    finally:
        p.join(10.0)
        if p.is_alive():
            p.kill()
    half = np.array(rtt) / 2 * 1e6
    return float(np.median(half)), float(np.percentile(half, 99))


def frames_per_s(cfg: CanBusConfig) -> tuple[float, float, float]:
    ctx = mp.get_context("spawn")
    ready, out = ctx.Event(), ctx.Queue()
    p = ctx.Process(target=_count, args=(cfg, ready, out))
    p.start()
    try:
        ready.wait(20.0)
        time.sleep(0.2)
        with open_bus(cfg) as bus:
            t0 = time.perf_counter()
            for _ in range(N_BURST):
                bus.send(0x1234, b"12345678")
            sent_s = time.perf_counter() - t0
        got, span = out.get(timeout=30.0)
    finally:
        p.join(10.0)
        if p.is_alive():
            p.kill()
    return N_BURST / sent_s, got / max(span, 1e-9), 1.0 - got / N_BURST


def servo_send_us(cfg: CanBusConfig, listen: bool = True) -> float:
    """Median of one tick's send (3 frames of ArrayCommand, ArmingStatus at 2 Hz, NodeStatus
    at 1 Hz of tick time), listening for GetNodeInfo requests (its own frames read back on
    mcast) or not (``listen=False``; on udp_multicast it never does)."""
    with CanServoSender(cfg, node_id=10) as tx, open_bus(cfg) as sink:
        tx._listens = tx._listens and listen
        times = np.empty(N_TICKS)
        for k in range(N_TICKS):
            t0 = time.perf_counter()
            tx.send(U, 0.01 * k, armed=True)
            times[k] = time.perf_counter() - t0
            while sink.recv(0.0) is not None:
                pass
            time.sleep(0.0002)  # the tick's own frames come back before the next send
    return float(np.median(times) * 1e6)


def endpoint_poll_us(cfg: CanBusConfig, node: bool) -> float:
    with (
        CanServoSender(cfg, node_id=10) as tx,
        CanServoEndpoint(cfg, limits=LIMITS, source_node_id=10, node_id=20 if node else None) as ep,
    ):
        times = np.empty(N_TICKS)
        for k in range(N_TICKS):
            tx.send(U, 0.01 * k)
            time.sleep(0.0002)
            t0 = time.perf_counter()
            ep.poll(0.01 * k)
            times[k] = time.perf_counter() - t0
    return float(np.mean(times) * 1e6)


def main() -> int:
    if not _in_private_netns():
        print("can_mcast_probe: the multicast route is not on lo: run it in a private network "
              "namespace (see the module doc)", file=sys.stderr)  # fmt: skip
        return 2
    out: dict[str, Any] = {}
    for name, cfg in BUSES.items():
        sent, recv, lost = frames_per_s(cfg)
        p50, p99 = latency_us(cfg)
        out[name] = {
            "send_us": round(send_us(cfg), 2),
            "latency_us_p50": round(p50, 1), "latency_us_p99": round(p99, 1),
            "burst_sent_per_s": round(sent), "burst_received_per_s": round(recv),
            "burst_lost": round(lost, 4),
            "servo_send_us": round(servo_send_us(cfg), 1),
            "servo_send_us_not_listening": round(servo_send_us(cfg, listen=False), 1),
            "endpoint_poll_us_with_node": round(endpoint_poll_us(cfg, True), 1),
            "endpoint_poll_us_without_node": round(endpoint_poll_us(cfg, False), 1),
        }  # fmt: skip
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
