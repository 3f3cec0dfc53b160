"""``heli-sitl compare``: the controllers side by side on the same flights, with intervals.

A comparison file (``configs/compare.toml``) names the contenders (a controller, its gains,
the TLC's feed-forward), the plants, and what they all fly on each plant:

* **trajectories**: each scenario (the paper's and the held-out ones) once in its calm world
  (deterministic: one flight says it), then ``seeds`` times in its Monte Carlo world;
* **worlds**: the paper scenario in each world preset, ``seeds`` times where the world has a
  seeded part (turbulence, sensors), once where it has none;
* **campaigns**: the shipped campaigns, each flown by every contender with the same samples
  and seeds, on one Dask cluster; their Parquet rows stay in ``--work`` (a re-run resumes).

Every Monte Carlo set is paired: each contender flies the same seeds (the same samples), so
each one is tested against the ``reference`` contender per flight: the bootstrap 95 % interval
of the median difference and the Wilcoxon signed-rank test (:mod:`heli_sitl.studies.stats`); the
medians and 95th percentiles carry their bootstrap intervals, the loss rates their exact ones.
Every contender flies under the same command limits (``max_speed_m_s``: the horizontal speed
of the position loop's correction). The metrics of a flight: :mod:`heli_sitl.studies.scorecard`.

Written to ``--out``: ``report.md`` (every table, and the command that made it),
``comparison.json`` (the same numbers) and the figures.
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
from autopilot.user_controller import is_user_spec, normalise_spec
from heli_common.config import CONFIG_DIR, ConfigError, read_toml, resolve
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.studies.campaigns import engine
from heli_sitl.studies.campaigns.counts import CampaignCounts, flags
from heli_sitl.studies.campaigns.flight import flight_seed
from heli_sitl.studies.campaigns.run import run_campaign
from heli_sitl.studies.campaigns.settings import canonical
from heli_sitl.studies.campaigns.spec import CampaignSpec, Vary, load_campaign
from heli_sitl.studies.scorecard import LABELS, FlightScore, score
from heli_sitl.studies.stats import Interval, Paired, holm, loss_rate, paired, percentile_ci

TOP_KEYS = ("name", "plants", "plant", "reference", "seeds", "max_speed_m_s", "trajectory", "worlds",
            "campaigns", "contender")  # fmt: skip
CONTENDER_KEYS = ("label", "controller", "gains", "pid_gains", "feedforward", "plant")
#: what a contender may set per plant ([contender.plant.NAME]): its gains tuned there
PLANT_KEYS = ("gains", "pid_gains")
TRAJECTORY_KEYS = ("name", "world", "mc_world")
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")
#: the metrics the paired tables test, each against the reference contender
PAIRED_METRICS = ("steady_rms_m", "transient_peak_m", "pitch_rate_rms_rad_s")


@dataclass(frozen=True)
class Contender:
    label: str
    controller: str = "tlc"
    gains: str = ""  # the TLC's ("": the scenario's)
    pid_gains: str = ""  # "": configs/gains_pid.toml
    feedforward: str = ""  # the TLC's ("": the scenario's)
    # per plant, the gains it flies there instead: (plant, gains, pid_gains), "" = as above;
    # "each contender tuned on the plant it flies" ([contender.plant.paper] in compare.toml)
    on_plant: tuple[tuple[str, str, str], ...] = ()

    @property
    def slug(self) -> str:
        return re.sub(r"[^a-z0-9]+", "-", self.label.lower()).strip("-")

    def on(self, plant: str) -> Contender:
        """The contender as it flies ``plant``: its gains for that plant, if it names any."""
        for name, gains, pid_gains in self.on_plant:
            if name == plant:
                g, pg = gains or self.gains, pid_gains or self.pid_gains
                return dataclasses.replace(self, gains=g, pid_gains=pg, on_plant=())
        return dataclasses.replace(self, on_plant=())


@dataclass(frozen=True)
class TrajectorySet:
    """A scenario flown once in ``world`` ("": calm) and ``seeds`` times in ``mc_world``."""

    name: str
    world: str = ""
    mc_world: str = ""


@dataclass(frozen=True)
class CompareSpec:
    name: str
    contenders: tuple[Contender, ...]
    plants: tuple[str, ...] = ("paper",)
    reference: str = ""  # the label every contender is tested against ("": the first)
    # per plant, another reference: (plant, label); the contender tuned for that plant
    reference_on: tuple[tuple[str, str], ...] = ()
    seeds: int = 20  # Monte Carlo flights per set
    max_speed_m_s: float = 0.0  # every contender's correction speed limit (0: each its own)
    trajectories: tuple[TrajectorySet, ...] = (TrajectorySet("paper"),)
    worlds: tuple[str, ...] = ()
    campaigns: tuple[str, ...] = ()
    source: str = ""

    @property
    def reference_label(self) -> str:
        return self.reference or self.contenders[0].label

    def reference_for(self, plant: str) -> str:
        return dict(self.reference_on).get(plant, self.reference_label)

    def contenders_on(self, plant: str) -> tuple[Contender, ...]:
        return tuple(c.on(plant) for c in self.contenders)


def _names(src: str, t: dict[str, Any], k: str) -> tuple[str, ...]:
    v = t.get(k, [])
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise ConfigError(f"{src}: {k}: expected an array of names")
    return tuple(v)


def _tables(src: str, t: dict[str, Any], k: str, keys: tuple[str, ...]) -> list[dict[str, str]]:
    raw = t.get(k, [])
    if not isinstance(raw, list):
        raise ConfigError(f"{src}: {k}: expected an array of tables [[{k}]]")
    for i, c in enumerate(raw):
        where = f"{src}: {k}[{i}]"
        if not isinstance(c, dict):
            raise ConfigError(f"{where}: expected a table")
        for key, v in c.items():
            if key not in keys:
                raise ConfigError(f"{where}: unknown key {key!r}; expected one of {', '.join(keys)}")
            if key == "plant":  # [contender.plant.NAME]: checked by _on_plant
                continue
            if not isinstance(v, str):
                raise ConfigError(f"{where}.{key}: expected a string, got {v!r}")
    return raw


def _on_plant(where: str, raw: Any) -> tuple[tuple[str, str, str], ...]:
    """``[contender.plant.NAME]`` tables: the gains a contender flies on plant NAME."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}.plant: expected tables [{where}.plant.NAME] with gains or pid_gains")
    out = []
    for plant, t in raw.items():
        w = f"{where}.plant.{plant}"
        if not isinstance(t, dict) or not t:
            raise ConfigError(f"{w}: expected a table with gains or pid_gains")
        for k, v in t.items():
            if k not in PLANT_KEYS:
                raise ConfigError(f"{w}: unknown key {k!r}; expected one of {', '.join(PLANT_KEYS)}")
            if not isinstance(v, str) or not v:
                raise ConfigError(f"{w}.{k}: expected a file name, got {v!r}")
        out.append((str(plant), str(t.get("gains", "")), str(t.get("pid_gains", ""))))
    return tuple(out)


