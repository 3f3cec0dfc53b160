"""``heli-sitl compare``: the controllers side by side on the same flights.

A comparison file (``configs/compare.toml``) names the contenders (a controller, its gains,
the TLC's feed-forward) and what they all fly:

* **nominal**: the paper scenario in the ideal world, one flight each;
* **worlds**: the same scenario in each world preset (air, servos, model mismatch, sensors
  through the estimator), one flight each with the same world seed;
* **campaigns**: the shipped campaigns (robustness Monte Carlo, the servo margins grid, the
  region of attraction), each flown by every contender with the same samples and seeds,
  on one Dask cluster; their Parquet rows stay in ``--work`` (a re-run resumes them).

Written to ``--out``: ``report.md`` (every table, and the command that made it),
``comparison.json`` (the same numbers) and the overlay figures.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from autopilot.estimation.config import EstimatorConfig
from autopilot.metrics import FlightRecord
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from heli_common.config import CONFIG_DIR, ConfigError, read_toml, resolve
from heli_common.plant_model import PlantModel
from heli_common.state import PSI
from heli_common.world import World
from heli_sitl.campaign import engine
from heli_sitl.campaign.flight import flight_seed, metrics
from heli_sitl.campaign.run import run_campaign
from heli_sitl.campaign.settings import canonical
from heli_sitl.campaign.spec import CampaignSpec, load_campaign
from heli_sitl.closed_loop import SimOptions, simulate

TOP_KEYS = ("name", "scenario", "plant", "worlds", "campaigns", "contender")
CONTENDER_KEYS = ("label", "controller", "gains", "pid_gains", "feedforward")
FLIGHT_METRICS = (
    "rms_0_m",
    "rms_10_m",
    "rms_45_m",
    "max_err_10_m",
    "pitch_travel_rad",
    "max_servo_rate_rad_s",
    "saturated_ticks",
    "max_tilt_rad",
    "converged",
    "diverged",
)
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")


@dataclass(frozen=True)
class Contender:
    label: str
    controller: str = "tlc"
    gains: str = ""  # the TLC's ("": the scenario's)
    pid_gains: str = ""  # "": configs/gains_pid.toml
    feedforward: str = ""  # the TLC's ("": the scenario's)

    @property
    def slug(self) -> str:
        return re.sub(r"[^a-z0-9]+", "-", self.label.lower()).strip("-")


@dataclass(frozen=True)
class CompareSpec:
    name: str
    contenders: tuple[Contender, ...]
    scenario: str = "paper"
    worlds: tuple[str, ...] = ()
    campaigns: tuple[str, ...] = ()
    source: str = ""
    plant: str = "paper"  # every flight's plant: paper, gavrilets or a plant file


def load_compare(path: str | Path = "compare.toml") -> CompareSpec:
    """A comparison file (as given, or in configs/), checked: unknown keys, a controller
    that is not tlc or pid, a gains file, world or campaign that does not load."""
    p, t = read_toml(path)
    src = str(p)
    for k in t:
        if k not in TOP_KEYS:
            raise ConfigError(f"{src}: unknown key {k!r}; expected one of {', '.join(TOP_KEYS)}")
    raw = t.get("contender", [])
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{src}: expected at least one [[contender]]")
    contenders = []
    for i, c in enumerate(raw):
        where = f"{src}: contender[{i}]"
        if not isinstance(c, dict) or not isinstance(c.get("label"), str) or not c["label"]:
            raise ConfigError(f"{where}: a table with a label")
        for k, v in c.items():
            if k not in CONTENDER_KEYS:
                raise ConfigError(f"{where}: unknown key {k!r}; expected one of {', '.join(CONTENDER_KEYS)}")
            if not isinstance(v, str):
                raise ConfigError(f"{where}.{k}: expected a string, got {v!r}")
        con = Contender(**c)
        if con.controller not in ("tlc", "pid"):
            raise ConfigError(f'{where}.controller: expected "tlc" or "pid", got {con.controller!r}')
        if con.feedforward not in ("", "pseudo", "exact"):
            raise ConfigError(f'{where}.feedforward: expected "pseudo" or "exact", got {con.feedforward!r}')
        contenders.append(con)
    labels = [c.label for c in contenders]
    if len({c.slug for c in contenders}) != len(contenders):
        raise ConfigError(f"{src}: contender labels must differ ({', '.join(labels)})")
    lists = {}
    for k in ("worlds", "campaigns"):
        v = t.get(k, [])
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise ConfigError(f"{src}: {k}: expected an array of names")
        lists[k] = tuple(v)
    spec = CompareSpec(
        str(t.get("name", p.stem)),
        tuple(contenders),
        str(t.get("scenario", "paper")),
        lists["worlds"],
        lists["campaigns"],
        src,
        str(t.get("plant", "paper")),
    )
    PlantModel.load(spec.plant)
    for c in spec.contenders:  # every file loads before anything flies
        scenario_for(spec.scenario, c)
        if c.pid_gains:
            PidGains.load(c.pid_gains)
    for w in spec.worlds:
        World.load(w)
    for name in spec.campaigns:
        load_campaign(name)
    return spec


def scenario_for(name: str, c: Contender) -> Scenario:
    sc = Scenario.load(name, gains=c.gains or None)
    if c.feedforward:
        sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, feedforward=c.feedforward))
    return sc


def estimator_for(world: str) -> EstimatorConfig:
    """The estimator tuned for a sensor preset where one is shipped (configs/estimator/)."""
    f = CONFIG_DIR / "estimator" / f"{Path(world).stem}.toml"
    return EstimatorConfig.load(f) if world and f.is_file() else EstimatorConfig()


# ----------------------------------------------------------------------------- flights


def fly(
    spec: CompareSpec, c: Contender, world: str = "", seed: int = 1
) -> tuple[dict[str, Any], FlightRecord]:
    """One flight of ``c`` in ``world`` ("" the ideal one), with the campaigns' metrics."""
    sc = scenario_for(spec.scenario, c)
    w = dataclasses.replace(World.load(world), seed=seed) if world else None
    if w is not None:
        w = dataclasses.replace(w, sensors=dataclasses.replace(w.sensors, seed=seed))
    opts = SimOptions(
        world=w,
        estimator=estimator_for(world),
        controller=c.controller,
        pid_gains=PidGains.load(c.pid_gains) if c.pid_gains else None,
        plant=PlantModel.load(spec.plant),
    )
    rec = simulate(sc, opts)
    m = metrics(rec, CampaignSpec(name="compare", metrics=FLIGHT_METRICS))
    m["saturated_pct"] = 100.0 * m.pop("saturated_ticks") / max(1, rec.t_s.size)
    # the tuning cost knows only the position: the heading is reported beside it
    yaw_err = np.angle(np.exp(1j * (rec.psi_cmd - rec.x[:, PSI])))[rec.window(10.0, float(rec.t_s[-1]))]
    m["rms_yaw_10_deg"] = float(np.degrees(np.sqrt(np.mean(yaw_err**2)))) if yaw_err.size else math.nan
    return m, rec


