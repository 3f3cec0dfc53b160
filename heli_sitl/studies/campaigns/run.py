"""``heli-sitl campaign FILE --out DIR``: check the file, fly its samples on Dask, report.

Re-running the same command on the same DIR resumes (the flights already written are
skipped); DIR remembers which campaign it holds and refuses another one. The figures are
drawn on the campaign's cluster before it closes (here, one after the other, when nothing
was left to fly); a figure that cannot be drawn is reported, never at the cost of the
results or campaign.json.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from autopilot.estimation.config import EstimatorConfig
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from autopilot.user_controller import is_user_spec, normalise_spec
from heli_common.config import ConfigError
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_sitl.studies.campaigns import engine, report
from heli_sitl.studies.campaigns.counts import CampaignCounts
from heli_sitl.studies.campaigns.flight import METRIC_DOC
from heli_sitl.studies.campaigns.sampling import sample_table
from heli_sitl.studies.campaigns.settings import FlightSetup, canonical, check
from heli_sitl.studies.campaigns.spec import CampaignSpec, Vary, load_campaign

ID_FILE = "campaign-id.json"


def base_flight(spec: CampaignSpec) -> FlightSetup:
    sc = Scenario.load(spec.scenario, gains=spec.gains or None)
    if spec.feedforward:
        sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, feedforward=spec.feedforward))
    world = World.load(spec.world) if spec.world else World()
    est = EstimatorConfig.load(spec.estimator) if spec.estimator else EstimatorConfig()
    pid = PidGains.load(spec.pid_gains) if spec.pid_gains else None
    return FlightSetup(sc, world, est, spec.controller, pid, PlantModel.load(spec.plant))


def _probes(v: Vary) -> list[float]:
    if v.dist in ("grid", "choice"):
        return list(v.levels())
    if v.dist == "normal":
        return [v.mean]
    return [v.low, v.high] + ([v.mean] if v.dist == "truncnormal" else [])


def prepare(
    path: str | Path | CampaignSpec, samples: int | None = None, controller: str | None = None
) -> tuple[CampaignSpec, FlightSetup, np.ndarray]:
    """The checked campaign (a file, a name, or a spec already loaded), its base flight and
    its sample table; ConfigError naming the key for anything wrong, before a single flight.
    ``controller`` overrides the file's."""
    spec = path if isinstance(path, CampaignSpec) else load_campaign(path)
    if controller is not None:
        spec = dataclasses.replace(spec, controller=normalise_spec(controller))
    if samples is not None:
        if samples < 1:
            raise ConfigError(f"--samples: expected >= 1, got {samples}")
        spec = dataclasses.replace(spec, samples=samples)
    base = base_flight(spec)
    canon = tuple(canonical(v.key) for v in spec.vary)
    if len(set(canon)) != len(canon):
        raise ConfigError(f"{spec.source}: vary: two keys name the same setting ({', '.join(spec.keys)})")
    # another controller's gains would change nothing: flights that differ in name only
    for prefix, owner in (("pid.", "pid"), ("gains.", "tlc")):
        flown = "your controller" if is_user_spec(spec.controller) else f"the {spec.controller.upper()}"
        for v in spec.vary:
            if owner != spec.controller and canonical(v.key).startswith(prefix):
                raise ConfigError(
                    f"{v.key}: varies the {owner.upper()}'s gains, but the campaign flies {flown} "
                    f'(set controller = "{owner}", or --controller {owner})'
                )
    for v in spec.vary:
        check(base, v.key, _probes(v))
    spec = dataclasses.replace(
        spec, vary=tuple(dataclasses.replace(v, key=k) for v, k in zip(spec.vary, canon, strict=True))
    )
    table = sample_table(spec)
    if spec.sampler == "grid" and samples is not None:
        table = table[:samples]
    return spec, base, table