def _reference(src: str, t: dict[str, Any], labels: list[str]) -> tuple[str, tuple[tuple[str, str], ...]]:
    """``reference = "label"``, or ``reference = {default = "label", paper = "label"}``."""
    raw = t.get("reference", "")
    table = raw if isinstance(raw, dict) else {"default": raw}
    for k, v in table.items():
        if not isinstance(v, str) or (v and v not in labels):
            on = "" if k == "default" else f" on {k}"
            raise ConfigError(f"{src}: reference{on} {v!r} is not a contender's label ({', '.join(labels)})")
    return str(table.get("default", "")), tuple((k, str(v)) for k, v in table.items() if k != "default")


def load_compare(path: str | Path = "compare.toml") -> CompareSpec:
    """A comparison file (as given, or in configs/), checked: unknown keys, a controller
    that is not tlc, pid or a loadable ``module:Class``, a gains file, world, scenario or
    campaign that does not load."""
    p, t = read_toml(path)
    src = str(p)
    for k in t:
        if k not in TOP_KEYS:
            raise ConfigError(f"{src}: unknown key {k!r}; expected one of {', '.join(TOP_KEYS)}")
    raw = _tables(src, t, "contender", CONTENDER_KEYS)
    if not raw:
        raise ConfigError(f"{src}: expected at least one [[contender]]")
    contenders = []
    for i, c in enumerate(raw):
        if not c.get("label"):
            raise ConfigError(f"{src}: contender[{i}]: a table with a label")
        where = f"{src}: contender[{i}]"
        per = _on_plant(where, c.pop("plant")) if "plant" in c else ()
        con = Contender(**c, on_plant=per)
        try:  # tlc, pid, ardupilot or a user's class (loaded here, once, to fail before any flight)
            if con.controller != ARDUPILOT:
                con = dataclasses.replace(con, controller=normalise_spec(con.controller))
        except ConfigError as exc:
            raise ConfigError(f"{src}: contender[{i}].controller: {exc}") from exc
        if con.feedforward not in ("", "pseudo", "exact"):
            raise ConfigError(
                f'{src}: contender[{i}].feedforward: expected "pseudo" or "exact", got {con.feedforward!r}'
            )
        contenders.append(con)
    labels = [c.label for c in contenders]
    if len({c.slug for c in contenders}) != len(contenders):
        raise ConfigError(f"{src}: contender labels must differ ({', '.join(labels)})")
    reference, reference_on = _reference(src, t, labels)
    firmware = {c.label for c in contenders if c.controller == ARDUPILOT}
    if firmware & {reference, *(lab for _, lab in reference_on)}:
        raise ConfigError(f"{src}: reference: the ArduPilot contender flies no paired Monte Carlo "
                          "set; choose one of the bench's controllers")  # fmt: skip
    plants = _names(src, t, "plants") if "plants" in t else (str(t.get("plant", "paper")),)
    seeds, speed = t.get("seeds", 20), t.get("max_speed_m_s", 0.0)
    if not isinstance(seeds, int) or isinstance(seeds, bool) or not 2 <= seeds <= 10_000:
        raise ConfigError(f"{src}: seeds: expected an integer in [2, 10000], got {seeds!r}")
    if not isinstance(speed, (int, float)) or isinstance(speed, bool) or not 0.0 <= speed <= 50.0:
        raise ConfigError(f"{src}: max_speed_m_s: expected a number in [0, 50] m/s, got {speed!r}")
    trajs = tuple(TrajectorySet(**c) for c in _tables(src, t, "trajectory", TRAJECTORY_KEYS))
    for i, tr in enumerate(trajs):
        if not tr.name:
            raise ConfigError(f"{src}: trajectory[{i}]: a table with a name")
    spec = CompareSpec(
        str(t.get("name", p.stem)), tuple(contenders), plants, reference, reference_on, seeds, float(speed),
        trajs or (TrajectorySet("paper"),), _names(src, t, "worlds"), _names(src, t, "campaigns"), src,
    )  # fmt: skip
    for plant, _ in reference_on:
        if plant not in plants:
            raise ConfigError(f"{src}: reference {plant}: not one of the plants ({', '.join(plants)})")
    for plant in spec.plants:
        PlantModel.load(plant)
    for con in (c for plant in spec.plants for c in spec.contenders_on(plant)):  # every file loads first
        for tr in spec.trajectories:
            scenario_for(tr.name, dataclasses.replace(con, gains="") if con.controller == ARDUPILOT else con)
        if con.pid_gains:
            PidGains.load(con.pid_gains)
    for w in (*spec.worlds, *(x for tr in spec.trajectories for x in (tr.world, tr.mc_world) if x)):
        World.load(w)
    for name in spec.campaigns:
        load_campaign(name)
    return spec


