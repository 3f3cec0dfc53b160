"""What ``--rt-priority`` buys on a loaded machine: a 400 Hz real-time flight (both
processes) beside one busy-looping process per core, under the default policy and then
under SCHED_FIFO. Prints one line per policy. Not part of ``make bench`` (it loads the
machine on purpose, ~2 minutes).

``python -m benchmarks.loaded_realtime [DURATION_S]``
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from heli_common.rt_priority import DEFAULT_PRIORITY
from heli_sitl.launch.demo import DemoOptions, run_demo


def loaded_flight(rt_priority: int, duration_s: float) -> dict[str, object]:
    """The flight's loop summary with a busy loop per core running beside it."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 1)]
    try:
        with tempfile.TemporaryDirectory() as d:
            s = run_demo(DemoOptions(out=Path(d), via_ground=False, mode="realtime", rate_hz=400.0,
                                     rt_priority=rt_priority, duration_s=duration_s))  # fmt: skip
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    loop = s["loop"]
    assert isinstance(loop, dict)
    return {"scheduling": s.get("scheduling"), **{k: loop[k] for k in (
        "ticks", "overruns", "skipped_ticks", "stale_ticks", "jitter_p99_ms", "jitter_max_ms")}}  # fmt: skip


def main(argv: list[str]) -> int:
    duration_s = float(argv[0]) if argv else 40.0
    for prio in (0, DEFAULT_PRIORITY):
        r = loaded_flight(prio, duration_s)
        print(f"{r['scheduling']:>8}: {r['ticks']} ticks, {r['overruns']} overruns, "
              f"{r['skipped_ticks']} skipped, {r['stale_ticks']} without a new state, "
              f"lateness p99 {r['jitter_p99_ms']:.3f} ms, "
              f"max {r['jitter_max_ms']:.2f} ms")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