def _identity(spec: CampaignSpec, table: np.ndarray, base: FlightSetup) -> dict[str, Any]:
    """What a directory's rows were flown with: the spec, the samples, and what the files the
    spec names held (a gain file edited since is another campaign: its rows would be stale,
    as a resumed comparison once reported a PID's old gains beside its new ones)."""
    h = hashlib.sha256(json.dumps(dataclasses.asdict(spec), sort_keys=True, default=str).encode())
    h.update(np.ascontiguousarray(table).tobytes())
    # frozen dataclasses loaded from the files: their repr is the values, the same in every process
    loaded = (base.scenario.gains, base.pid_gains, base.plant, base.scenario.airframe, base.world,
              base.estimator)  # fmt: skip
    h.update(repr(loaded).encode())
    return {
        "name": spec.name,
        "source": spec.source,
        "flights": int(table.shape[0]),
        "hash": h.hexdigest()[:16],
    }


def _claim(out: Path, ident: dict[str, Any]) -> None:
    f = out / ID_FILE
    if f.is_file():
        old = json.loads(f.read_text())
        if old.get("hash") != ident["hash"]:
            raise ConfigError(
                f"{out}: holds the results of another campaign ({old.get('name')}, "
                f"{old.get('flights')} flights); use another --out"
            )
        return
    out.mkdir(parents=True, exist_ok=True)
    f.write_text(json.dumps(ident, indent=2) + "\n")