def scenario_for(name: str, c: Contender, max_speed_m_s: float = 0.0) -> Scenario:
    sc = Scenario.load(name, gains=c.gains or None)
    if c.feedforward:
        sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, feedforward=c.feedforward))
    if max_speed_m_s > 0.0:
        g = sc.gains
        sc = dataclasses.replace(sc, gains=dataclasses.replace(
            g, limits=dataclasses.replace(g.limits, max_speed_m_s=max_speed_m_s)))  # fmt: skip
    return sc


def gains_flown(c: Contender) -> str:
    """What a report names as a contender's gains: a file, or the user's own class."""
    if is_user_spec(c.controller):
        return c.controller.rpartition(":")[2] + " (its own)"
    return c.pid_gains or c.gains or "the scenario's"


def pid_gains_for(c: Contender, max_speed_m_s: float = 0.0) -> PidGains | None:
    if c.controller != "pid":
        return None
    g = PidGains.load(c.pid_gains or "gains_pid.toml")
    if max_speed_m_s > 0.0:
        g = dataclasses.replace(g, position=dataclasses.replace(g.position, max_speed_m_s=max_speed_m_s))
    return g


def estimator_for(world: str) -> EstimatorConfig:
    """The estimator tuned for a sensor preset where one is shipped (configs/estimator/)."""
    f = CONFIG_DIR / "estimator" / f"{Path(world).stem}.toml"
    return EstimatorConfig.load(f) if world and f.is_file() else EstimatorConfig()


# ----------------------------------------------------------------------------- flights


@dataclass(frozen=True)
class FlightCase:
    """One flight of the comparison: who, on which plant, what, in which world, which seed."""

    contender: Contender
    plant: str
    scenario: str
    world: str = ""  # "": calm
    seed: int = 1
    max_speed_m_s: float = 0.0


def fly_record(f: FlightCase) -> tuple[Scenario, FlightRecord]:
    sc = scenario_for(f.scenario, f.contender, f.max_speed_m_s)
    w = dataclasses.replace(World.load(f.world), seed=f.seed) if f.world else None
    if w is not None:
        w = dataclasses.replace(w, sensors=dataclasses.replace(w.sensors, seed=f.seed))
    opts = SimOptions(
        world=w,
        estimator=estimator_for(f.world),
        controller=f.contender.controller,
        pid_gains=pid_gains_for(f.contender, f.max_speed_m_s),
        plant=PlantModel.load(f.plant),
    )
    return sc, simulate(sc, opts)


def fly(f: FlightCase) -> FlightScore:
    """One flight's score; a flight that raises is lost (its error kept out of the numbers)."""
    try:
        sc, rec = fly_record(f)
    except Exception as exc:
        numeric = isinstance(exc, (ValueError, FloatingPointError, np.linalg.LinAlgError))
        if not numeric and not is_user_spec(f.contender.controller):  # the bench's own fault
            raise
        nan = math.nan
        return FlightScore(nan, nan, nan, nan, nan, nan, nan, nan, 1.0)
    return score(rec, sc)


