"""One campaign flight in-process, and the metrics kept of it.

A flight that raises is a row too (``failed``, the error's text), never a lost sample.
"""

from __future__ import annotations

import math
import traceback
from typing import Any

import numpy as np

from autopilot.metrics import FlightRecord
from heli_common.state import PHI, THETA
from heli_sitl.campaign.settings import Flight, apply
from heli_sitl.campaign.spec import CampaignSpec
from heli_sitl.closed_loop import SimOptions, simulate

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
    "diverged": "1: non-finite state, or not converged after a tumble (tilt > 90 deg) or a run-away "
    "(error beyond the initial error + diverge_m)",
    "diverged_reason": "why (empty when it did not)",
}


def flight_seed(spec: CampaignSpec, sample_id: int) -> int:
    """Each flight's world seed (turbulence, sensors): fixed by the campaign's seed and the
    sample id, different for every flight; a varied ``world.seed`` overrides it."""
    return (spec.seed * 1_000_003 + sample_id * 7_919 + 1) % (2**53)


def metrics(rec: FlightRecord, spec: CampaignSpec) -> dict[str, Any]:
    s = rec.summary()
    out: dict[str, Any] = {}
    for name, t0 in (("rms_0_m", "0"), ("rms_10_m", "10"), ("rms_45_m", "45")):
        out[name] = next((v for k, v in s["rms_pos_err_m"].items() if k.split("-")[0] == t0), math.nan)
    mx = s["max_pos_err_m"]
    out["max_err_10_m"] = next((v for k, v in mx.items() if k.split("-")[0] == "10"), math.nan)
    with np.errstate(invalid="ignore"):
        tilt = np.arccos(np.clip(np.cos(rec.x[:, PHI]) * np.cos(rec.x[:, THETA]), -1.0, 1.0))
        dt = np.diff(rec.t_s)[:, None]
        rate = np.abs(np.diff(rec.pitches, axis=0)) / dt if rec.t_s.size > 1 else np.zeros((1, 4))
    out["max_tilt_rad"] = float(np.nanmax(tilt)) if tilt.size else math.nan
    out["saturated_ticks"] = int(s["saturated_ticks"])
    out["max_servo_rate_rad_s"] = float(np.nanmax(rate)) if rate.size else math.nan
    out["pitch_travel_rad"] = float(np.nansum(np.abs(np.diff(rec.pitches, axis=0))))
    err = rec.pos_err_m
    above = np.flatnonzero(~(err < spec.converge_m))  # NaN counts as above
    t_end = float(rec.t_s[-1])
    out["converge_s"] = (
        float(rec.t_s[above[-1] + 1])
        if above.size and above[-1] + 1 < err.size
        else (float(rec.t_s[0]) if not above.size else math.nan)
    )
    out["converged"] = not math.isnan(out["converge_s"]) and out["converge_s"] <= t_end
    # lost: the state blew up, or the flight did not come back after tumbling or running
    # away (a flight that tumbles and recovers has converged; its max_tilt_rad says so)
    reason = ""
    if not np.all(np.isfinite(rec.x)):
        reason = "non-finite state"
    elif not out["converged"] and np.nanmax(tilt) > math.pi / 2:
        reason = "tumbled (tilt > 90 deg)"
    elif not out["converged"] and np.nanmax(err) > err[0] + spec.diverge_m:
        reason = f"ran away (error > initial + {spec.diverge_m:g} m)"
    out["diverged"] = bool(reason)
    out["diverged_reason"] = reason
    return {k: out[k] for k in spec.metrics}


def fly(
    spec: CampaignSpec, base: Flight, sample_id: int, keys: tuple[str, ...], values: list[float]
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
        opts = SimOptions(world=f.world, estimator=f.estimator, duration_s=spec.duration_s,
                          controller=f.controller, pid_gains=f.pid_gains, plant=f.plant)  # fmt: skip
        rec = simulate(f.scenario, opts)
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
