"""What a campaign answers: a summary table, campaign.json, figures, Sobol indices.

* ``summary_rows``: per numeric metric, p5 / p50 / p95 / max over the flights that did not
  fail, the median and the 95th percentile with their bootstrap 95 % intervals
  (:mod:`heli_sitl.studies.stats`), with the failure and divergence counts and the loss rate's exact
  95 % interval (printed on the console);
* ``hist.png``: each metric's histogram; ``vs_<setting>.png``: each metric against each
  varied setting (diverged flights in red);
* for a grid of two settings, ``map.png`` (of three: ``map_<third>_<level>.png``, one per
  level of the third): RMS[45, end] over the grid with the boundary between the flights
  that converged and those that did not;
* for ``saltelli``: first-order and total Sobol' indices of every numeric metric (SALib),
  ``sobol.csv`` and on the console.

The figures are independent of each other: ``sheets`` lists them, ``render`` draws one to
PNG bytes, the same bytes wherever it runs (a task on the campaign's Dask cluster, or here:
``plots`` draws them all one after the other).
"""

from __future__ import annotations

import contextlib
import csv
import gc
import io
import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa

from heli_sitl.studies import stats
from heli_sitl.studies.campaigns.counts import CampaignCounts, flags, outcomes
from heli_sitl.studies.campaigns.spec import METRICS, CampaignSpec

#: the metrics that are numbers (the rest are flags and text)
NUMERIC = tuple(m for m in METRICS if m not in ("converged", "diverged", "diverged_reason"))


def _col(table: pa.Table, name: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in table.column(name).to_pylist()], dtype=float)


def numeric_metrics(spec: CampaignSpec) -> list[str]:
    return [m for m in spec.metrics if m in NUMERIC]


def summary_rows(spec: CampaignSpec, table: pa.Table) -> list[dict[str, Any]]:
    ok = ~np.array(table.column("failed").to_pylist(), dtype=bool)
    rows = []
    for m in numeric_metrics(spec):
        v = _col(table, m)[ok]
        v = v[np.isfinite(v)]
        if v.size:
            p5, p50, p95 = np.percentile(v, [5, 50, 95])
            c50 = stats.percentile_ci(v, 50, seed=spec.seed)
            c95 = stats.percentile_ci(v, 95, seed=spec.seed)
            rows.append(
                {
                    "metric": m,
                    "n": int(v.size),
                    "p5": float(p5),
                    "p50": float(p50),
                    "p95": float(p95),
                    "max": float(v.max()),
                    "p50_ci": [c50.lo, c50.hi],
                    "p95_ci": [c95.lo, c95.hi],
                }
            )
        else:
            nan2 = [math.nan, math.nan]
            rows.append({"metric": m, "n": 0, "p5": math.nan, "p50": math.nan, "p95": math.nan,
                         "max": math.nan, "p50_ci": nan2, "p95_ci": nan2})  # fmt: skip
    return rows


def format_table(rows: list[dict[str, Any]], c: CampaignCounts) -> str:
    lines = [f"{'metric':24s} {'n':>6s} {'p5':>10s} {'p50 [95 % interval]':>30s} "
             f"{'p95 [95 % interval]':>30s} {'max':>10s}"]  # fmt: skip

    def ci(v: float, c: list[float]) -> str:
        return f"{v:.4g} [{c[0]:.4g}, {c[1]:.4g}]"

    for r in rows:
        lines.append(
            f"{r['metric']:24s} {r['n']:6d} {r['p5']:10.4g} {ci(r['p50'], r['p50_ci']):>30s} "
            f"{ci(r['p95'], r['p95_ci']):>30s} {r['max']:10.4g}"
        )
    lines.append(c.line())
    return "\n".join(lines)