# a contender's controller: ArduPilot's firmware (heli_sitl.studies.ardupilot_contender)
ARDUPILOT = "ardupilot"
FIRMWARE_NOTE = (
    "ArduPilot (`arducopter-heli` SITL on this plant, `configs/ardupilot/xcell60.parm`) flies each "
    "trajectory once, through processes, in GUIDED from `heli-ground fly --guided`'s stream: it takes "
    "off and reaches the trajectory's start before t = 0 (the bench's contenders start at the "
    "scenario's initial state, off the path), flies on its own EKF3 and sensors, and a trajectory "
    "starting at ground level is flown 3 m higher. Its cyclic rate is the swashplate's reading of "
    "its servo outputs; it flies no Monte Carlo set and no campaign (about a minute a flight)."
)


def fly_firmware(scenario: str, plant: str, out: Path, firmware: Path, world: str = "") -> FlightScore:
    """ArduPilot's flight of ``scenario`` (heli_sitl.studies.ardupilot_contender); lost if it fails."""
    from heli_sitl.studies.ardupilot_contender import fly_ardupilot

    try:
        return fly_ardupilot(scenario, plant, out, firmware=firmware, world=world or None).score
    except (RuntimeError, ValueError, OSError) as exc:  # the firmware's failure is its flight's
        print(f"ArduPilot's flight of {scenario} on the {plant} plant failed: {exc}", file=sys.stderr)
        nan = math.nan
        return FlightScore(nan, nan, nan, nan, nan, nan, nan, nan, 1.0)


def mc_seeds(n: int) -> tuple[int, ...]:
    """The Monte Carlo sets' world seeds: the campaigns' flight seeds of samples 0..n-1."""
    return tuple(flight_seed(CampaignSpec(name="compare", seed=1), i) for i in range(n))


def campaign_spec(
    name: str, c: Contender, samples: int | None, plant: str = "paper", max_speed_m_s: float = 0.0
) -> CampaignSpec:
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
    if max_speed_m_s > 0.0 and not is_user_spec(c.controller):  # one command limit for all (a
        # user's class keeps its own: it has no setting of ours to fix)
        key = "pid.position.max_speed_m_s" if c.controller == "pid" else "gains.limits.max_speed_m_s"
        fixed = Vary(key, "grid" if spec.sampler == "grid" else "choice", values=(max_speed_m_s,))
        spec = dataclasses.replace(spec, vary=(*spec.vary, fixed))
    # the settings by their full names, as the rows' columns carry them
    return dataclasses.replace(
        spec, vary=tuple(dataclasses.replace(v, key=canonical(v.key)) for v in spec.vary)
    )


def _col(t: pa.Table, name: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in t.column(name).to_pylist()], dtype=float)


def largest_converged(t: pa.Table, key: str, fixed: dict[str, float] | None = None) -> float:
    """The largest level of ``key`` up to which every flight converged (with the other keys
    at ``fixed`` values, or at every level when ``fixed`` is None); NaN if not the first."""
    x = _col(t, key)
    ok = flags(t, "converged") & ~flags(t, "failed")
    sel = np.ones(x.size, bool)
    for k, v in (fixed or {}).items():
        sel &= np.isclose(_col(t, k), v)
    best = math.nan
    for level in np.unique(x[sel]):
        if not ok[sel & (x == level)].all():
            break
        best = float(level)
    return best


def grid_keys(spec: CampaignSpec) -> tuple[str, ...]:
    """The varied settings with more than one level (one held at a single level, as the
    comparison's common speed limit, is no axis of the grid)."""
    return tuple(v.key for v in spec.vary if v.dist not in ("grid", "choice") or len(v.levels()) > 1)


