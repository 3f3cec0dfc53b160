"""heli-sitl: simulate in-process, or run the plant process (and the demo that starts them all).

The vehicle modules never import ``autopilot``; this entry point is the one place that
composes the vehicle with the controller for the in-process ``simulate`` command.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from heli_sitl.config import ConfigError


def _simulate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from autopilot.closed_loop import SimOptions, simulate
    from autopilot.scenario import Scenario
    from ground.plots import plot_figures

    scenario = Scenario.load(args.scenario)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    opts = SimOptions(
        rate_hz=args.rate_hz,
        feedforward=args.feedforward,
        plant_substeps=args.plant_substeps,
        duration_s=args.duration_s,
    )
    with tqdm(
        total=100, desc=f"simulate {scenario.run.name}", unit="%", disable=args.quiet,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}",
    ) as bar:  # fmt: skip
        def progress(k: int, n: int) -> None:
            bar.n = round(100 * k / max(n, 1))
            bar.refresh()

        record = simulate(scenario, opts, progress)
    record.write_csv(out / "run.csv")
    summary = record.write_summary(out / "summary.json")
    figs = plot_figures(record.columns(), out, title=f"{scenario.run.name}, {record.extra['feedforward']}")
    rms = summary["rms_pos_err_m"]
    print(f"RMS 3-D position error: " + ", ".join(f"[{k}] s {v:.4f} m" for k, v in rms.items()))
    print(
        f"max error in [40, 45] s: {summary['max_pos_err_40_45_m']:.3f} m; "
        f"saturated ticks: {summary['saturated_ticks']}; "
        f"real-time factor: {summary['realtime_factor']:.0f}x"
    )
    print(f"wrote {out / 'run.csv'}, {out / 'summary.json'}")
    for f in figs:
        print(f"wrote {f}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="heli-sitl", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("simulate", help="closed loop in one process; writes CSV, summary, figures")
    s.add_argument("--scenario", default="paper", help="name (configs/scenario_NAME.toml) or path")
    s.add_argument("--rate-hz", type=float, default=None, help="control rate, 50-1000 Hz")
    s.add_argument("--feedforward", choices=("pseudo", "exact"), default=None)
    s.add_argument("--plant-substeps", type=int, default=None, help="RK4 sub-steps per tick")
    s.add_argument("--duration-s", type=float, default=None)
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=_simulate)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        rc: int = args.func(args)
    except ConfigError as exc:
        print(f"heli-sitl: config error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"heli-sitl: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("heli-sitl: interrupted", file=sys.stderr)
        return 130
    return rc


if __name__ == "__main__":
    sys.exit(main())
