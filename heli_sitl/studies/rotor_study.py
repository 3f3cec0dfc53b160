"""What the rotor plant does to the controllers: ``python -m heli_sitl.studies.rotor_study --out DIR``.

Flies the paper scenario in-process with every shipped gain set, on both plants, in the
ideal world, with the default servos and in ``everything``; linearises each closed loop
(:mod:`heli_sitl.engine.loop_linear`) and the TLC's cascade loop at a time
(:mod:`autopilot.analysis.margins`, with and without the rotor's flapping); trims both
plants. Writes ``study.md`` (the tables of docs/rotor-plant.md) and ``study.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.analysis.margins import DEFAULT_SERVOS, IDEAL_SERVOS, RotorFlapping, loop_margins
from autopilot.controllers import build_kernel_controller
from autopilot.pid.gains import PidGains
from autopilot.scenario import Scenario
from heli_common.state import EPS, ETA
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import World
from heli_plant.trim import linearize, trim
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.engine.loop_linear import linearize_loop, servo_model
from heli_sitl.studies.campaigns.flight import metrics
from heli_sitl.studies.campaigns.spec import CampaignSpec

CONTENDERS = (  # label, controller, TLC gains, PID gains
    ("TLC, paper Table 2", "tlc", "gains_paper.toml", ""),
    ("TLC, servo-aware", "tlc", "gains_servo_aware.toml", ""),
    ("PID, tuned", "pid", "gains_paper.toml", "gains_pid.toml"),
)
WORLDS = ("ideal", "servos-default", "everything")
PLANTS = ("paper", "gavrilets")
METRICS = ("rms_45_m", "max_err_10_m", "diverged", "diverged_reason", "max_tilt_rad")


def _flight(label: str, ctrl: str, gains: str, pid: str, world: str, plant: str) -> dict[str, Any]:
    sc = Scenario.load("paper", gains=gains)
    opts = SimOptions(world=None if world == "ideal" else World.load(world), controller=ctrl,
                      pid_gains=PidGains.load(pid) if pid else None,
                      plant=PlantModel.load(plant))  # fmt: skip
    rec = simulate(sc, opts)
    m = metrics(rec, CampaignSpec(name="rotor-study", metrics=METRICS))
    late = rec.t_s >= 10.0
    lim = np.array(sc.airframe.limits.as_tuple())
    sat = np.abs(rec.pitches[late][:, [EPS, ETA]]) >= lim[[EPS, ETA], 1] - 1e-9
    m["cyclic_saturated_pct"] = float(100.0 * np.mean(np.any(sat, axis=1)))
    if rec.rotor is not None:
        r = rec.rotor[np.all(np.isfinite(rec.rotor), axis=1)]
        m["max_flapping_rad"] = float(np.max(np.abs(r[:, 0:2])))
        m["omega_range_rad_s"] = [float(r[:, 2].min()), float(r[:, 2].max())]
    return {"label": label, "world": world, "plant": plant, **m}


def _loop(label: str, ctrl: str, gains: str, pid: str, servos: str, plant: str) -> dict[str, Any]:
    sc = Scenario.load("paper", gains=gains)
    pid_gains = PidGains.load(pid) if pid else None
    c = build_kernel_controller(ctrl, sc.airframe, sc.gains, 100.0, pid_gains=pid_gains)
    name, sv = servo_model(servos)
    lin = linearize_loop(c, PlantModel.load(plant), sc.airframe, sv, name)
    inputs = [b for b in lin.break_points if b.name.startswith("input")]
    worst = min(inputs, key=lambda b: b.disk_margin)
    states = [b for b in lin.break_points if b.name.startswith("state")]
    worst_state = min(states, key=lambda b: b.disk_margin)
    return {
        "label": label, "servos": servos, "plant": plant, "spectral_radius": lin.spectral_radius,
        "stable": lin.stable, "dominant_rad_s": [lin.dominant_rad_s.real, lin.dominant_rad_s.imag],
        "worst_input": dataclasses.asdict(worst), "worst_state": dataclasses.asdict(worst_state),
        "input_multiloop": dataclasses.asdict(lin.input_multiloop),
        "break_points": [dataclasses.asdict(b) for b in lin.break_points],
    }  # fmt: skip


def _cascade(gains: str, servos: str, rotor: bool) -> dict[str, Any]:
    sc = Scenario.load("paper", gains=gains)
    rp = PlantModel.load("gavrilets").rotor
    assert rp is not None
    rf = RotorFlapping.from_plant(rp, sc.airframe) if rotor else None
    rep = loop_margins(sc.gains, IDEAL_SERVOS if servos == "ideal" else DEFAULT_SERVOS, rotor=rf)
    out: dict[str, Any] = {"gains": gains, "servos": servos, "rotor": rotor}
    for ch in ("roll", "pitch"):
        m = rep.get(4, ch)
        out[f"loop4_{ch}"] = {"pm_deg": m.phase_margin_deg, "at_rad_s": m.phase_margin_at_rad_s,
                              "gm_db": m.gain_margin_db, "stable": m.stable}  # fmt: skip
    return out


def _trims() -> list[dict[str, Any]]:
    design = Scenario.load("paper").airframe
    rows = []
    for plant in PLANTS:
        model = PlantModel.load(plant)
        tr = trim(model, design)
        lin = linearize(tr, model, design)
        rows.append({"plant": plant, "trim": tr.as_dict(), "modes": [
            {"name": m.name, "natural_frequency_rad_s": m.natural_frequency_rad_s, "damping": m.damping,
             "eigenvalue": [m.eigenvalue.real, m.eigenvalue.imag]} for m in lin.modes]})  # fmt: skip
    return rows


def _fmt(v: float, nd: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def report(data: dict[str, Any]) -> str:
    lines = ["# The rotor plant against the controllers (generated by "
             "`python -m heli_sitl.studies.rotor_study`)", ""]  # fmt: skip
    lines += ["## Hover trim", "", "| quantity | paper | gavrilets |", "|---|---|---|"]
    t0, t1 = data["trims"][0]["trim"], data["trims"][1]["trim"]
    for k in t1:
        if k in ("plant", "speed_m_s"):
            continue
        a = t0.get(k)
        lines.append(f"| {k} | {_fmt(a, 5) if isinstance(a, float) else '-'} | {_fmt(t1[k], 5)} |")
    lines += ["", "## Modes of the gavrilets plant in hover (open loop)", "",
              "| mode | eigenvalue | w_n [rad/s] | damping |", "|---|---|---|---|"]  # fmt: skip
    for m in data["trims"][1]["modes"]:
        re_, im = m["eigenvalue"]
        lines.append(f"| {m['name']} | {re_:.3f} {im:+.3f}j | {m['natural_frequency_rad_s']:.2f} | "
                     f"{m['damping']:.3f} |")  # fmt: skip
    lines += ["", "## Flights: the paper scenario, in-process, 120 s", "",
              "| controller | world | plant | RMS [45,120] m | max err after 10 s m | lost "
              "| cyclic saturated % (from 10 s) | max flapping rad |",
              "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for f in data["flights"]:
        lost = f["diverged_reason"] or "no"
        lines.append(f"| {f['label']} | {f['world']} | {f['plant']} | {_fmt(f['rms_45_m'], 4)} | "
                     f"{_fmt(f['max_err_10_m'])} | {lost} | {f['cyclic_saturated_pct']:.1f} | "
                     f"{_fmt(f.get('max_flapping_rad', math.nan))} |")  # fmt: skip
    lines += ["", "## The whole closed loop linearised at hover (one tick's Jacobian)", "",
              "| controller | servos | plant | max abs eigenvalue | dominant ln(lambda)/dt [1/s] "
              "| worst input (disk margin, +/- dB, +/- deg) | worst measurement | all four inputs at once |",
              "|---|---|---|---|---|---|---|---|"]  # fmt: skip

    def bp(b: dict[str, Any]) -> str:
        if b["disk_margin"] == 0.0:
            return f"{b['name']}: unstable"
        dm, gm, pm = b["disk_margin"], b["gain_margin_db"], b["phase_margin_deg"]
        return f"{b['name']}: {dm:.2f}, {gm:.1f} dB, {pm:.1f} deg"

    for r in data["loops"]:
        re_, im = r["dominant_rad_s"]
        lines.append(f"| {r['label']} | {r['servos']} | {r['plant']} | {r['spectral_radius']:.4f} | "
                     f"{re_:.2f} {im:+.2f}j | {bp(r['worst_input'])} | {bp(r['worst_state'])} | "
                     f"{bp(r['input_multiloop'])} |")  # fmt: skip
    lines += ["", "## The TLC's loop 4 loop at a time (autopilot/analysis/margins.py)", "",
              "| gains | servos | flapping in the loop | roll PM deg (at rad/s) | pitch PM deg (at rad/s) | "
              "stable (roll, pitch) |", "|---|---|---|---|---|---|"]  # fmt: skip
    for c in data["cascade"]:
        r, p = c["loop4_roll"], c["loop4_pitch"]
        lines.append(f"| {c['gains']} | {c['servos']} | {'yes' if c['rotor'] else 'no'} | "
                     f"{r['pm_deg']:.1f} ({r['at_rad_s']:.1f}) | {p['pm_deg']:.1f} ({p['at_rad_s']:.1f}) | "
                     f"{r['stable']}, {p['stable']} |")  # fmt: skip
    lines += ["", f"Generated in {data['wall_s']:.0f} s."]
    return "\n".join(lines) + "\n"


def run(out: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    data: dict[str, Any] = {"trims": _trims(), "flights": [], "loops": [], "cascade": []}
    for label, ctrl, gains, pid in CONTENDERS:
        for world in WORLDS:
            for plant in PLANTS:
                data["flights"].append(_flight(label, ctrl, gains, pid, world, plant))
        for servos in ("ideal", "servos-default"):
            for plant in PLANTS:
                data["loops"].append(_loop(label, ctrl, gains, pid, servos, plant))
        if ctrl == "tlc":
            for servos in ("ideal", "default"):
                for rotor in (False, True):
                    data["cascade"].append(_cascade(gains, servos, rotor))
    data["wall_s"] = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps(data, indent=1) + "\n")
    (out / "study.md").write_text(report(data))
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m heli_sitl.studies.rotor_study", description=__doc__)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    run(Path(args.out))
    print((Path(args.out) / "study.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