def campaign_summary(t: pa.Table, spec: CampaignSpec) -> dict[str, Any]:
    """A contender's campaign: its counts, and its percentiles over the flights that stayed
    inside the envelope; the lost are counted apart (a tumbling flight's 1e8 m is no
    percentile of tracking)."""
    failed = flags(t, "failed")
    c = CampaignCounts.of(t, sampled=spec.sampler != "grid")
    out: dict[str, Any] = {"flights": c.flights, "failed": c.failed, "converged": c.converged or 0,
                           "diverged": c.diverged or 0}  # fmt: skip
    kept = ~failed & ~flags(t, "diverged")
    for m in ("rms_10_m", "rms_45_m", "max_err_10_m", "pitch_travel_rad", "converge_s"):
        v = _col(t, m)[kept]
        v = v[np.isfinite(v)]
        out[m] = (
            {"p50": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
            if (v.size)
            else {"p50": math.nan, "p95": math.nan, "max": math.nan}
        )
    lost, flights = out["diverged"] + out["failed"], max(1, out["flights"])
    rms = _col(t, "rms_10_m")[kept]
    if spec.sampler == "grid":  # a map of the grid's points: its figures, no interval
        out["loss_rate"] = Interval.of_grid(lost / flights)
        out["rms_10_ci"] = {q: Interval.of_grid(float(np.percentile(rms, n)) if rms.size else math.nan)
                            for q, n in (("p50", 50), ("p95", 95))}  # fmt: skip
    else:
        out["loss_rate"] = loss_rate(lost, flights)
        out["rms_10_ci"] = {"p50": percentile_ci(rms, 50), "p95": percentile_ci(rms, 95)}
    keys = grid_keys(spec)
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


def _ci(iv: Interval, fmt: str = ".3f") -> str:
    if iv.bare:  # a grid's figure: no interval over a map
        return f"{_f(iv.estimate, fmt)} (grid)"
    return f"{_f(iv.estimate, fmt)} [{_f(iv.lo, fmt)}, {_f(iv.hi, fmt)}]"


def _p(p: float) -> str:
    return "-" if not math.isfinite(p) else ("<1e-4" if p < 1e-4 else f"{p:.2g}")


def trajectory_table(res: dict[str, dict[str, FlightScore]]) -> str:
    """One flight each (deterministic): every score field per trajectory and contender."""
    names = FlightScore.names()
    header = ["trajectory", "controller"] + [f"{LABELS[n][0]} {LABELS[n][1]}".strip() for n in names]
    rows = []
    for traj, by in res.items():
        for lab, sc in by.items():
            d = sc.as_dict()
            rows.append([traj, lab] + [_f(d[n], LABELS[n][2]) for n in names])
    return md_table(header, rows)


@dataclass(frozen=True)
class MonteCarloSet:
    """``seeds`` flights of every contender in one world (the same seeds): the scores, and
    each contender against the reference on every paired metric."""

    title: str
    seeds: int
    scores: dict[str, tuple[FlightScore, ...]]  # by contender label
    reference: str

    def values(self, label: str, metric: str) -> np.ndarray:
        return np.array([getattr(s, metric) for s in self.scores[label]], dtype=float)

    @property
    def deterministic(self) -> bool:
        """Every seed flew the same flight (the world has no seeded part)."""
        return all(len({round(s.steady_rms_m, 12) for s in v}) == 1 for v in self.scores.values())

    def against_reference(self, label: str, metric: str) -> Paired:
        """``label`` against the reference on the same seeds, a lost flight's value as +inf
        (a loss in the paired test, never a dropped pair or a good number)."""
        return paired(self._scored(label, metric), self._scored(self.reference, metric))

    def _scored(self, label: str, metric: str) -> np.ndarray:
        return np.where(self.values(label, "lost") > 0.0, np.inf, self.values(label, metric))

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"title": self.title, "seeds": self.seeds, "reference": self.reference,
                               "deterministic": self.deterministic, "by": {}}  # fmt: skip
        for lab in self.scores:
            m: dict[str, Any] = {"lost": int(self.values(lab, "lost").sum())}
            for metric in PAIRED_METRICS:
                v = self.values(lab, metric)
                m[metric] = {"p50": dataclasses.asdict(percentile_ci(v, 50)),
                             "p95": dataclasses.asdict(percentile_ci(v, 95))}  # fmt: skip
                if lab != self.reference:
                    m[metric]["vs_reference"] = dataclasses.asdict(self.against_reference(lab, metric))
            out["by"][lab] = m
        return out


def monte_carlo_table(sets: list[MonteCarloSet]) -> str:
    """Per set and contender: median and 95th percentile [95 % CI] of the steady RMS, the
    median transient peak and cyclic rate, losses; against the reference: the median
    difference [95 % CI] and the Wilcoxon p of the steady RMS and the transient peak."""
    header = [
        "set",
        "controller",
        "lost",
        "steady RMS p50 [CI] m",
        "steady RMS p95 [CI] m",
        "transient peak p50 [CI] m",
        "cyclic rate RMS p50 [CI] rad/s",
        "steady RMS minus reference: p50 [CI] m (Wilcoxon p, Holm)",
        "transient peak minus reference: p50 [CI] m (Wilcoxon p, Holm)",
    ]
    rows: list[list[str]] = []
    tests: list[tuple[int, int, float]] = []  # (row, column, raw p): one family, the table
    for ms in sets:
        for lab in ms.scores:
            lost = int(ms.values(lab, "lost").sum())
            cells = [ms.title, lab, f"{lost}/{ms.seeds}"]
            steady = ms.values(lab, "steady_rms_m")
            if ms.deterministic:
                cells += [f"{_f(steady[0], '.4f')} (deterministic)", "-",
                          _f(ms.values(lab, "transient_peak_m")[0]),
                          _f(ms.values(lab, "pitch_rate_rms_rad_s")[0])]  # fmt: skip
            else:
                cells += [_ci(percentile_ci(steady, 50), ".4f"), _ci(percentile_ci(steady, 95), ".4f"),
                          _ci(percentile_ci(ms.values(lab, "transient_peak_m"), 50)),
                          _ci(percentile_ci(ms.values(lab, "pitch_rate_rms_rad_s"), 50))]  # fmt: skip
            for metric in ("steady_rms_m", "transient_peak_m"):
                if lab == ms.reference:
                    cells.append("(reference)")
                    continue
                pr = ms.against_reference(lab, metric)
                if ms.deterministic:
                    cells.append(_f(pr.median_diff.estimate, "+.4f"))
                else:  # its p is the table's family's, filled in below
                    tests.append((len(rows), len(cells), pr.wilcoxon_p))
                    cells.append(f"{_ci(pr.median_diff, '+.4f')} ({{p}})")
            rows.append(cells)
    for (r, col), p in zip(((r, col) for r, col, _ in tests), holm([p for *_, p in tests]), strict=True):
        rows[r][col] = rows[r][col].format(p=_p(p))
    return md_table(header, rows)


