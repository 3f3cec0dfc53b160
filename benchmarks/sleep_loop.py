"""The floor of a fixed-rate loop on this machine: a process that does nothing but sleep
to its deadlines (``start + k period``, as the autopilot's real-time runner) and counts its
lateness by the runner's own rule (more than 2 periods late: the ticks in between are
skipped). Prints one JSON object.

``python -m benchmarks.sleep_loop RATE_HZ DURATION_S [RT_PRIORITY]`` (started by the
real-time benchmark beside a second loop at twice the rate, the plant's; under SCHED_FIFO at
RT_PRIORITY when given and permitted, as the flight's processes with ``--rt-priority``).
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from heli_common.rt_priority import current_policy, request_fifo

SKIP_AFTER_PERIODS = 2  # autopilot.runner.RunnerConfig.skip_after_periods


def sleep_loop(rate_hz: float, duration_s: float) -> dict[str, float]:
    period = 1.0 / rate_hz
    n = round(duration_s * rate_hz)
    lateness = np.empty(n)
    n_late = 0
    skipped = overruns = skip_events = 0
    start = time.monotonic()
    k = 0
    while k < n:
        deadline = start + k * period
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        late = time.monotonic() - deadline
        if late > SKIP_AFTER_PERIODS * period:
            skip = int(late / period)
            skipped += skip
            skip_events += 1
            overruns += 1
            k += skip
            continue
        if late >= period:
            overruns += 1
        lateness[n_late] = late
        n_late += 1
        k += 1
    lat_ms = lateness[:n_late] * 1e3
    return {
        "p50_ms": float(np.percentile(lat_ms, 50)),
        "p99_ms": float(np.percentile(lat_ms, 99)),
        "max_ms": float(lat_ms.max()),
        "overruns": overruns,
        "skipped": skipped,
        "skip_events": skip_events,
    }


if __name__ == "__main__":
    refused = request_fifo(int(sys.argv[3])) if len(sys.argv) > 3 else None
    result: dict[str, object] = {**sleep_loop(float(sys.argv[1]), float(sys.argv[2]))}
    result["scheduling"] = current_policy()
    if refused:
        result["refused"] = refused
    json.dump(result, sys.stdout)