def versions() -> dict[str, str]:
    from importlib.metadata import version

    import numba
    import pyarrow
    import scipy

    return {
        "heli-tlc-sitl": engine.software_version(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "dask": version("dask"),
        "distributed": version("distributed"),
        "pyarrow": pyarrow.__version__,
        "machine": f"{platform.system()} {platform.machine()}, {os.cpu_count()} CPUs",
    }


@dataclass
class Figures:
    """A campaign's figures, drawn on its cluster while it is up (:meth:`on_cluster`, given
    to ``engine.run``), and here (:meth:`finish`) where no cluster ran or a figure's task
    failed there: the same pictures either way (:func:`report.render` draws both)."""

    spec: CampaignSpec
    out: Path
    quiet: bool = False
    draw: bool = True  # False: rows and campaign.json only (a re-run over ``out`` draws them)
    results: pa.Table | None = None  # the rows, collected while the cluster is up
    written: set[str] = field(default_factory=set)
    errors: dict[str, str] = field(default_factory=dict)  # not drawn: why
    seconds: float = 0.0

    def on_cluster(self, client: Any) -> None:
        """Every flight is in: collect the rows, then one task per figure, each file written
        here as its bytes come in."""
        self.results = engine.collect(self.out, self.spec)
        t0 = time.perf_counter()
        plan = self.plan()
        if not plan:
            return
        try:
            for sheet, png in engine.render_figures(client, self.spec, self.results, plan):
                if isinstance(png, bytes):
                    (self.out / sheet.name).write_bytes(png)
                    self.written.add(sheet.name)
                else:
                    self._say(f"figure {sheet.name}: its task failed on the cluster ({png!r}); drawn here")
        except Exception as exc:  # the cluster itself (scheduler lost): the rest drawn here
            self._say(f"figures: the cluster failed ({exc!r}); the rest drawn here")
        self.seconds += time.perf_counter() - t0

    def finish(self) -> tuple[pa.Table, list[str]]:
        """Draw here every figure not drawn on the cluster: the rows, and the names of the
        figures written in the campaign's order of figures."""
        results = self.results if self.results is not None else engine.collect(self.out, self.spec)
        t0 = time.perf_counter()
        plan = self.plan()
        for sheet in plan:
            if sheet.name in self.written:
                continue
            try:
                (self.out / sheet.name).write_bytes(report.render(self.spec, results, sheet))
                self.written.add(sheet.name)
            except Exception as exc:  # a figure is not worth the campaign's results: say so
                self.errors[sheet.name] = repr(exc)
                print(f"heli-sitl: figure {sheet.name} not drawn: {exc!r}", file=sys.stderr)
        self.seconds += time.perf_counter() - t0
        return results, [s.name for s in plan if s.name in self.written]

    def plan(self) -> list[report.Sheet]:
        return report.sheets(self.spec) if self.draw else []

    def _say(self, line: str) -> None:
        if not self.quiet:
            print(f"heli-sitl: {line}", file=sys.stderr)


def run_campaign(
    path: str | Path | CampaignSpec,
    out: Path,
    samples: int | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    quiet: bool = False,
    controller: str | None = None,
    figures: bool = True,
) -> dict[str, Any]:
    """Fly every sample of the campaign not yet in ``out`` (a re-run resumes), then write its
    rows, campaign.json and (unless ``figures`` is False: a thousand-flight campaign's rows
    without its ~2 s of CPU a figure; a re-run over ``out`` draws them) its figures."""
    t_start = time.perf_counter()
    spec, base, table = prepare(path, samples, controller)
    ident = _identity(spec, table, base)
    _claim(out, ident)
    n_workers = workers or os.cpu_count() or 1
    from tqdm import tqdm

    drawing = Figures(spec, out, quiet, draw=figures)
    with tqdm(
        total=table.shape[0], desc=f"campaign {spec.name}", unit="flight", smoothing=0.1,
        disable=True if quiet else None,  # None: off where not a terminal (a log)
    ) as bar:

        def progress(done: int, total: int, failed: int) -> None:
            bar.n = done
            bar.set_postfix(failed=failed, refresh=False)
            bar.refresh()

        stats = engine.run(spec, base, table, out, n_workers, scheduler, progress, drawing.on_cluster)
    results, drawn = drawing.finish()
    wall = time.perf_counter() - t_start  # to the rows and the figures
    duration = spec.duration_s or base.scenario.run.duration_s
    c = CampaignCounts.of(results, sampled=spec.sampler != "grid")
    rows = report.summary_rows(spec, results)
    workers_used = stats.workers or n_workers
    flown_s = stats.flights * duration
    # the pace while flying (the cluster up); its start is reported apart (cluster_start_s)
    throughput = flown_s / stats.flying_s if stats.flying_s > 0 else math.nan
    walls = np.array([w for w in results.column("wall_s").to_pylist() if w is not None and w > 0])
    # each worker's own pace, flight by flight: throughput against it is what scheduling,
    # start-up and the engine cost (the benchmark measures against one process alone)
    rate1 = float(duration / walls.mean()) if walls.size else math.nan
    summary: dict[str, Any] = {
        "campaign": ident,
        "spec": dataclasses.asdict(spec),
        "versions": versions(),
        "counts": c.as_dict(),
        "metrics": rows,
        "metric_doc": {k: METRIC_DOC[k] for k in spec.metrics},
        "run": {
            "flown_now": stats.flights,
            "failed_now": stats.failed,
            "batches": stats.batches,
            "workers": workers_used,
            "scheduler": stats.scheduler,
            "cluster_start_s": stats.cluster_start_s,
            "engine_wall_s": stats.wall_s,
            "flying_s": stats.flying_s,
            "figures_s": drawing.seconds,
            "total_wall_s": wall,
            "vehicle_s_per_wall_s": throughput,
            "in_worker_flight_rate": rate1,
            "engine_efficiency": throughput / (workers_used * rate1) if stats.flying_s > 0 else math.nan,
        },
    }
    text = report.format_table(rows, c)
    if spec.sampler == "saltelli":
        sob = report.sobol_indices(spec, results)
        report.write_sobol(out / "sobol.csv", sob)
        summary["sobol"] = sob
        if sob:
            first = "rms_45_m" if "rms_45_m" in spec.metrics else sob[0]["metric"]
            text += "\n" + report.format_sobol(sob, first)
    summary["figures"] = drawn
    if drawing.errors:
        summary["figure_errors"] = drawing.errors
    (out / "campaign.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if not quiet:
        print(text)
        if stats.flights:
            eff = summary["run"]["engine_efficiency"]
            print(
                f"{stats.flights} flights in {stats.flying_s:.1f} s on {workers_used} workers "
                f"({stats.scheduler}, started in {stats.cluster_start_s:.1f} s): {throughput:,.0f} "
                f"vehicle-s per wall-s = {eff:.0%} of {workers_used} x a worker's own pace "
                f"({rate1:,.0f}x); figures {drawing.seconds:.1f} s; {wall:.1f} s in all"
            )
        where = f", figures in {out}" if figures else " (no figures: --no-figures)"
        print(f"wrote {out / engine.RESULTS}, {out / 'campaign.json'}{where}")
    return summary