def sobol_indices(spec: CampaignSpec, table: pa.Table) -> list[dict[str, Any]]:
    """First-order and total Sobol' indices (SALib) of each numeric metric, per setting,
    computed on the metric's ranks. The errors are heavy-tailed (1 % of the flights upset
    by metres where the rest differ by millimetres) and on the raw values, or their logs,
    those few own the variance and the indices come out above 1 with confidence intervals
    of tens; on ranks every flight weighs the same. Failed or non-finite flights take the
    median rank (counted in ``replaced``); the 0/1 ``diverged`` gets its own indices when
    at least 1 % of the flights diverged."""
    from SALib.analyze import sobol
    from scipy.stats import rankdata

    from heli_sitl.studies.campaigns.sampling import saltelli_problem

    problem = saltelli_problem(spec)
    failed = flags(table, "failed")
    series = [(m, _col(table, m)) for m in numeric_metrics(spec)]
    # a handful of events carries no variance to apportion: at least 1 % of the flights
    if "diverged" in table.column_names and flags(table, "diverged").mean() >= 0.01:
        series.append(("diverged", flags(table, "diverged").astype(float)))
    out = []
    for name, y in series:
        bad = failed | ~np.isfinite(y)
        if bad.all() or np.std(y[~bad]) == 0.0:
            continue
        r = np.full(y.size, np.nan)
        r[~bad] = rankdata(y[~bad]) / np.count_nonzero(~bad)
        r[bad] = np.median(r[~bad])
        res = sobol.analyze(problem, r, calc_second_order=False, seed=spec.seed)
        for j, k in enumerate(spec.keys):
            out.append({
                "metric": name, "setting": k,
                "S1": float(res["S1"][j]), "S1_conf": float(res["S1_conf"][j]),
                "ST": float(res["ST"][j]), "ST_conf": float(res["ST_conf"][j]),
                "replaced": int(bad.sum()),
            })  # fmt: skip
    return out


def write_sobol(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["metric", "setting", "S1", "S1_conf", "ST", "ST_conf", "replaced"])
        w.writeheader()
        w.writerows(rows)


def format_sobol(rows: list[dict[str, Any]], metric: str) -> str:
    sel = sorted((r for r in rows if r["metric"] == metric), key=lambda r: -r["ST"])
    lines = [
        f"Sobol' indices of {metric} (SALib), by total index:",
        f"{'setting':36s} {'S1':>8s} {'+-':>6s} {'ST':>8s} {'+-':>6s}",
    ]
    lines += [
        f"{r['setting']:36s} {r['S1']:8.3f} {r['S1_conf']:6.3f} {r['ST']:8.3f} {r['ST_conf']:6.3f}"
        for r in sel
    ]
    return "\n".join(lines)


#: a positive metric whose largest value is more than LOG_RATIO times its smallest is drawn on
#: a log axis, and so is one over SKEW_RATIO whose lowest tenth of the range holds most flights:
#: a few lost flights' metres beside the rest's centimetres squash a linear axis to one bar
LOG_RATIO = 100.0
SKEW_RATIO = 10.0

#: each outcome's look in the scatters and the maps: colour and marker differ both, so the
#: outcomes stay apart in grey print and for colour-blind readers
OUTCOME_STYLE: dict[str, dict[str, Any]] = {
    "converged": {"color": "steelblue", "marker": "o"},
    "not_converged": {"color": "orange", "marker": "s"},
    "diverged": {"color": "red", "marker": "^"},
    "failed": {"color": "black", "marker": "x"},
}


def _outcome_labels(
    spec: CampaignSpec, out: dict[str, np.ndarray], failed_note: str, measured: bool
) -> dict[str, str]:
    """What each outcome means, in the words of autopilot.flight_metrics, with its count;
    ``measured``: whether the rows have the converged flag."""
    n = {k: int(v.sum()) for k, v in out.items()}
    conv = f"converged: error < {spec.converge_m:g} m from some time to the end"
    if not measured:  # "converged" is then every flight not lost
        conv = "flown and not lost (convergence not measured)"
    return {
        "converged": f"{conv} ({n['converged']})",
        "not_converged": f"did not converge: flown, not lost, not within {spec.converge_m:g} m at the end "
        f"({n['not_converged']})",
        "diverged": f"diverged: {spec.envelope.describe()} "
        f"({n['diverged']})",
        "failed": f"failed: raised an error, so no metrics; {failed_note} ({n['failed']})",
    }


def _outcome_legend(
    spec: CampaignSpec, table: pa.Table, out: dict[str, np.ndarray], failed_note: str,
    which: tuple[str, ...] = tuple(OUTCOME_STYLE),
) -> list[Any]:  # fmt: skip
    """One handle per outcome of ``which``, drawn or not (a zero count is an answer too)."""
    from matplotlib.lines import Line2D

    labels = _outcome_labels(spec, out, failed_note, "converged" in table.column_names)
    return [Line2D([], [], ls="none", ms=6, label=labels[k], **OUTCOME_STYLE[k]) for k in which]


