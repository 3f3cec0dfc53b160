"""What a campaign answers: a summary table, campaign.json, figures, Sobol indices.

* ``summary_rows``: per numeric metric, p5 / p50 / p95 / max over the flights that did not
  fail, the median and the 95th percentile with their bootstrap 95 % intervals
  (:mod:`heli_sitl.stats`), with the failure and divergence counts and the loss rate's exact
  95 % interval (printed on the console);
* ``hist.png``: each metric's histogram; ``vs_<setting>.png``: each metric against each
  varied setting (diverged flights in red);
* for a grid of two settings, ``map.png`` (of three: ``map_<third>_<level>.png``, one per
  level of the third): RMS[45, end] over the grid with the boundary between the flights
  that converged and those that did not;
* for ``saltelli``: first-order and total Sobol' indices of every numeric metric (SALib),
  ``sobol.csv`` and on the console.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from heli_sitl import stats
from heli_sitl.campaign.spec import METRICS, CampaignSpec

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


def _flags(table: pa.Table, name: str) -> np.ndarray:
    if name not in table.column_names:
        return np.zeros(table.num_rows, bool)
    return np.array([bool(v) for v in table.column(name).to_pylist()])


def counts(table: pa.Table) -> dict[str, Any]:
    failed = _flags(table, "failed")
    out: dict[str, Any] = {"flights": int(table.num_rows), "failed": int(failed.sum())}
    if "converged" in table.column_names:
        out["converged"] = int((_flags(table, "converged") & ~failed).sum())
    if "diverged" in table.column_names:
        div = _flags(table, "diverged") & ~failed
        out["diverged"] = int(div.sum())
        if "diverged_reason" in table.column_names:
            reasons = [r for r, d in zip(table.column("diverged_reason").to_pylist(), div, strict=True) if d]
            out["diverged_by_reason"] = {r: reasons.count(r) for r in sorted(set(reasons))}
        flown = out["flights"] - out["failed"]
        if flown > 0:
            rate = stats.loss_rate(out["diverged"], flown)
            out["loss_rate"] = {"estimate": rate.estimate, "ci95": [rate.lo, rate.hi]}
    return out


def format_table(rows: list[dict[str, Any]], c: dict[str, Any]) -> str:
    lines = [f"{'metric':24s} {'n':>6s} {'p5':>10s} {'p50 [95 % interval]':>30s} "
             f"{'p95 [95 % interval]':>30s} {'max':>10s}"]  # fmt: skip

    def ci(v: float, c: list[float]) -> str:
        return f"{v:.4g} [{c[0]:.4g}, {c[1]:.4g}]"

    for r in rows:
        lines.append(
            f"{r['metric']:24s} {r['n']:6d} {r['p5']:10.4g} {ci(r['p50'], r['p50_ci']):>30s} "
            f"{ci(r['p95'], r['p95_ci']):>30s} {r['max']:10.4g}"
        )
    conv = f", converged {c['converged']}" if "converged" in c else ""
    why = "; ".join(f"{k}: {v}" for k, v in c.get("diverged_by_reason", {}).items())
    loss = ""
    if "loss_rate" in c:
        lr = c["loss_rate"]
        loss = (f"; loss rate {100 * lr['estimate']:.2f} % [{100 * lr['ci95'][0]:.2f}, "
                f"{100 * lr['ci95'][1]:.2f}] % (95 %, exact)")  # fmt: skip
    lines.append(
        f"flights {c['flights']}, failed {c['failed']}{conv}, diverged {c.get('diverged', 0)}"
        + (f" ({why})" if why else "") + loss
    )
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

    from heli_sitl.campaign.sampling import saltelli_problem

    problem = saltelli_problem(spec)
    failed = _flags(table, "failed")
    series = [(m, _col(table, m)) for m in numeric_metrics(spec)]
    # a handful of events carries no variance to apportion: at least 1 % of the flights
    if "diverged" in table.column_names and _flags(table, "diverged").mean() >= 0.01:
        series.append(("diverged", _flags(table, "diverged").astype(float)))
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


def plots(spec: CampaignSpec, table: pa.Table, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = ~_flags(table, "failed")
    div = _flags(table, "diverged")
    conv = _flags(table, "converged") if "converged" in table.column_names else ~div
    mets = numeric_metrics(spec)
    files = []
    n = len(mets)
    cols = min(4, n)
    rows_ = math.ceil(n / cols)
    fig, axs = plt.subplots(rows_, cols, figsize=(3.2 * cols, 2.6 * rows_), squeeze=False)
    for a, m in zip(axs.flat, mets, strict=False):
        v = _col(table, m)[ok]
        v = v[np.isfinite(v)]
        if v.size:
            try:
                a.hist(v, bins=min(50, max(5, v.size // 10)), color="steelblue")
            except ValueError:  # a lost flight's 1e8 m beside mm: no finite bins; say so
                a.text(0.5, 0.5, f"range {v.min():.3g} to {v.max():.3g}", ha="center", fontsize=7,
                       transform=a.transAxes)  # fmt: skip
        a.set_title(m, fontsize=8)
        a.tick_params(labelsize=7)
    for a in list(axs.flat)[n:]:
        a.axis("off")
    fig.suptitle(f"campaign {spec.name}: {int(ok.sum())} flights", fontsize=9)
    fig.tight_layout()
    files.append(out / "hist.png")
    fig.savefig(files[-1], dpi=100)
    plt.close(fig)
    for k in spec.keys:
        x = _col(table, k)
        fig, axs = plt.subplots(rows_, cols, figsize=(3.2 * cols, 2.6 * rows_), squeeze=False)
        for a, m in zip(axs.flat, mets, strict=False):
            y = _col(table, m)
            a.plot(x[ok & conv], y[ok & conv], ".", ms=3, color="steelblue", label="converged")
            a.plot(
                x[ok & ~conv & ~div], y[ok & ~conv & ~div], ".", ms=3, color="orange", label="not converged"
            )
            a.plot(x[ok & div], y[ok & div], ".", ms=3, color="red", label="diverged")
            a.set_title(m, fontsize=8)
            a.set_xlabel(k, fontsize=7)
            a.tick_params(labelsize=7)
        for a in list(axs.flat)[n:]:
            a.axis("off")
        fig.tight_layout()
        safe = k.replace(".", "_").replace("[", "_").replace("]", "")
        files.append(out / f"vs_{safe}.png")
        fig.savefig(files[-1], dpi=100)
        plt.close(fig)
    if spec.sampler == "grid" and len(spec.keys) == 2:
        files.append(grid_map(spec, table, out, np.ones(table.num_rows, bool), "map.png", ""))
    if spec.sampler == "grid" and len(spec.keys) == 3:
        k3 = spec.keys[2]
        v3 = _col(table, k3)
        for level in spec.vary[2].levels():
            sel = np.isclose(v3, level)
            name = f"map_{k3.replace('.', '_')}_{level:g}.png"
            files.append(grid_map(spec, table, out, sel, name, f", {k3} = {level:g}"))
    return files


def grid_map(spec: CampaignSpec, table: pa.Table, out: Path, sel: np.ndarray, name: str, note: str) -> Path:
    import matplotlib.pyplot as plt

    k1, k2 = spec.keys[:2]
    x1, x2 = (np.array(spec.vary[i].levels()) for i in (0, 1))
    metric = "rms_45_m" if "rms_45_m" in spec.metrics else numeric_metrics(spec)[0]
    z = np.full((x2.size, x1.size), np.nan)
    d = np.zeros((x2.size, x1.size))
    v1, v2, m = _col(table, k1)[sel], _col(table, k2)[sel], _col(table, metric)[sel]
    conv = _flags(table, "converged") if "converged" in table.column_names else ~_flags(table, "diverged")
    div = (~conv | _flags(table, "failed"))[sel]
    for a, b, val, dv in zip(v1, v2, m, div, strict=True):
        i, j = int(np.argmin(np.abs(x2 - b))), int(np.argmin(np.abs(x1 - a)))
        z[i, j] = val
        d[i, j] = 1.0 if dv else 0.0
    fig, ax = plt.subplots(figsize=(6.5, 5))
    pc = ax.pcolormesh(x1, x2, np.log10(np.maximum(z, 1e-4)), shading="nearest", cmap="viridis")
    fig.colorbar(pc, ax=ax, label=f"log10 {metric} [m]")
    if 0.0 < d.sum() < d.size and x1.size > 1 and x2.size > 1:
        ax.contour(x1, x2, d, levels=[0.5], colors="red", linewidths=2)
    xx, yy = np.meshgrid(x1, x2)
    ax.plot(xx[d > 0.5], yy[d > 0.5], "rx", ms=5, label="not converged")
    ax.set_xlabel(k1)
    ax.set_ylabel(k2)
    ax.set_title(f"{spec.name}{note}: {metric}; x and red line: not converged", fontsize=9)
    fig.tight_layout()
    path = out / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