def campaign_spec(name: str, c: Contender, samples: int | None, plant: str = "paper") -> CampaignSpec:
    spec = load_campaign(name)
    spec = dataclasses.replace(
        spec,
        plant=plant,
        controller=c.controller,
        gains=c.gains or spec.gains,
        pid_gains=c.pid_gains,
        feedforward=c.feedforward or spec.feedforward,
    )
    if samples is not None and spec.sampler != "grid":
        spec = dataclasses.replace(spec, samples=samples)
    # the settings by their full names, as the rows' columns carry them
    return dataclasses.replace(
        spec, vary=tuple(dataclasses.replace(v, key=canonical(v.key)) for v in spec.vary)
    )


def _col(t: pa.Table, name: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in t.column(name).to_pylist()], dtype=float)


def _flag(t: pa.Table, name: str) -> np.ndarray:
    return np.array([bool(v) for v in t.column(name).to_pylist()])


def largest_converged(t: pa.Table, key: str, fixed: dict[str, float] | None = None) -> float:
    """The largest level of ``key`` up to which every flight converged (with the other keys
    at ``fixed`` values, or at every level when ``fixed`` is None); NaN if not the first."""
    x = _col(t, key)
    ok = _flag(t, "converged") & ~_flag(t, "failed")
    sel = np.ones(x.size, bool)
    for k, v in (fixed or {}).items():
        sel &= np.isclose(_col(t, k), v)
    best = math.nan
    for level in np.unique(x[sel]):
        if not ok[sel & (x == level)].all():
            break
        best = float(level)
    return best


