"""Plant and autopilot as processes: lockstep real-time factor (MAVLink, DroneCAN) and the
real-time loop's period jitter at 400 Hz over the 120 s paper flight."""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.flight_metrics import FlightMetrics
from autopilot.scenario import Scenario
from benchmarks import Row, above, below, bench
from heli_common.rt_priority import DEFAULT_PRIORITY
from heli_sitl.engine.closed_loop import simulate
from heli_sitl.launch.demo import DemoOptions, run_demo


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
    rms45 = window_45(s)
    rows.append(Row("paper 120 s at 100 Hz: RMS error [45, 120] s", rms45, "m", *below(rms45, 0.05)))
    alone, together = concurrent_lockstep_s(1), concurrent_lockstep_s(2)
    rows.append(Row("floor: one lockstep flight (60 s, autostart) alone, wall", alone, "s"))
    rows.append(Row("  two at once on the machine's cores: each one's wall / alone", together / alone, "x",
                    *below(together / alone, 2.0)))  # fmt: skip
    return rows


def concurrent_lockstep_s(n: int) -> float:
    """The slowest wall time of ``n`` lockstep flights started at once (`heli-sitl demo`, 60 s,
    autostart): a lockstep wait that spins without yielding holds the core its partner needs
    (two at once took 30 s each against 5 s alone before the spin yielded)."""
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "heli_sitl.cli", "demo", "--mode", "lockstep", "--autostart",
               "--duration-s", "60"]  # fmt: skip
        t0 = time.perf_counter()
        procs = [subprocess.Popen([*cmd, "--out", f"{d}/{i}"], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL) for i in range(n)]  # fmt: skip
        for p in procs:
            if p.wait(timeout=600) != 0:
                raise RuntimeError(f"a lockstep demo failed (exit {p.returncode})")
        return time.perf_counter() - t0


def window_45(summary: dict[str, object]) -> float:
    """The RMS error from 45 s to the end of the flown trajectory."""
    return FlightMetrics.from_summary(summary).rms_45_m


