"""Running a campaign on Dask distributed, with its results in Parquet as they arrive.

The flights are grouped into tasks (:func:`batches`: big ones first, so that Dask's
per-task cost, milliseconds, stays small beside a batch's seconds of flying, single flights
last), submitted to an embedded
``LocalCluster`` (one single-threaded worker process per core, BLAS pinned to one thread)
or to a running scheduler (``--scheduler tcp://host:port``). Each finished batch is written
at once as its own Parquet file ``DIR/parts/part-<first>-<last>.parquet`` (written to a
temporary name, then renamed: a part is there whole or not at all). Running the same
command again reads the parts, skips every sample id already there, and flies the rest:
no sample is flown into two parts. A worker that dies has its task retried (Dask's
``retries``); a flight that raises is a failed row. At the end ``DIR/results.parquet``
holds every row, sorted by sample id. While the cluster is still up, the campaign draws its
figures on it (:func:`render_figures`: one task per figure, its PNG bytes sent back).
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from heli_common.threads import SINGLE_THREAD_ENV, one_blas_thread
from heli_sitl.studies.campaigns import report
from heli_sitl.studies.campaigns.flight import fly, warm
from heli_sitl.studies.campaigns.settings import FlightSetup
from heli_sitl.studies.campaigns.spec import CampaignSpec

PARTS = "parts"
RESULTS = "results.parquet"
def software_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("heli-tlc-sitl")
    except PackageNotFoundError:
        return "unknown"


def schema(spec: CampaignSpec) -> pa.Schema:
    """One row per flight: its id, each varied value, its seed, the metrics, the outcome."""
    fields = [pa.field("sample_id", pa.int64())]
    fields += [pa.field(k, pa.float64()) for k in spec.keys]
    fields.append(pa.field("seed", pa.int64()))
    kind = {
        "saturated_ticks": pa.int64(),
        "converged": pa.bool_(),
        "diverged": pa.bool_(),
        "diverged_reason": pa.string(),
    }
    fields += [pa.field(m, kind.get(m, pa.float64())) for m in spec.metrics]
    fields += [
        pa.field("failed", pa.bool_()),
        pa.field("error", pa.string()),
        pa.field("traceback", pa.string()),
        pa.field("version", pa.string()),
        pa.field("wall_s", pa.float64()),
    ]
    return pa.schema(fields)


def warm_worker(base: FlightSetup) -> None:
    """Run on every worker as the cluster starts: imports and compiled code loaded before
    the first batch (counted in the cluster's start, not in the flights' pace)."""
    one_blas_thread()
    with contextlib.suppress(Exception):  # a flight that cannot fly says so in its own row
        warm(base)


def run_batch(
    spec: CampaignSpec, base: FlightSetup, ids: list[int], rows: list[list[float]]
) -> list[dict[str, Any]]:
    """A task: fly these samples one after the other (in a worker process)."""
    one_blas_thread()
    version = software_version()
    out = []
    for sid, values in zip(ids, rows, strict=True):
        r = fly(spec, base, sid, spec.keys, values)
        r["version"] = version
        out.append(r)
    return out


def preload_writer(spec: CampaignSpec) -> None:
    """What the first part's write imports (pyarrow builds a table from rows through its
    pandas shim, which imports pandas: ~1 s of CPU), loaded before the flights start. Run
    in a thread while the cluster starts, when this process only waits: done later, it took
    a core from the two workers in the middle of the flights (measured, py-spy)."""
    pa.Table.from_pylist([], schema=schema(spec))


def done_ids(out: Path) -> set[int]:
    """Sample ids already written (complete parts only)."""
    parts = out / PARTS
    if not parts.is_dir():
        return set()
    ids: set[int] = set()
    for f in sorted(parts.glob("part-*.parquet")):
        ids.update(pq.read_table(f, columns=["sample_id"]).column("sample_id").to_pylist())
    return ids


def write_part(out: Path, spec: CampaignSpec, rows: list[dict[str, Any]]) -> Path:
    sch = schema(spec)
    table = pa.Table.from_pylist([{k: r.get(k) for k in sch.names} for r in rows], schema=sch)
    parts = out / PARTS
    parts.mkdir(parents=True, exist_ok=True)
    ids = [r["sample_id"] for r in rows]
    path = parts / f"part-{min(ids):08d}-{max(ids):08d}.parquet"
    tmp = path.with_suffix(".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)
    return path


def collect(out: Path, spec: CampaignSpec) -> pa.Table:
    """Every row written, one per sample id, sorted; written to DIR/results.parquet."""
    parts = sorted((out / PARTS).glob("part-*.parquet"))
    tables = [pq.read_table(f, schema=schema(spec)) for f in parts]
    table = pa.concat_tables(tables) if tables else schema(spec).empty_table()
    table = table.sort_by("sample_id")
    pq.write_table(table, out / RESULTS)
    return table


MAX_BATCH = 50  # flights in one task at most: a lost task costs little to fly again


def batches(spec: CampaignSpec, todo: list[int], workers: int) -> list[list[int]]:
    """The sample ids of each task, in submission order. ``spec.batch`` > 0: that many per
    task. Otherwise guided: each task takes a quarter of what is left per worker (at most
    ``MAX_BATCH``, at least one), so the first tasks are big (Dask's per-task cost, a few
    ms, stays small beside seconds of flying) and the last ones single flights: at the end
    no worker waits long for another to finish a big batch (fixed 32-flight batches left
    one worker idle for ~1 s of a 35 s campaign on 2 cores)."""
    out: list[list[int]] = []
    k = 0
    while k < len(todo):
        left = len(todo) - k
        size = spec.batch or max(1, min(MAX_BATCH, math.ceil(left / (4 * max(1, workers)))))
        out.append(todo[k : k + size])
        k += size
    return out


@dataclass
class EngineStats:
    flights: int = 0
    failed: int = 0
    batches: int = 0
    wall_s: float = 0.0  # cluster start + flights (not what runs on the cluster after them)
    cluster_start_s: float = 0.0  # workers up, their compiled code loaded
    flying_s: float = 0.0  # from the workers ready to the last part written
    workers: int = 0
    scheduler: str = "embedded LocalCluster"


#: the embedded cluster's settings. Its workers use every core, so what the scheduler, the
#: nannies and the workers' own threads do between flights is taken from the flights: the
#: workers' statistical profiler walked the flying thread's stack every 10 ms, the event
#: loops measured their tick every 20 ms, the system monitors read psutil twice a second
#: (py-spy profiles of a 2-worker campaign). And the workers' malloc: Dask starts them with
#: MALLOC_TRIM_THRESHOLD_=65536, which hands freed memory back to the OS at once (and, set at
#: all, stops glibc raising its mmap threshold), so each flight's megabytes of arrays came
#: back as fresh pages: ~2000 page faults a flight, its Python part 7.3 ms instead of 3.8.
#: Without it, and with one malloc arena (a task runs in a thread, and a thread's own arena
#: also faulted, ~1300 a flight), a flight in a worker runs as fast as in a plain loop
#: (measured: 41.5 ms both; tests/test_campaign.py checks the page faults).
CLUSTER_CONFIG: dict[str, object] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.nanny.pre-spawn-environ": {"MALLOC_ARENA_MAX": 1, **SINGLE_THREAD_ENV},
}


@contextlib.contextmanager
def cluster(workers: int, scheduler: str | None) -> Iterator[Any]:
    """A Dask client: to ``scheduler``, or to an embedded LocalCluster of ``workers``
    single-threaded processes (workers inherit the single-thread BLAS settings)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout="30s") as client:
            yield client
        return
    import dask

    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    try:
        with (
            dask.config.set(CLUSTER_CONFIG),
            LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                host="127.0.0.1",
                # no memory limit, so no nanny polling each worker's memory 10 times a
                # second (psutil, CPU taken from the flights): a flight holds a few MB
                memory_limit=0,
                silence_logs=40,
            ) as lc,
            Client(lc) as client,
        ):
            yield client
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run(
    spec: CampaignSpec,
    base: FlightSetup,
    table: np.ndarray,
    out: Path,
    workers: int,
    scheduler: str | None = None,
    progress: Callable[[int, int, int], None] | None = None,
    on_cluster: Callable[[Any], None] | None = None,
) -> EngineStats:
    """Fly every sample of ``table`` not yet in ``out``; ``progress(done, total, failed)``
    after each batch; ``on_cluster(client)`` once every flight is written, the cluster still
    up (the campaign draws its figures on it). Where every flight was already written no
    cluster starts, and ``on_cluster`` is not called."""
    from dask.distributed import as_completed

    stats = EngineStats(scheduler=scheduler or "embedded LocalCluster")
    have = done_ids(out)
    todo = [i for i in range(table.shape[0]) if i not in have]
    total = table.shape[0]
    if progress is not None:
        progress(len(have), total, 0)
    if not todo:
        return stats
    t0 = time.perf_counter()
    preload = threading.Thread(target=preload_writer, args=(spec,), name="preload-writer", daemon=True)
    preload.start()
    with cluster(workers, scheduler) as client:
        client.run(warm_worker, base)
        preload.join()
        t_ready = time.perf_counter()
        stats.cluster_start_s = t_ready - t0
        stats.workers = len(client.scheduler_info().get("workers", {})) or workers
        # The campaign and its base flight (~8 KB pickled) travel inside each task, not
        # scattered: scattered data has no lineage, and the scheduler's active memory manager
        # (ReduceReplicas, every 2 s) drops a broadcast's extra copies, so a worker killed
        # mid-campaign could take the only one with it and every task left was cancelled
        # ("lose scattered data, which can't be recovered"; test_campaign's killed worker)
        futures = []
        for ids in batches(spec, todo, stats.workers):
            key = f"flights-{spec.name}-{ids[0]}-{ids[-1]}"
            futures.append(
                client.submit(run_batch, spec, base, ids, table[ids].tolist(), retries=3, pure=False, key=key)
            )
        done = len(have)
        for fut in as_completed(futures):
            rows = fut.result()
            write_part(out, spec, rows)
            stats.batches += 1
            stats.flights += len(rows)
            stats.failed += sum(1 for r in rows if r["failed"])
            done += len(rows)
            if progress is not None:
                progress(done, total, stats.failed)
        stats.flying_s = time.perf_counter() - t_ready
        stats.wall_s = time.perf_counter() - t0
        if on_cluster is not None:
            on_cluster(client)
    return stats


def render_figures(
    client: Any, spec: CampaignSpec, table: pa.Table, sheets: list[report.Sheet]
) -> Iterator[tuple[report.Sheet, bytes | Exception]]:
    """Each figure of ``sheets`` drawn by a task of its own on the cluster, as it comes in:
    its PNG bytes, or the error its task raised. Only bytes come back, the caller writes the
    files: with ``--scheduler`` the workers may be on another machine."""
    from dask.distributed import as_completed

    spec_f, table_f = client.scatter([spec, table], broadcast=True, hash=False)
    futures = {client.submit(report.render, spec_f, table_f, s, pure=False): s for s in sheets}
    for fut in as_completed(futures):
        yield futures[fut], _png_or_error(fut)


def _png_or_error(fut: Any) -> bytes | Exception:
    try:
        png: bytes = fut.result()
    except Exception as exc:  # the task's own error, or its worker lost: the caller decides
        return exc
    return png