def campaign_paired_table(tables: dict[str, pa.Table], reference: str) -> str:
    """Each contender against the reference on the campaign's own samples (rows by sample
    id), the RMS from 10 s: the median difference [95 % CI], the Wilcoxon p and how often it
    is the better of the two."""
    ref = tables[reference]
    ids = _col(ref, "sample_id")
    header = ["controller", "flights paired (lost: it / the reference)", "RMS [10,end] minus reference: "
              "p50 [CI] m (both flown)", "Wilcoxon p, Holm (losses as the worst)",
              "better than the reference in"]  # fmt: skip
    rows, p_raw = [], []
    for lab, t in tables.items():
        if lab == reference:
            continue
        other = dict(zip(_col(t, "sample_id"), _scored(t), strict=True))
        a = np.array([other.get(i, math.nan) for i in ids])
        pr = paired(a, _scored(ref))
        p_raw.append(pr.wilcoxon_p)
        rows.append([lab, f"{pr.n} (lost {pr.lost_a} / {pr.lost_b})", _ci(pr.median_diff, "+.4f"),
                     "", f"{100 * pr.a_better_fraction:.0f} %"])  # fmt: skip
    for row, p in zip(rows, holm(p_raw), strict=True):  # the table's contenders, one family
        row[3] = _p(p)
    return md_table(header, rows)


def _scored(t: pa.Table) -> np.ndarray:
    """A campaign's RMS from 10 s per flight, a lost flight (it left the safety envelope, or
    raised) as +inf: a loss in the paired test, never a dropped pair or a good number."""
    rms = np.asarray(_col(t, "rms_10_m"), dtype=float)
    lost = np.zeros(rms.shape, dtype=bool)
    for flag in ("diverged", "failed"):
        if flag in t.column_names:
            lost |= np.asarray([bool(v) for v in t.column(flag).to_pylist()])
    return np.where(lost, np.inf, rms)


def md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def campaign_table(res: dict[str, dict[str, Any]]) -> str:
    first = next(iter(res.values()))
    header = [
        "controller",
        "flights",
        "converged",
        "lost",
        "lost: rate [95 % interval]",
        # the percentiles: over the flights not lost (the lost are counted apart)
        "not lost: RMS [10,end] p50 [95 % CI] m",
        "not lost: RMS [10,end] p95 [95 % CI] m",
        "not lost: RMS [45,end] p50 / p95 m",
        "not lost: max from 10 s p95 m",
        "not lost: pitch travel p50 rad",
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
            s["loss_rate"].pct(),
            _ci(s["rms_10_ci"]["p50"]),
            _ci(s["rms_10_ci"]["p95"]),
            f"{_f(s['rms_45_m']['p50'], '.4f')} / {_f(s['rms_45_m']['p95'], '.4f')}",
            _f(s["max_err_10_m"]["p95"]),
            _f(s["pitch_travel_rad"]["p50"], ".2f"),
            f"{_f(s['converge_s']['p50'], '.1f')} / {_f(s['converge_s']['max'], '.1f')}",
        ]
        r += [_f(s[pick][k], "g") for k in extra]
        rows.append(r)
    return md_table(header, rows)