def bare_loops(duration_s: float = 60.0, rt_priority: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """The floor of the real-time stack's scheduling: two processes that only sleep to
    their deadlines at 400 Hz (the autopilot's) and 800 Hz (the plant's), side by side,
    under the scheduling policy the flight asks for (``rt_priority``: SCHED_FIFO)."""
    cmd = [sys.executable, "-m", "benchmarks.sleep_loop"]
    prio = [str(rt_priority)] if rt_priority else []
    plant = subprocess.Popen([*cmd, "800", str(duration_s), *prio], stdout=subprocess.PIPE, text=True)
    ap = subprocess.run([*cmd, "400", str(duration_s), *prio], capture_output=True, text=True, check=True)
    out, _ = plant.communicate(timeout=duration_s + 60)
    return json.loads(ap.stdout), json.loads(out)


def steal_ms() -> float:
    """CPU time the hypervisor took from this VM so far, all CPUs (/proc/stat's 'steal'
    column, in clock ticks): a sleep it wakes late is late for any program (NaN off Linux)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return float(fields[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return math.nan


FLIGHT_S = 120.0  # the paper flight; the floor's loops run as long, so both meet the same hypervisor


def poisson_rate_ci(events: int, minutes: float) -> tuple[float, float]:
    """The exact (Garwood) 95 % interval of a Poisson rate [per minute] from ``events`` seen
    in ``minutes``."""
    from scipy.stats import chi2

    lo = 0.0 if events == 0 else float(chi2.ppf(0.025, 2 * events)) / 2.0
    hi = float(chi2.ppf(0.975, 2 * events + 2)) / 2.0
    return lo / minutes, hi / minutes


@bench("processes, real time 400 Hz")
def bench_realtime_400() -> list[Row]:
    """The 400 Hz flight with both loops under SCHED_FIFO (``--rt-priority``) where the
    machine permits it, and its floor's sleep loops under the same policy.

    A skip on this machine is a single sleep woken 5-25 ms late (the hypervisor's steal
    takes the vCPU; no tick overran), a few minutes apart: 120 s of floor sees zero, one or
    two of them by luck. So the late wake-ups are also counted as events with their rate's
    95 % interval, flight and floor: the flight passes while its rate is not shown to be
    above the floor's (the intervals overlap)."""
    st0 = steal_ms()
    s = _demo(mode="realtime", rate_hz=400.0, rt_priority=DEFAULT_PRIORITY)
    st1 = steal_ms()
    loop = s["loop"]
    assert isinstance(loop, dict)
    rms = window_45(s)
    floor, _ = bare_loops(FLIGHT_S, DEFAULT_PRIORITY)
    st2 = steal_ms()
    per_min = 60.0 / FLIGHT_S
    skipped_min = loop["skipped_ticks"] * per_min
    floor_min = floor["skipped"] * per_min
    events = len(loop["tick_sections"]["skips"])
    f_lo, f_hi = poisson_rate_ci(events, FLIGHT_S / 60.0)
    b_lo, b_hi = poisson_rate_ci(int(floor["skip_events"]), FLIGHT_S / 60.0)
    return [
        Row(f"floor: bare 400 Hz sleep loop beside an 800 Hz one ({floor['scheduling']}), lateness p99",
            floor["p99_ms"], "ms"),
        Row("floor: bare 400 Hz sleep loop, skipped ticks per minute", floor_min, "ticks/min"),
        Row(f"floor: late wake-ups (skip events) per minute, 95 % interval [{b_lo:.2f}, {b_hi:.2f}]",
            floor["skip_events"] * per_min, "events/min"),
        Row("  CPU time the hypervisor took (steal), during the floor's loops", st2 - st1, "ms"),
        Row("  the same during the flight (its start and end included)", st1 - st0, "ms"),
        Row("period lateness p50", loop["jitter_p50_ms"], "ms"),
        Row("period lateness p99", loop["jitter_p99_ms"], "ms", *below(loop["jitter_p99_ms"], 0.5)),
        Row("period lateness max", loop["jitter_max_ms"], "ms", *below(loop["jitter_max_ms"], 5.0)),
        Row("tick work p99 (control, telemetry, record)", loop["tick_work_p99_ms"], "ms"),
        Row("  tick work max", loop["tick_work_max_ms"], "ms"),
        Row("overruns (a tick a period or more late)", loop["overruns"], "ticks"),
        Row(f"skipped ticks (more than 2 periods late; autopilot {s.get('scheduling')}), per minute",
            skipped_min, "ticks/min", f"<= floor ({floor_min:g})", skipped_min <= floor_min),
        Row(f"late wake-ups (skip events) per minute, 95 % interval [{f_lo:.2f}, {f_hi:.2f}]",
            events * per_min, "events/min", f"not above the floor's (<= {b_hi:.2f})", f_lo <= b_hi),
        Row("ticks with no new state", loop["stale_ticks"], "ticks"),
        Row("RMS error [45, 120] s", rms, "m", *below(rms, 1.2 * 0.0402)),
        *tick_section_rows(loop["tick_sections"]),
    ]  # fmt: skip


def tick_section_rows(sections: dict[str, Any]) -> list[Row]:
    """Where the ticks' time went (autopilot.tick_timer): each section's worst tick, the
    collector's longest pause, and what the skipped ticks were (a tick that overran, or a
    sleep the OS woke late)."""
    rows = [Row(f"  tick section max: {name}", ms, "ms") for name, ms in sections["section_max_ms"].items()]
    rows.append(Row("  collector pause max (generation 0 / 1 / 2 at most)", max(sections["gc_max_ms"]), "ms"))
    skips = sections["skips"]
    overslept = sum(1 for s in skips if s["overslept_ms"] > 0.0)
    rows.append(Row("  skip events: asleep past the deadline (the OS)", overslept, "events"))
    rows.append(Row("  skip events: the tick before overran", len(skips) - overslept, "events"))
    return rows


@bench("processes, lockstep (DroneCAN)")
def bench_lockstep_can() -> list[Row]:
    """DroneCAN against MAVLink for the servo command, per tick and in lockstep, all
    measured in one private network namespace (udp_multicast stays on its loopback)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from netns import NETNS_SETUP, unshare_reason

    if unshare_reason() is not None:
        return []
    probe = f"{sys.executable} -m benchmarks.can_probe"
    done = subprocess.run(["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {probe}"],
                          check=True, capture_output=True, text=True, timeout=1200)  # fmt: skip
    r = json.loads(done.stdout)
    send_ratio = r["can_send_us"] / r["mavlink_send_us"]
    rtf_ratio = r["can_lockstep_rtf"] / r["mavlink_lockstep_rtf"]
    return [
        Row("floor: MAVLink servo command, normalise + pack + send (median)", r["mavlink_send_us"], "us"),
        Row("DroneCAN ArrayCommand, encode + 3 frames on udp_multicast (median)", r["can_send_us"], "us"),
        Row("  DroneCAN send / MAVLink send", send_ratio, "x", *below(send_ratio, 3.0)),
        Row("lockstep over MAVLink, GCS streaming: real-time factor", r["mavlink_lockstep_rtf"], "x"),
        Row("lockstep over DroneCAN (udp_multicast), GCS streaming: real-time factor",
            r["can_lockstep_rtf"], "x"),
        Row("  DroneCAN real-time factor / MAVLink's", rtf_ratio, "x", *above(rtf_ratio, 0.7)),
        Row("RMS error [45, 120] s over DroneCAN (float16 commands)", r["can_rms_45_120_m"], "m",
            *below(r["can_rms_45_120_m"], 0.05)),
    ]  # fmt: skip
