"""Campaign throughput on Dask: simulated vehicle-seconds per wall-second, embedded cluster
of 1 and 2 workers, against one process flying the same flights in a plain loop (the
floor: the single-flight in-process rate, on one core: this process, like the workers, has
one BLAS thread, heli_common/threads.py), and the shipped 1000-flight robustness campaign's
wall time including the cluster's start."""

from __future__ import annotations

import multiprocessing as mp
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks import Row, above, below, bench
from heli_sitl.studies.campaigns.engine import run_batch
from heli_sitl.studies.campaigns.run import prepare, run_campaign

SUBSET = 200  # flights of the robustness campaign for the 1- and 2-worker figures


def _plain_loop(first: int, n: int, start: Any, out: Any) -> None:
    """One of the side-by-side floor processes: flies samples ``first .. first + n - 1`` in a
    plain loop once both processes are warm; puts its flying time."""
    spec, base, table = prepare("robustness", SUBSET)
    run_batch(spec, base, [0], [table[0].tolist()])
    start.wait()
    t0 = time.perf_counter()
    ids = list(range(first, first + n))
    run_batch(spec, base, ids, table[ids].tolist())
    out.put(time.perf_counter() - t0)


def side_by_side_rate(duration_s: float) -> float:
    """The machine's own ceiling for two workers: two processes flying half the subset each
    in a plain loop at the same time, vehicle-s per wall-s (no Dask). On this 2-core VM two
    busy processes each run slower than one alone (shared caches, the hypervisor)."""
    ctx = mp.get_context("spawn")
    start, out = ctx.Barrier(2), ctx.Queue()
    half = SUBSET // 2
    procs = [ctx.Process(target=_plain_loop, args=(i * half, half, start, out)) for i in range(2)]
    for p in procs:
        p.start()
    walls = [float(out.get(timeout=600)) for _ in procs]
    for p in procs:
        p.join()
    return 2 * half * duration_s / max(walls)


@bench("campaigns on Dask")
def bench_campaign() -> list[Row]:
    spec, base, table = prepare("robustness", SUBSET)
    duration = base.scenario.run.duration_s
    run_batch(spec, base, [0], [table[0].tolist()])  # load the compiled code in this process
    t0 = time.perf_counter()
    run_batch(spec, base, list(range(SUBSET)), table.tolist())
    serial = SUBSET * duration / (time.perf_counter() - t0)
    rows = [Row(f"floor: one process, plain loop, {SUBSET} robustness flights", serial, "veh-s/s")]
    pair = side_by_side_rate(duration)
    rows.append(Row("floor: two processes side by side, plain loops, the same flights", pair, "veh-s/s"))
    rows.append(Row("  their efficiency vs 2 x the one-process floor", 100 * pair / (2 * serial), "%"))
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            out = Path(tmp) / f"w{workers}"
            s = run_campaign("robustness", out, samples=SUBSET, workers=workers, quiet=True)
            tput = float(s["run"]["vehicle_s_per_wall_s"])
            eff = tput / (workers * serial)
            rows.append(Row(f"embedded LocalCluster, {workers} worker(s), {SUBSET} flights", tput, "veh-s/s"))
            rows.append(Row(f"  parallel efficiency vs {workers} x the floor", eff * 100, "%",
                            *above(eff * 100, 90.0)))  # fmt: skip
            if workers == 2:
                rows.append(Row("  vs the two side-by-side processes", 100 * tput / pair, "%"))
        t0 = time.perf_counter()
        s = run_campaign("robustness", Path(tmp) / "full", quiet=True)
        wall = float(s["run"]["cluster_start_s"] + s["run"]["engine_wall_s"])
        name = "robustness.toml, 1000 flights: cluster start + flights"
        rows.append(Row(name, wall, "s", *below(wall, 30.0)))
        whole = time.perf_counter() - t0
        rows.append(Row("  the same with sample table, Parquet and figures", whole, "s", *below(whole, 40.0)))
    return rows
