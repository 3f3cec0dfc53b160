"""Plant and autopilot as processes: lockstep real-time factor (MAVLink, DroneCAN) and the
real-time loop's period jitter at 400 Hz over the 120 s paper flight."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import Row, above, below, bench
from heli_sitl.demo import DemoOptions, run_demo


def _demo(**kw: object) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as d:
        return run_demo(DemoOptions(out=Path(d), via_ground=False, **kw))  # type: ignore[arg-type]


@bench("processes, lockstep (MAVLink)")
def bench_lockstep() -> list[Row]:
    _demo(mode="lockstep", duration_s=5.0)  # warm the compile cache of both processes
    rows = []
    for label, extra in (("sim link only (--no-gcs)", ("--no-gcs",)),
                         ("with the GCS link streaming", ())):  # fmt: skip
        s = _demo(mode="lockstep", rate_hz=100.0, extra_autopilot_args=extra)
        rtf = 120.0 / float(s["wall_s"])  # type: ignore[arg-type]
        rows.append(Row(f"paper 120 s at 100 Hz, {label}: real-time factor", rtf, "x", *above(rtf, 50.0)))
    rows.append(Row("paper 120 s at 100 Hz: RMS error [45, 120] s", s["rms_pos_err_m"]["45-120"], "m",  # type: ignore[index]
                    *below(s["rms_pos_err_m"]["45-120"], 0.05)))  # type: ignore[index]
    return rows


@bench("processes, real time 400 Hz")
def bench_realtime_400() -> list[Row]:
    s = _demo(mode="realtime", rate_hz=400.0)
    loop = s["loop"]
    assert isinstance(loop, dict)
    rms = s["rms_pos_err_m"]["45-120"]  # type: ignore[index]
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
