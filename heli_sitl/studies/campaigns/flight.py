"""One campaign flight in-process, and the metrics kept of it.

A flight that raises is a row too (``failed``, the error's text), never a lost sample.
"""

from __future__ import annotations

import traceback
from typing import Any

from autopilot.flight_metrics import FlightMetrics
from autopilot.metrics import FlightRecord
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.studies.campaigns.settings import FlightSetup, apply
from heli_sitl.studies.campaigns.spec import CampaignSpec

#: the metrics' units and meaning (campaign.json carries them)
METRIC_DOC = {
    "rms_0_m": "RMS 3-D position error over the whole trajectory [m]",
    "rms_10_m": "RMS 3-D position error from 10 s [m]",
    "rms_45_m": "RMS 3-D position error from 45 s (the paper's figure) [m]",
    "max_err_10_m": "largest 3-D position error from 10 s [m]",
    "max_tilt_rad": "largest tilt, arccos(cos(phi) cos(theta)) [rad]",
    "saturated_ticks": "ticks with a pitch command at its limit",
    "max_servo_rate_rad_s": "largest commanded pitch rate of any channel [rad/s]",
    "pitch_travel_rad": "control effort: the commanded pitches' total travel, sum over the four "
    "channels of |change| tick to tick [rad]",
    "converge_s": "time from which the error stays below converge_m to the end (NaN: never) [s]",
    "converged": "1: the error stays below converge_m from some time to the end",
    "diverged": "1: lost, the flight left the safety envelope (autopilot.envelope: a non-finite state, "
    "tilt beyond max_tilt_deg, a ground strike, or an error beyond max_error_m after settle_s), "
    "whether or not it came back",
    "diverged_reason": "why (empty when it did not)",
}


def flight_seed(spec: CampaignSpec, sample_id: int) -> int:
    """Each flight's world seed (turbulence, sensors): fixed by the campaign's seed and the
    sample id, different for every flight; a varied ``world.seed`` overrides it."""
    return (spec.seed * 1_000_003 + sample_id * 7_919 + 1) % (2**53)


def metrics(rec: FlightRecord, spec: CampaignSpec) -> dict[str, Any]:
    """The campaign's columns of one flight: :class:`FlightMetrics`, the one parser."""
    row = FlightMetrics.of(rec, spec.converge_m, spec.envelope).row()
    return {k: row[k] for k in spec.metrics}


def options(f: FlightSetup, duration_s: float | None) -> SimOptions:
    """The in-process flight of ``f`` (for ``duration_s``, None: the scenario's)."""
    return SimOptions(world=f.world, estimator=f.estimator, duration_s=duration_s,
                      controller=f.controller, pid_gains=f.pid_gains, plant=f.plant)  # fmt: skip


def warm(base: FlightSetup) -> None:
    """Load the compiled code a campaign's flights run (numba's cache, ~1 s per process) with
    a flight of a few ticks, so that a worker's first batch is flown at its full pace."""
    simulate(base.scenario, options(base, 0.05))


def fly(
    spec: CampaignSpec, base: FlightSetup, sample_id: int, keys: tuple[str, ...], values: list[float]
) -> dict[str, Any]:
    """One row: the sample id, its values, its seed, the metrics (or the error), and the
    flight's wall time (the only value that differs between two runs of a campaign)."""
    row: dict[str, Any] = {"sample_id": sample_id, **dict(zip(keys, values, strict=True))}
    settings = dict(zip(keys, values, strict=True))
    try:
        if "world.seed" not in settings:
            settings["world.seed"] = float(flight_seed(spec, sample_id))
        f = apply(base, settings)
        row["seed"] = f.world.seed
        rec = simulate(f.scenario, options(f, spec.duration_s))
        row["wall_s"] = rec.wall_s
        row.update(metrics(rec, spec))
        row["failed"] = False
        row["error"] = ""
    except Exception as exc:  # a flight that raises is recorded, never dropped
        row.setdefault("seed", -1)
        row["failed"] = True
        row["error"] = f"{type(exc).__name__}: {exc}"[:500]
        row["traceback"] = traceback.format_exc(limit=3)[-1000:]
    return row