def campaign_summary(t: pa.Table, spec: CampaignSpec) -> dict[str, Any]:
    failed = _flag(t, "failed")
    out: dict[str, Any] = {
        "flights": int(t.num_rows),
        "failed": int(failed.sum()),
        "converged": int((_flag(t, "converged") & ~failed).sum()),
        "diverged": int((_flag(t, "diverged") & ~failed).sum()),
    }
    for m in ("rms_10_m", "rms_45_m", "max_err_10_m", "pitch_travel_rad", "converge_s"):
        v = _col(t, m)[~failed]
        v = v[np.isfinite(v)]
        out[m] = (
            {"p50": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
            if (v.size)
            else {"p50": math.nan, "p95": math.nan, "max": math.nan}
        )
    keys = spec.keys
    if spec.sampler == "grid" and keys:
        low = {k: float(np.nanmin(_col(t, k))) for k in keys}
        out["largest_converged"] = {
            k: largest_converged(t, k, {o: low[o] for o in keys if o != k}) for k in keys
        }
        out["largest_converged_all"] = {k: largest_converged(t, k) for k in keys}
    return out


# ----------------------------------------------------------------------------- report


def _f(v: Any, fmt: str = ".3f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, fmt)


def md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def nominal_table(res: dict[str, Any]) -> str:
    header = [
        "controller",
        "RMS [0,end] m",
        "RMS [10,end] m",
        "RMS [45,end] m",
        "max from 10 s m",
        "pitch travel rad",
        "max pitch rate rad/s",
        "saturated %",
        "max tilt deg",
        "RMS yaw error [10,end] deg",
    ]
    rows = [
        [
            lab,
            _f(m["rms_0_m"]),
            _f(m["rms_10_m"]),
            _f(m["rms_45_m"], ".4f"),
            _f(m["max_err_10_m"]),
            _f(m["pitch_travel_rad"], ".2f"),
            _f(m["max_servo_rate_rad_s"], ".2f"),
            _f(m["saturated_pct"], ".2f"),
            _f(math.degrees(m["max_tilt_rad"]), ".1f"),
            _f(m["rms_yaw_10_deg"], ".2f"),
        ]
        for lab, m in res.items()
    ]
    return md_table(header, rows)


def worlds_table(res: dict[str, dict[str, Any]], labels: list[str]) -> str:
    header = ["world"] + [f"{lab}: RMS [10,end] / max from 10 s m" for lab in labels]
    rows = []
    for world, by in res.items():
        cells = [world]
        for lab in labels:
            m = by[lab]
            tag = " (lost)" if m["diverged"] else ""
            cells.append(f"{_f(m['rms_10_m'])} / {_f(m['max_err_10_m'], '.2f')}{tag}")
        rows.append(cells)
    return md_table(header, rows)


def campaign_table(res: dict[str, dict[str, Any]]) -> str:
    first = next(iter(res.values()))
    header = [
        "controller",
        "flights",
        "converged",
        "lost",
        "RMS [10,end] p50 / p95 m",
        "RMS [45,end] p50 / p95 m",
        "max from 10 s p95 m",
        "pitch travel p50 rad",
        "converged from p50 / max s",
    ]
    # a grid's boundary: with two keys, how far each goes with the other at its lowest; with
    # more, how far the first goes with every level of the rest converged
    keys = list(first.get("largest_converged", {}))
    pick = "largest_converged" if len(keys) == 2 else "largest_converged_all"
    extra = keys if len(keys) == 2 else keys[:1]
    short = [k.rsplit(".", 1)[-1] for k in keys]
    if len(keys) == 2:
        header += [f"all converged up to {short[i]} ({short[1 - i]} = its lowest)" for i in range(2)]
    elif keys:
        header += [f"all converged up to {short[0]} (every level of {', '.join(short[1:])})"]
    rows = []
    for lab, s in res.items():
        r = [
            lab,
            str(s["flights"]),
            str(s["converged"]),
            str(s["diverged"]),
            f"{_f(s['rms_10_m']['p50'])} / {_f(s['rms_10_m']['p95'])}",
            f"{_f(s['rms_45_m']['p50'], '.4f')} / {_f(s['rms_45_m']['p95'], '.4f')}",
            _f(s["max_err_10_m"]["p95"]),
            _f(s["pitch_travel_rad"]["p50"], ".2f"),
            f"{_f(s['converge_s']['p50'], '.1f')} / {_f(s['converge_s']['max'], '.1f')}",
        ]
        r += [_f(s[pick][k], "g") for k in extra]
        rows.append(r)
    return md_table(header, rows)


def plot_nominal(recs: dict[str, FlightRecord], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for (lab, rec), col in zip(recs.items(), COLORS, strict=False):
        axs[0].semilogy(rec.t_s, np.maximum(rec.pos_err_m, 1e-5), color=col, lw=1, label=lab)
        axs[1].plot(
            rec.t_s,
            np.sum(np.abs(np.diff(rec.pitches, axis=0, prepend=rec.pitches[:1])), axis=1)
            / np.gradient(rec.t_s),
            color=col,
            lw=0.6,
            label=lab,
        )
    axs[0].set_ylabel("3-D position error [m]")
    axs[0].legend(fontsize=8)
    axs[0].grid(True, which="both", alpha=0.3)
    axs[1].set_ylabel("sum of |pitch rate| [rad/s]")
    axs[1].set_xlabel("t [s]")
    axs[1].grid(True, alpha=0.3)
    fig.suptitle("paper scenario, ideal world: tracking error and control activity", fontsize=10)
    fig.tight_layout()
    files = [out / "nominal_error.png"]
    fig.savefig(files[0], dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(1, 2, figsize=(10, 4.5))
    first = next(iter(recs.values()))
    axs[0].plot(first.ref[:, 1], first.ref[:, 0], "k--", lw=1, label="reference")
    axs[1].plot(first.t_s, first.ref[:, 2], "k--", lw=1, label="reference")
    for (lab, rec), col in zip(recs.items(), COLORS, strict=False):
        axs[0].plot(rec.x[:, 1], rec.x[:, 0], color=col, lw=1, label=lab)
        axs[1].plot(rec.t_s, rec.x[:, 2], color=col, lw=1, label=lab)
    axs[0].set_xlabel("y west [m]")
    axs[0].set_ylabel("x north [m]")
    axs[0].invert_xaxis()  # west to the left, as on a map
    axs[0].set_aspect("equal", adjustable="datalim")
    axs[0].set_title("top view", fontsize=9)
    axs[1].set_xlabel("t [s]")
    axs[1].set_ylabel("z up [m]")
    axs[1].set_title("height", fontsize=9)
    axs[0].legend(fontsize=7)
    fig.tight_layout()
    files.append(out / "nominal_path.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files


def plot_worlds(res: dict[str, dict[str, Any]], labels: list[str], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    worlds = list(res)
    fig, ax = plt.subplots(figsize=(max(7.0, 0.8 * len(worlds) * len(labels) / 2), 4.2))
    width = 0.8 / len(labels)
    for j, (lab, col) in enumerate(zip(labels, COLORS, strict=False)):
        v = [res[w][lab]["rms_10_m"] for w in worlds]
        ax.bar(np.arange(len(worlds)) + (j - (len(labels) - 1) / 2) * width, v, width, color=col, label=lab)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(worlds)), worlds, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("RMS error [10, end] [m]")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("paper scenario in each world preset", fontsize=10)
    fig.tight_layout()
    f = out / "worlds.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return f


def plot_campaigns(
    tables: dict[str, dict[str, pa.Table]], specs: dict[str, CampaignSpec], out: Path
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    for name, by in tables.items():
        spec = specs[name]
        if spec.sampler != "grid":  # a Monte Carlo: the distributions
            fig, axs = plt.subplots(1, 2, figsize=(10, 4))
            for (lab, t), col in zip(by.items(), COLORS, strict=False):
                for a, m in zip(axs, ("rms_10_m", "max_err_10_m"), strict=True):
                    v = np.sort(_col(t, m)[np.isfinite(_col(t, m))])
                    a.step(
                        v, np.arange(1, v.size + 1) / max(1, t.num_rows), color=col, label=lab, where="post"
                    )
                    a.set_xscale("log")
                    a.set_xlabel(m.replace("_m", " [m]"))
                    a.set_ylabel("fraction of flights")
                    a.grid(True, which="both", alpha=0.3)
            axs[0].legend(fontsize=8)
            fig.suptitle(
                f"{name}: {next(iter(by.values())).num_rows} flights each, the same samples", fontsize=10
            )
        elif len(spec.keys) == 2:  # a 2-D grid: each contender's converged region
            fig, ax = plt.subplots(figsize=(6.5, 5))
            k0, k1 = spec.keys
            for (lab, t), col in zip(by.items(), COLORS, strict=False):
                x, y, ok = _col(t, k0), _col(t, k1), _flag(t, "converged")
                xs, ys = np.unique(x), np.unique(y)
                z = np.full((ys.size, xs.size), np.nan)
                for xi, yi, c in zip(x, y, ok, strict=True):
                    z[np.searchsorted(ys, yi), np.searchsorted(xs, xi)] = float(c)
                ax.contour(xs, ys, z, levels=[0.5], colors=[col])
                ax.plot([], [], color=col, label=f"{lab}: converged below/left")
                ax.plot(x[ok], y[ok], ".", color=col, ms=4, alpha=0.5)
            ax.set_xlabel(k0)
            ax.set_ylabel(k1)
            ax.legend(fontsize=8)
            ax.set_title(f"{name}: the boundary of convergence", fontsize=10)
        else:  # a larger grid: converged fraction against the first key
            fig, ax = plt.subplots(figsize=(6.5, 4))
            k0 = spec.keys[0]
            for (lab, t), col in zip(by.items(), COLORS, strict=False):
                x, ok = _col(t, k0), _flag(t, "converged")
                xs = np.unique(x)
                ax.plot(xs, [ok[x == v].mean() for v in xs], "o-", color=col, label=lab)
            ax.set_xlabel(k0)
            ax.set_ylabel("fraction converged (over the other keys' levels)")
            ax.set_ylim(-0.05, 1.05)
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
            ax.set_title(name, fontsize=10)
        fig.tight_layout()
        files.append(out / f"campaign_{name}.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    return files


# ----------------------------------------------------------------------------- the command


def run_compare(
    path: str | Path,
    out: Path,
    work: Path,
    samples: int | None = None,
    workers: int | None = None,
    quiet: bool = False,
    command: str = "",
) -> dict[str, Any]:
    t0 = time.perf_counter()
    spec = load_compare(path)
    out.mkdir(parents=True, exist_ok=True)
    labels = [c.label for c in spec.contenders]

    def say(line: str) -> None:
        if not quiet:
            print(line, flush=True)

    result: dict[str, Any] = {
        "compare": spec.name,
        "source": str(resolve(path)),
        "command": command,
        "contenders": [dataclasses.asdict(c) for c in spec.contenders],
    }
    nominal: dict[str, Any] = {}
    recs: dict[str, FlightRecord] = {}
    for c in spec.contenders:
        nominal[c.label], recs[c.label] = fly(spec, c)
    result["nominal"] = nominal
    text = ["## Nominal: the paper scenario, ideal world", "", nominal_table(nominal), ""]
    say("\n".join(text))
    figures = plot_nominal(recs, out)
    worlds: dict[str, dict[str, Any]] = {}
    for w in spec.worlds:
        seed = flight_seed(CampaignSpec(name="compare", seed=1), len(worlds))
        worlds[w] = {c.label: fly(spec, c, w, seed)[0] for c in spec.contenders}
    result["worlds"] = worlds
    if worlds:
        title = "## Each world preset (one flight each, the same world seed)"
        part = [title, "", worlds_table(worlds, labels), ""]
        say("\n".join(part))
        text += part
        figures.append(plot_worlds(worlds, labels, out))
    tables: dict[str, dict[str, pa.Table]] = {}
    specs: dict[str, CampaignSpec] = {}
    camp: dict[str, dict[str, Any]] = {}
    flown = 0  # campaign flights flown by this run (the rest were in --work already)
    if spec.campaigns:
        n_workers = workers or os.cpu_count() or 1
        with engine.cluster(n_workers, None) as client:
            address = client.scheduler.address
            for source in spec.campaigns:
                name = Path(source).stem  # a name in configs/campaigns/, or a file
                tables[name], camp[name] = {}, {}
                for c in spec.contenders:
                    cs = campaign_spec(source, c, samples, spec.plant)
                    specs[name] = cs
                    d = work / f"{name}-{c.slug}"
                    say(f"campaign {name}, {c.label}: {d}")
                    flown += run_campaign(cs, d, scheduler=address, quiet=True)["run"]["flown_now"]
                    t = pq.read_table(d / engine.RESULTS)
                    tables[name][c.label] = t
                    camp[name][c.label] = campaign_summary(t, cs)
                src = Path(specs[name].source).name
                part = [
                    f"## Campaign `{name}` ({src}, seed {specs[name].seed})",
                    "",
                    campaign_table(camp[name]),
                    "",
                ]
                say("\n".join(part))
                text += part
        figures += plot_campaigns(tables, specs, out)
    result["campaigns"] = camp
    result["wall_s"] = time.perf_counter() - t0
    head = [
        f"# {spec.name}",
        "",
        f"Made by `{command}` ({Path(spec.source).name}; contenders: {'; '.join(labels)}): "
        f"{result['wall_s']:.0f} s on {os.cpu_count()} cores, {flown} campaign flights flown, "
        f"{sum(s['flights'] for by in camp.values() for s in by.values()) - flown} resumed from `--work`.",
        "",
    ]
    figs = [f"![{f.stem}]({f.name})" for f in figures]
    (out / "report.md").write_text("\n".join(head + text + ["## Figures", ""] + figs) + "\n")
    (out / "comparison.json").write_text(json.dumps(result, indent=2, default=str) + "\n")
    say(f"wrote {out / 'report.md'}, {out / 'comparison.json'} and {len(figures)} figures in {out}")
    return result


def command_line() -> str:
    return "heli-sitl " + " ".join(shlex.quote(a) for a in sys.argv[1:])