def plot_campaigns(
    tables: dict[str, dict[str, pa.Table]], specs: dict[str, CampaignSpec], out: Path, prefix: str = ""
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
            # every legend below its axes: inside, one sat on the curves and boundaries
            fig.legend(*axs[0].get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.5, 0.0),
                       ncol=min(4, len(by)), fontsize=8, frameon=False)  # fmt: skip
            fig.suptitle(
                f"{name}: {next(iter(by.values())).num_rows} flights each, the same samples", fontsize=10
            )
        elif len(grid_keys(spec)) == 2:  # a 2-D grid: each contender's converged region
            fig, ax = plt.subplots(figsize=(6.5, 5))
            k0, k1 = grid_keys(spec)
            for (lab, t), col in zip(by.items(), COLORS, strict=False):
                x, y, ok = _col(t, k0), _col(t, k1), flags(t, "converged")
                xs, ys = np.unique(x), np.unique(y)
                z = np.full((ys.size, xs.size), np.nan)
                for xi, yi, c in zip(x, y, ok, strict=True):
                    z[np.searchsorted(ys, yi), np.searchsorted(xs, xi)] = float(c)
                ax.contour(xs, ys, z, levels=[0.5], colors=[col])
                ax.plot([], [], color=col, label=f"{lab}: converged below/left")
                ax.plot(x[ok], y[ok], ".", color=col, ms=4, alpha=0.5)
            ax.set_xlabel(k0)
            ax.set_ylabel(k1)
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8, frameon=False)
            ax.set_title(f"{name}: the boundary of convergence", fontsize=10)
        else:  # a larger grid: converged fraction against the first key
            fig, ax = plt.subplots(figsize=(6.5, 4))
            k0 = grid_keys(spec)[0]
            for (lab, t), col in zip(by.items(), COLORS, strict=False):
                x, ok = _col(t, k0), flags(t, "converged")
                xs = np.unique(x)
                ax.plot(xs, [ok[x == v].mean() for v in xs], "o-", color=col, label=lab)
            ax.set_xlabel(k0)
            ax.set_ylabel("fraction converged (over the other keys' levels)")
            ax.set_ylim(-0.05, 1.05)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2, fontsize=8, frameon=False)
            ax.set_title(name, fontsize=10)
        fig.tight_layout()
        files.append(out / f"{prefix}campaign_{name}.png")
        fig.savefig(files[-1], dpi=110, bbox_inches="tight")  # the tight box takes the legend in
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
    seeds: int | None = None,
    ardupilot_bin: str | None = None,
) -> dict[str, Any]:
    t0 = time.perf_counter()
    spec = load_compare(path)
    firmware = None
    if any(c.controller == ARDUPILOT for c in spec.contenders):
        from heli_sitl.launch.ardupilot import FirmwareNotFoundError, find_firmware

        try:
            firmware = find_firmware(ardupilot_bin)
        except FirmwareNotFoundError as exc:
            raise ConfigError(f"{spec.source}: an ArduPilot contender: {exc}") from None
    if seeds is not None:
        spec = dataclasses.replace(spec, seeds=seeds)
    out.mkdir(parents=True, exist_ok=True)
    labels = [c.label for c in spec.contenders]
    speed = spec.max_speed_m_s

    def say(line: str) -> None:
        if not quiet:
            print(line, flush=True)

    result: dict[str, Any] = {
        "compare": spec.name,
        "source": str(resolve(path)),
        "command": command,
        "contenders": [dataclasses.asdict(c) for c in spec.contenders],
        "reference": {plant: spec.reference_for(plant) for plant in spec.plants},
        "seeds": spec.seeds,
        "max_speed_m_s": speed,
        "plants": {},
    }
    text: list[str] = []
    figures: list[Path] = []
    flown = resumed = 0  # campaign flights flown by this run, and found in --work
    base = spec.trajectories[0].name  # the scenario every world preset flies
    n_workers = workers or os.cpu_count() or 1
    with engine.cluster(n_workers, None) as client:

        def fly_all(flights: list[FlightCase]) -> list[FlightScore]:
            return list(client.gather(client.map(fly, flights, pure=False)))

        for plant in spec.plants:
            everyone = spec.contenders_on(plant)  # each with its gains for this plant
            # ArduPilot flies each trajectory once, through processes (about a minute a flight):
            # no Monte Carlo set, no campaign
            contenders = tuple(c for c in everyone if c.controller != ARDUPILOT)
            firmware_contenders = tuple(c for c in everyone if c.controller == ARDUPILOT)
            ref = spec.reference_for(plant)
            say(f"plant {plant}: {len(spec.trajectories)} trajectories, {len(spec.worlds)} worlds, "
                f"{spec.seeds} seeds each")  # fmt: skip
            pres: dict[str, Any] = {}
            # one flight each in calm air (or the trajectory's own world): deterministic
            det = [(tr, c) for tr in spec.trajectories for c in contenders]
            scores = fly_all([FlightCase(c, plant, tr.name, tr.world, 1, speed) for tr, c in det])
            traj: dict[str, dict[str, FlightScore]] = {}
            for (tr, c), sc in zip(det, scores, strict=True):
                traj.setdefault(tr.name + (f" ({tr.world})" if tr.world else ""), {})[c.label] = sc
            for tr in spec.trajectories:
                for c in firmware_contenders:
                    assert firmware is not None
                    d = work / plant / f"{c.slug}-{tr.name}"
                    say(f"{c.label} flies {tr.name} on the {plant} plant (processes): {d}")
                    sc = fly_firmware(tr.name, plant, d, firmware, tr.world)
                    traj.setdefault(tr.name + (f" ({tr.world})" if tr.world else ""), {})[c.label] = sc
            pres["trajectories"] = {k: {lab: v.as_dict() for lab, v in by.items()} for k, by in traj.items()}
            # the paired Monte Carlo sets: each trajectory in its turbulent world, then the
            # base scenario in each world preset; every contender the same seeds
            sets = [(f"{tr.name} in {tr.mc_world}", tr.name, tr.mc_world)
                    for tr in spec.trajectories if tr.mc_world]  # fmt: skip
            sets += [(f"{base} in {w}", base, w) for w in spec.worlds]
            sd = mc_seeds(spec.seeds)
            jobs = [(title, c, seed) for title, _, _ in sets for c in contenders for seed in sd]
            where = {title: (scn, w) for title, scn, w in sets}
            mc_scores = fly_all([FlightCase(c, plant, *where[t], seed, speed) for t, c, seed in jobs])
            by_set: dict[str, dict[str, list[FlightScore]]] = {}
            for (title, c, _), sc in zip(jobs, mc_scores, strict=True):
                by_set.setdefault(title, {}).setdefault(c.label, []).append(sc)
            mc = [MonteCarloSet(t, spec.seeds, {lab: tuple(v) for lab, v in by.items()}, ref)
                  for t, by in by_set.items()]  # fmt: skip
            pres["monte_carlo"] = [m.as_dict() for m in mc]
            pres["contenders"] = {c.label: c.gains or c.pid_gains for c in contenders}
            for c in firmware_contenders:
                pres["contenders"][c.label] = "configs/ardupilot/xcell60.parm"
            part = [
                f"## The {plant} plant",
                "",
                "Gains flown here: " + "; ".join(f"{c.label} `{gains_flown(c)}`" for c in contenders) + ".",
                "",
                "### Each trajectory, one flight (calm air unless named: deterministic)",
                "",
                trajectory_table(traj),
                "",
                *([FIRMWARE_NOTE, ""] if firmware_contenders else []),
                f"### Paired Monte Carlo: {spec.seeds} seeds per set, every contender the same; "
                f"against `{ref}`",
                "",
                monte_carlo_table(mc),
                "",
            ]
            say("\n".join(part))
            text += part
            camp: dict[str, dict[str, Any]] = {}
            tables: dict[str, dict[str, pa.Table]] = {}
            specs: dict[str, CampaignSpec] = {}
            for source in spec.campaigns:
                name = Path(source).stem  # a name in configs/campaigns/, or a file
                tables[name], camp[name] = {}, {}
                for c in contenders:
                    cs = campaign_spec(source, c, samples, plant, speed)
                    specs[name] = cs
                    d = work / plant / f"{name}-{c.slug}"
                    say(f"campaign {name}, {c.label}, {plant} plant: {d}")
                    run = run_campaign(cs, d, scheduler=client.scheduler.address, quiet=True)["run"]
                    flown += run["flown_now"]
                    t = pq.read_table(d / engine.RESULTS)
                    resumed += t.num_rows - run["flown_now"]
                    tables[name][c.label] = t
                    camp[name][c.label] = campaign_summary(t, cs)
                src = Path(specs[name].source).name
                title = f"### Campaign `{name}` ({src}, seed {specs[name].seed})"
                part = [title, "", campaign_table(camp[name]), ""]
                if specs[name].sampler != "grid" and len(contenders) > 1:
                    part += [f"Paired on the same samples, against `{ref}`:", "",
                             campaign_paired_table(tables[name], ref), ""]  # fmt: skip
                say("\n".join(part))
                text += part
            pres["campaigns"] = camp
            figures += plot_campaigns(tables, specs, out, prefix=f"{plant}_")
            result["plants"][plant] = pres
    result["wall_s"] = time.perf_counter() - t0
    head = [
        f"# {spec.name}",
        "",
        f"Made by `{command}` ({Path(spec.source).name}; contenders: {'; '.join(labels)}; "
        f"plants: {', '.join(spec.plants)}): {result['wall_s']:.0f} s on {os.cpu_count()} cores, "
        f"{flown} campaign flights flown, {resumed} resumed from `--work`. Every contender's correction "
        f"speed limit: {speed:g} m/s (0: its own). Intervals: 95 %, bootstrap for medians and "
        "percentiles of sampled flights, Clopper-Pearson for sampled loss rates, none over a grid "
        "(a map, not a sample); p: two-sided Wilcoxon signed-rank on the paired flights, "
        "Holm-adjusted over each table's tests.",
        "",
    ]
    figs = [f"![{f.stem}]({f.name})" for f in figures]
    tail = ["## Figures", ""] + figs if figs else []
    (out / "report.md").write_text("\n".join(head + text + tail) + "\n")
    (out / "comparison.json").write_text(json.dumps(result, indent=2, default=str) + "\n")
    say(f"wrote {out / 'report.md'}, {out / 'comparison.json'} and {len(figures)} figures in {out}")
    return result


def command_line() -> str:
    return "heli-sitl " + " ".join(shlex.quote(a) for a in sys.argv[1:])
