"""Your own controller's cost: a Python law against the compiled TLC, in-process and over
processes (lockstep), each beside its floor measured in the same run."""

from __future__ import annotations

from pathlib import Path

from autopilot.scenario import Scenario
from benchmarks import Row, bench
from benchmarks.bench_processes import _demo, raw_round_trip_us
from heli_sitl.engine.closed_loop import SimOptions, simulate

ROOT = Path(__file__).resolve().parent.parent
LQR = f"{ROOT / 'docs/examples/lqr_hover.py'}:LqrHover"
WRAPPED = f"{ROOT / 'tests/user_controllers.py'}:WrappedTLC"


@bench("your own controller (Python) against the compiled TLC")
def bench_user_controller() -> list[Row]:
    sc = Scenario.load("paper")
    n = round(sc.run.duration_s * sc.run.rate_hz) + 1

    def per_tick_us(controller: str) -> float:
        return min(simulate(sc, SimOptions(controller=controller)).wall_s for _ in range(3)) / n * 1e6

    compiled, lqr, wrapped = per_tick_us("tlc"), per_tick_us(LQR), per_tick_us(WRAPPED)
    rows = [
        Row("floor: in-process tick, compiled TLC + plant in one compiled loop", compiled, "us"),
        Row("in-process tick, LQR in Python (docs/examples/lqr_hover.py)", lqr, "us"),
        Row("  the Python path itself: the compiled TLC called from Python each tick", wrapped, "us"),
        Row("  LQR in Python / compiled loop", lqr / compiled, "x"),
    ]
    rtt = raw_round_trip_us()
    lock: dict[str, float] = {}
    for label, ctrl in (("compiled TLC", "tlc"), ("LQR in Python", LQR)):
        s = _demo(mode="lockstep", rate_hz=100.0, extra_autopilot_args=("--no-gcs", "--controller", ctrl))
        lock[label] = float(s["wall_s"]) / 12001 * 1e6  # type: ignore[arg-type]
    rows += [
        Row("floor: raw two-process UDP round trip (median)", rtt, "us"),
        Row("lockstep tick, compiled TLC (--no-gcs)", lock["compiled TLC"], "us"),
        Row("lockstep tick, LQR in Python (--no-gcs)", lock["LQR in Python"], "us"),
        Row("  LQR in Python / compiled TLC, lockstep", lock["LQR in Python"] / lock["compiled TLC"], "x"),
    ]
    return rows
