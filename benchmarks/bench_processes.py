"""Plant and autopilot as processes: lockstep real-time factor (MAVLink, DroneCAN) and the
real-time loop's period jitter at 400 Hz over the 120 s paper flight."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from autopilot.scenario import Scenario
from benchmarks import Row, above, below, bench
from heli_sitl.closed_loop import simulate
from heli_sitl.demo import DemoOptions, run_demo


def _demo(**kw: object) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as d:
        return run_demo(DemoOptions(out=Path(d), via_ground=False, **kw))  # type: ignore[arg-type]


ECHO = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
while True:
    data, addr = s.recvfrom(2048)
    if data == b"stop":
        break
    s.sendto(data, addr)
"""


def raw_round_trip_us(n: int = 3000, size: int = 180) -> float:
    """Median two-process UDP round trip of a state-sized datagram, no parsing: the floor
    of a lockstep tick's communication (the same wake-ups, none of the work)."""
    child = subprocess.Popen([sys.executable, "-c", ECHO], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        port = int(child.stdout.readline())
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(2.0)
            data, times = bytes(size), []
            for _ in range(n):
                t0 = time.perf_counter()
                s.sendto(data, ("127.0.0.1", port))
                s.recvfrom(2048)
                times.append(time.perf_counter() - t0)
            s.sendto(b"stop", ("127.0.0.1", port))
    finally:
        child.wait(timeout=5)
    return float(np.median(times) * 1e6)


def in_process_tick_us() -> float:
    """One tick of `heli-sitl simulate` (plant step + TLC, compiled), the floor of a
    lockstep tick's computation."""
    rec = simulate(Scenario.load("paper"))
    return rec.wall_s / rec.t_s.size * 1e6


@bench("processes, lockstep (MAVLink)")
def bench_lockstep() -> list[Row]:
    _demo(mode="lockstep", duration_s=5.0)  # warm the compile cache of both processes
    rtt, tick = raw_round_trip_us(), in_process_tick_us()
    floor = rtt + tick
    rows = [Row("floor: raw two-process UDP round trip (median)", rtt, "us"),
            Row("floor: in-process tick (plant + TLC)", tick, "us")]  # fmt: skip
    for label, extra in (("sim link only (--no-gcs)", ("--no-gcs",)),
                         ("with the GCS link streaming", ())):  # fmt: skip
        s = _demo(mode="lockstep", rate_hz=100.0, extra_autopilot_args=extra)
        rtf = 120.0 / float(s["wall_s"])  # type: ignore[arg-type]
        tick_us = float(s["wall_s"]) / 12001 * 1e6  # type: ignore[arg-type]
        rows.append(Row(f"paper 120 s at 100 Hz, {label}: real-time factor", rtf, "x", *above(rtf, 50.0)))
        rows.append(Row(f"  {label}: tick / (round trip + in-process tick)", tick_us / floor, "x",
                        *below(tick_us / floor, 3.0)))  # fmt: skip
    rows.append(Row("paper 120 s at 100 Hz: RMS error [45, 120] s", s["rms_pos_err_m"]["45-120"], "m",  # type: ignore[index]
                    *below(s["rms_pos_err_m"]["45-120"], 0.05)))  # type: ignore[index]
    return rows


def window_45(summary: dict[str, object]) -> float:
    """The RMS error from 45 s to the end of the flown trajectory."""
    rms = summary["rms_pos_err_m"]
    assert isinstance(rms, dict)
    (key,) = [k for k in rms if k.startswith("45-")]
    return float(rms[key])


@bench("processes, real time 400 Hz")
def bench_realtime_400() -> list[Row]:
    s = _demo(mode="realtime", rate_hz=400.0)
    loop = s["loop"]
    assert isinstance(loop, dict)
    rms = window_45(s)
    return [
        Row("period lateness p50", loop["jitter_p50_ms"], "ms"),
        Row("period lateness p99", loop["jitter_p99_ms"], "ms", *below(loop["jitter_p99_ms"], 0.5)),
        Row("period lateness max", loop["jitter_max_ms"], "ms", *below(loop["jitter_max_ms"], 5.0)),
        Row("overruns (a tick a period or more late)", loop["overruns"], "ticks"),
        Row("skipped ticks (more than 2 periods late)", loop["skipped_ticks"], "ticks",
            *below(loop["skipped_ticks"], 1)),
        Row("ticks with no new state", loop["stale_ticks"], "ticks"),
        Row("RMS error [45, 120] s", rms, "m", *below(rms, 1.2 * 0.0402)),
    ]  # fmt: skip


@bench("processes, lockstep (DroneCAN)")
def bench_lockstep_can() -> list[Row]:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from netns import NETNS_SETUP, unshare_reason

    if unshare_reason() is not None:
        return []
    with tempfile.TemporaryDirectory() as d:
        demo = (f"{sys.executable} -m heli_sitl.cli demo --mode lockstep --servo-link can "
                f"--can-bus udp_multicast --autostart --out {d}")  # fmt: skip
        subprocess.run(["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {demo}"],
                       check=True, capture_output=True, timeout=900)  # fmt: skip
        s = json.loads((Path(d) / "summary.json").read_text())
    rtf = 120.0 / s["wall_s"]
    return [
        Row("paper 120 s at 100 Hz over udp_multicast: real-time factor", rtf, "x"),
        Row("RMS error [45, 120] s (float16 commands)", s["rms_pos_err_m"]["45-120"], "m",
            *below(s["rms_pos_err_m"]["45-120"], 0.05)),
    ]  # fmt: skip