def _log_axis(v: np.ndarray, zeros_ok: bool) -> bool:
    """Whether values ``v`` want a log axis: positive (zeros too with ``zeros_ok``), the
    positive ones spanning more than :data:`LOG_RATIO`, or more than :data:`SKEW_RATIO`
    with over half of them in the lowest tenth of their range."""
    v = v[np.isfinite(v)]
    pos = v[v > 0]
    if pos.size < 2 or (v < 0).any() or (not zeros_ok and pos.size < v.size):
        return False
    lo, hi = float(pos.min()), float(pos.max())
    squashed = np.mean(pos < lo + 0.1 * (hi - lo)) > 0.5
    return hi > LOG_RATIO * lo or (hi > SKEW_RATIO * lo and bool(squashed))


def _log_ticks(axis: Any) -> None:
    """Plain numbers (0.5, 20, 1e+08) on a log axis, a few minor ones labelled where it spans
    little more than a decade (matplotlib's default is 2x10^0 at full size, overlapping)."""
    from matplotlib.ticker import FuncFormatter, LogFormatter

    axis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    axis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(1.3, 0.5)))


def _no_values(a: Any) -> None:
    """An empty panel says why it is empty rather than leave a newcomer to guess."""
    a.text(0.5, 0.5, "no flight has a value\n(e.g. its window starts after\nthe end, or none converged)",
           ha="center", va="center", fontsize=7, color="0.4", transform=a.transAxes)  # fmt: skip


