"""``--via processes``: the first samples of a campaign flown again through the process
stack (plant and autopilot processes in lockstep, over MAVLink), from files written for
each sample (scenario, gains, world, estimator, and the plant where it has a rotor), and
compared with the in-process rows.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from autopilot.flight_metrics import FlightMetrics
from autopilot.pid.gains import default_pid_gains
from heli_common.config import as_table, read_toml, to_toml
from heli_sitl.launch.demo import DemoError, DemoOptions, run_demo
from heli_sitl.studies.campaigns import engine
from heli_sitl.studies.campaigns.flight import flight_seed
from heli_sitl.studies.campaigns.run import prepare
from heli_sitl.studies.campaigns.settings import FlightSetup, apply


def write_files(f: FlightSetup, base_scenario: Path, d: Path) -> dict[str, Path]:
    """The sample's scenario, gains, world and estimator as files the launchers read."""
    d.mkdir(parents=True, exist_ok=True)
    gains = as_table(f.scenario.gains)
    (d / "gains.toml").write_text(to_toml(gains))
    _, table = read_toml(base_scenario)
    run = as_table(f.scenario.run)
    run["gains"] = str((d / "gains.toml").resolve())
    run["airframe"] = str((base_scenario.parent / f.scenario.run.airframe).resolve())
    table["run"] = run
    traj = table.get("trajectory")
    if isinstance(traj, dict) and traj.get("kind") == "csv":  # the table stays where it was
        traj["path"] = str((base_scenario.parent / str(traj["path"])).resolve())
    table["initial_state"] = as_table(f.scenario.initial)
    (d / "scenario.toml").write_text(to_toml(table))
    world = as_table(f.world)
    world.pop("source", None)
    for k in ("name", "seed", "source"):
        world["sensors"].pop(k, None)
    (d / "world.toml").write_text(to_toml(world))
    (d / "estimator.toml").write_text(to_toml(as_table(f.estimator)))
    (d / "pid_gains.toml").write_text(to_toml(as_table(f.pid_gains or default_pid_gains())))
    names = ["scenario", "gains", "world", "estimator", "pid_gains"]
    if f.plant.rotor is not None:  # the sample's plant, its varied constants with it
        (d / "plant.toml").write_text(to_toml(as_table(f.plant.rotor)))
        names.append("plant")
    return {k: d / f"{k}.toml" for k in names}


def compare(
    path: str | Path, out: Path, limit: int, samples: int | None = None, quiet: bool = False,
    controller: str | None = None,
) -> list[dict[str, Any]]:  # fmt: skip
    spec, base, table = prepare(path, samples, controller)
    rows = {r["sample_id"]: r for r in pq.read_table(out / engine.RESULTS).to_pylist()}
    results: list[dict[str, Any]] = []
    # a vehicle lost in-process is lost over processes too, and there its state leaves the
    # range the sim link accepts, so lockstep would wait out its timeout: the first `limit`
    # samples that were not lost are flown
    chosen = [i for i in range(table.shape[0]) if not rows.get(i, {}).get("diverged", False)][:limit]
    for sid in chosen:
        values = dict(zip(spec.keys, table[sid].tolist(), strict=True))
        values.setdefault("world.seed", float(flight_seed(spec, sid)))
        f = apply(base, values)
        d = out / "via_processes" / f"sample-{sid:06d}"
        files = write_files(f, Path(base.scenario.source), d)
        try:
            summary = run_demo(
                DemoOptions(
                    mode="lockstep",
                    scenario=str(files["scenario"]),
                    out=d / "run",
                    timeout_s=300,
                    via_ground=False,
                    world=str(files["world"]),
                    duration_s=spec.duration_s,
                    extra_plant_args=("--plant", str(files["plant"])) if "plant" in files else (),
                    extra_autopilot_args=("--estimator", str(files["estimator"]), "--controller",
                                          f.controller, "--pid-gains", str(files["pid_gains"])),
                )
            )
        except DemoError as exc:  # recorded, and on to the next sample
            results.append({"sample_id": sid, "error": str(exc)})
            if not quiet:
                print(f"sample {sid}: processes failed: {exc}")
            continue
        m = FlightMetrics.from_summary(summary)
        proc = {"rms_0_m": m.rms_0_m, "rms_10_m": m.rms_10_m, "rms_45_m": m.rms_45_m}
        inproc = rows.get(sid, {})
        diff = {k: abs(proc[k] - inproc.get(k, math.nan)) for k in proc}
        results.append(
            {
                "sample_id": sid,
                "in_process": {k: inproc.get(k) for k in proc},
                "processes": proc,
                "abs_diff_m": diff,
            }
        )
        if not quiet:
            print(
                f"sample {sid}: RMS[45,end] in-process {inproc.get('rms_45_m', math.nan):.6f} m, "
                f"lockstep processes {proc['rms_45_m']:.6f} m (|diff| {diff['rms_45_m']:.1e} m)"
            )
    (out / "via_processes.json").write_text(json.dumps(results, indent=2) + "\n")
    return results


__all__ = ["compare", "write_files"]