def _histogram(a: Any, v: np.ndarray, m: str) -> bool:
    """One metric's histogram: log-spaced bins on a log x axis where :func:`_log_axis`
    says so (zeros, which a log axis cannot show, counted in the title); whether log."""
    bins = min(50, max(5, v.size // 10))
    title = m
    log = _log_axis(v, zeros_ok=True)
    if log:
        pos = v[v > 0]
        a.hist(pos, bins=np.geomspace(pos.min(), pos.max(), bins + 1), color="steelblue")
        a.set_xscale("log")
        _log_ticks(a.xaxis)
        zeros = int(v.size - pos.size)
        title += " (log x" + (f"; {zeros} at 0 not shown)" if zeros else ")")
    else:
        try:
            a.hist(v, bins=bins, color="steelblue")
        except ValueError:  # a lost flight's 1e8 m beside mm: no finite bins; say so
            a.text(0.5, 0.5, f"range {v.min():.3g} to {v.max():.3g}", ha="center", fontsize=7,
                   transform=a.transAxes)  # fmt: skip
    a.set_title(title, fontsize=8)
    a.set_ylabel("flights", fontsize=7)
    return log


@dataclass(frozen=True)
class Sheet:
    """One figure of a campaign, drawn on its own (a task of its own on a cluster)."""

    name: str  # the PNG's file name in the campaign's directory
    kind: Literal["hist", "vs", "map"]
    key: str = ""  # vs: the setting on x; map of three settings: the third
    level: float | None = None  # map of three settings: the third's level


def sheets(spec: CampaignSpec) -> list[Sheet]:
    """Every figure of the campaign, in the order campaign.json lists them: the histograms,
    each metric against each varied setting, and for a grid the map(s)."""
    out = [Sheet("hist.png", "hist")]
    for k in spec.keys:
        safe = k.replace(".", "_").replace("[", "_").replace("]", "")
        out.append(Sheet(f"vs_{safe}.png", "vs", key=k))
    if spec.sampler == "grid" and len(spec.keys) == 2:
        out.append(Sheet("map.png", "map"))
    if spec.sampler == "grid" and len(spec.keys) == 3:
        k3 = spec.keys[2]
        for level in spec.vary[2].levels():
            out.append(Sheet(f"map_{k3.replace('.', '_')}_{level:g}.png", "map", key=k3, level=level))
    return out


#: pyplot keeps one list of open figures per process: a Dask worker with several threads
#: draws one figure at a time
_PYPLOT = threading.Lock()


def render(spec: CampaignSpec, table: pa.Table, sheet: Sheet) -> bytes:
    """One figure of ``sheet`` as PNG bytes (Agg), a function of the arguments alone: run on
    a Dask worker (which may be on another machine: the caller writes the file) or here."""
    import matplotlib

    with _PYPLOT, _collector_paused():
        matplotlib.use("Agg")
        if sheet.kind == "hist":
            return _hist_sheet(spec, table)
        if sheet.kind == "vs":
            return _vs_sheet(spec, table, sheet.key)
        return _map_sheet(spec, table, sheet)


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off while a figure is drawn. matplotlib makes some
    10^5 objects a figure, alive until it closes, which with the collector on set off full
    collections: each a walk over every object of the process, some 3x10^5 in a worker that
    has flown (0.1-0.2 s a figure, a tenth of its time). The figure's garbage is freed as it
    closes by a collection of the young objects alone."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()
        gc.collect(0)


def plots(spec: CampaignSpec, table: pa.Table, out: Path) -> list[Path]:
    """Every figure drawn here, one after the other, and written to ``out``."""
    files = []
    for sheet in sheets(spec):
        files.append(out / sheet.name)
        files[-1].write_bytes(render(spec, table, sheet))
    return files


def _lay_out(fig: Any) -> None:
    """``fig.tight_layout()``, without the placeholder layout engine it leaves on the figure,
    for which savefig would go through the whole figure once more before drawing it (to lay
    it out again: no change)."""
    from matplotlib.layout_engine import TightLayoutEngine

    TightLayoutEngine().execute(fig)


def _png(fig: Any, dpi: float, tight: bool) -> bytes:
    """``fig`` (laid out by :func:`_lay_out`) as PNG, byte for byte as ``savefig(dpi=dpi,
    bbox_inches="tight" if tight else None)``, which for "tight" goes through the whole figure
    once before measuring the box; the box is measured directly."""
    box = _tight_box_in(fig, dpi) if tight else None
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches=box)
    return buf.getvalue()


def _tight_box_in(fig: Any, dpi: float) -> Any:
    """The box savefig(bbox_inches="tight") crops to [in]: every artist's extent, measured
    at the saving dpi (text extents depend on it), padded by savefig.pad_inches."""
    from matplotlib import rcParams

    shown = fig.dpi
    fig.dpi = dpi
    try:
        box = fig.get_tightbbox(fig.canvas.get_renderer())
    finally:
        fig.dpi = shown
    pad = rcParams["savefig.pad_inches"]
    return box.padded(pad, pad)


def _sheet(n: int) -> tuple[Any, list[Any]]:
    """A figure of ``n`` panels, at most four across; a grid cell left over gets no axes (an
    empty axes turned off would draw nothing and change no layout, but cost its share)."""
    import matplotlib.pyplot as plt

    cols = min(4, n)
    rows_ = math.ceil(n / cols)
    fig = plt.figure(figsize=(3.2 * cols, 2.6 * rows_))
    grid = fig.add_gridspec(rows_, cols)
    return fig, [fig.add_subplot(grid[i // cols, i % cols]) for i in range(n)]


def _hist_sheet(spec: CampaignSpec, table: pa.Table) -> bytes:
    import matplotlib.pyplot as plt

    outcome = outcomes(table)
    ok = ~outcome["failed"]
    mets = numeric_metrics(spec)
    fig, axs = _sheet(len(mets))
    any_log = False
    for a, m in zip(axs, mets, strict=True):
        v = _col(table, m)[ok]
        v = v[np.isfinite(v)]
        if v.size:
            any_log |= _histogram(a, v, m)
        else:
            a.set_title(m, fontsize=8)
            _no_values(a)
        a.tick_params(which="both", labelsize=7)
    failed = int(outcome["failed"].sum())
    title = f"campaign {spec.name}: {int(ok.sum())} flights flown"
    title += f" ({failed} more failed: no metrics)" if failed else ""
    if any_log:
        title += "\n(log x): log-spaced bins, for a positive metric that a few large values would squash"
    fig.suptitle(title, fontsize=9)
    _lay_out(fig)
    png = _png(fig, 100, tight=False)
    plt.close(fig)
    return png


def _vs_sheet(spec: CampaignSpec, table: pa.Table, k: str) -> bytes:
    """Each metric against setting ``k``, one point per flight coloured by its outcome."""
    import matplotlib.pyplot as plt

    outcome = outcomes(table)
    ok = ~outcome["failed"]
    failed = int(outcome["failed"].sum())
    mets = numeric_metrics(spec)
    # a failed flight has its settings but no metric: a cross on each panel's bottom edge
    handles = _outcome_legend(spec, table, outcome, "x on each panel's bottom edge")
    x = _col(table, k)
    fig, axs = _sheet(len(mets))
    for a, m in zip(axs, mets, strict=True):
        y = _col(table, m)
        title = m
        if _log_axis(y[ok], zeros_ok=False):  # lost flights' metres beside the rest's mm
            a.set_yscale("log")
            _log_ticks(a.yaxis)
            title += " (log y)"
        for name, sel in outcome.items():
            if name != "failed":
                a.plot(x[sel], y[sel], ls="none", ms=3, alpha=0.8, **OUTCOME_STYLE[name])
        if failed:  # (an empty unclipped line would stretch the tight layout to the origin)
            a.plot(x[outcome["failed"]], np.zeros(failed), ls="none", ms=5, clip_on=False,
                   transform=a.get_xaxis_transform(), **OUTCOME_STYLE["failed"])  # fmt: skip
        if not np.isfinite(y[ok]).any():
            _no_values(a)
        a.set_title(title, fontsize=8)
        a.set_xlabel(k, fontsize=7)
        a.tick_params(which="both", labelsize=7)
    fig.suptitle(f"campaign {spec.name}: each metric against {k}, one point per flight", fontsize=9)
    _lay_out(fig)
    # below the panels, never over a point; the tight box takes it in
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0),
               ncol=2 if len(mets) > 2 else 1, fontsize=8, frameon=False)  # fmt: skip
    png = _png(fig, 100, tight=True)
    plt.close(fig)
    return png


def _map_sheet(spec: CampaignSpec, table: pa.Table, sheet: Sheet) -> bytes:
    """A grid's map: of two settings all flights; of three, those at the third's level."""
    if sheet.level is None:
        return _grid_map(spec, table, np.ones(table.num_rows, bool), "")
    sel = np.isclose(_col(table, sheet.key), sheet.level)
    return _grid_map(spec, table, sel, f", {sheet.key} = {sheet.level:g}")


def _grid_map(spec: CampaignSpec, table: pa.Table, sel: np.ndarray, note: str) -> bytes:
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    k1, k2 = spec.keys[:2]
    x1, x2 = (np.array(spec.vary[i].levels()) for i in (0, 1))
    metric = "rms_45_m" if "rms_45_m" in spec.metrics else numeric_metrics(spec)[0]
    z = np.full((x2.size, x1.size), np.nan)
    d = np.zeros((x2.size, x1.size))
    v1, v2, m = _col(table, k1)[sel], _col(table, k2)[sel], _col(table, metric)[sel]
    outcome = {k: v[sel] for k, v in outcomes(table).items()}
    for a, b, val, dv, fl in zip(v1, v2, m, ~outcome["converged"], outcome["failed"], strict=True):
        i, j = int(np.argmin(np.abs(x2 - b))), int(np.argmin(np.abs(x1 - a)))
        z[i, j] = val
        # a failed flight says nothing about convergence: a hole in the boundary, not a loss
        d[i, j] = np.nan if fl else (1.0 if dv else 0.0)
    fig, ax = plt.subplots(figsize=(6.5, 5))
    pc = ax.pcolormesh(x1, x2, np.log10(np.maximum(z, 1e-4)), shading="nearest", cmap="viridis")
    fig.colorbar(pc, ax=ax, label=f"log10 {metric} [m]")
    if 0.0 < np.nansum(d) < np.isfinite(d).sum() and x1.size > 1 and x2.size > 1:
        ax.contour(x1, x2, np.ma.masked_invalid(d), levels=[0.5], colors="red", linewidths=2)
    # each flight that did not converge marked by how it ended: a failed one (no metric, a
    # blank cell) is the bench's fault, not the controller's, and must not read as a loss
    marked = ("not_converged", "diverged", "failed")
    for k in marked:
        rim: dict[str, Any] = {"mec": "white", "mew": 0.8} if k != "failed" else {"mew": 1.5}  # x: all rim
        ax.plot(v1[outcome[k]], v2[outcome[k]], ls="none", ms=6, **OUTCOME_STYLE[k], **rim)
    ax.set_xlabel(k1)
    ax.set_ylabel(k2)
    ax.set_title(f"{spec.name}{note}: {metric} (colour) over the grid", fontsize=9)
    n_conv = int(outcome["converged"].sum())
    edge = Line2D([], [], color="red", lw=2, label="edge of the converged region; an unmarked cell converged "
                  f"(error < {spec.converge_m:g} m to the end; {n_conv})")  # fmt: skip
    handles = [edge, *_outcome_legend(spec, table, outcome, "a blank cell", marked)]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=7, frameon=False)
    _lay_out(fig)
    png = _png(fig, 110, tight=True)
    plt.close(fig)
    return png
