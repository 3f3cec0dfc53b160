"""One flight's score for the comparison: steady tracking, the transient apart, and the
actuators' work, as a typed record (:class:`FlightScore`).

The windows are the scenario's own ``error_windows_s`` (trajectory time):

* **transient**: the event the scenario is about. With three windows or more, the middle one
  (the step, the turn, the gust); with fewer, the first (the start's offset, the speed ramp).
* **steady**: the last window (the paper scenario's [45, 120] s, the paper's own figure).

In the transient window: the RMS and the peak 3-D error (the gust's peak deviation), the
settling time (from the window's start until the error stays below ``SETTLE_BAND_M`` to the
end of the flight) and, where the reference comes to rest after a move of more than 1 m (the
position step), the overshoot past the final point along the move. The actuators: the
commanded cyclic pitch rate (RMS and largest) and the fraction of ticks at a pitch limit.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from autopilot.envelope import DEFAULT, Envelope
from autopilot.metrics import FlightRecord, window_rms_m
from autopilot.scenario import Scenario
from heli_common.state import EPS, ETA

SETTLE_BAND_M = 0.1  # 2 % of the 5 m position step
MOVE_M = 1.0  # a reference that moves less than this has no overshoot to speak of


@dataclass(frozen=True)
class FlightScore:
    """What the comparison reports of one flight (lower is better in every field but
    ``lost``, which is 0 or 1)."""

    transient_rms_m: float
    transient_peak_m: float
    settling_s: float  # NaN: never within the band to the end
    overshoot_m: float  # NaN: the scenario has no move that comes to rest
    steady_rms_m: float
    pitch_rate_rms_rad_s: float  # the commanded cyclic (eps, eta), tick to tick
    pitch_rate_max_rad_s: float
    saturated_pct: float
    lost: float  # 1.0: the flight left the safety envelope (autopilot.envelope), back or not

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FlightScore:
        return cls(**{k: float(d[k]) for k in cls.names()})


#: how each field is labelled in the report: (header, unit, format)
LABELS: dict[str, tuple[str, str, str]] = {
    "transient_rms_m": ("transient RMS", "m", ".3f"),
    "transient_peak_m": ("transient peak", "m", ".3f"),
    "settling_s": (f"settling to {SETTLE_BAND_M:g} m", "s", ".1f"),
    "overshoot_m": ("overshoot", "m", ".3f"),
    "steady_rms_m": ("steady RMS", "m", ".4f"),
    "pitch_rate_rms_rad_s": ("cyclic rate RMS", "rad/s", ".3f"),
    "pitch_rate_max_rad_s": ("cyclic rate max", "rad/s", ".2f"),
    "saturated_pct": ("saturated", "%", ".2f"),
    "lost": ("lost", "", ".0f"),
}


def windows(scenario: Scenario, end_s: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The (transient, steady) windows of ``scenario`` (see the module's docstring)."""
    w = scenario.run.error_windows_s or ((0.0, 10.0), (10.0, end_s))
    transient = w[len(w) // 2] if len(w) >= 3 else w[0]
    return transient, w[-1]


def score(rec: FlightRecord, scenario: Scenario, envelope: Envelope = DEFAULT) -> FlightScore:
    tt = rec.trajectory_time_s
    end = float(tt[-1]) if tt.size else 0.0
    (t0, t1), (s0, s1) = windows(scenario, end)
    err = rec.pos_err_m
    finite = bool(np.all(np.isfinite(rec.x))) and err.size > 0
    lost = not finite or bool(envelope.leaves(rec))
    m = rec.window(t0, t1)
    peak = float(np.nanmax(err[m])) if m.any() else math.nan
    after = tt >= t0 - 1e-9
    above = np.flatnonzero(after & ~(err < SETTLE_BAND_M))  # NaN counts as above
    if not above.size:
        settling = 0.0
    elif above[-1] + 1 < err.size:
        settling = float(tt[above[-1] + 1] - t0)
    else:
        settling = math.nan
    overshoot = math.nan
    move = rec.ref[-1, 0:3] - rec.ref[0, 0:3]
    length = float(np.linalg.norm(move))
    at_rest = float(np.linalg.norm(rec.ref[-1, 3:6])) < 1e-6 if rec.ref.shape[1] >= 6 else False
    if length > MOVE_M and at_rest and finite:
        along = (rec.x[:, 0:3] - rec.ref[-1, 0:3]) @ (move / length)
        overshoot = max(0.0, float(np.max(along[after])))
    if rec.t_s.size > 1:
        rate = np.diff(rec.pitches[:, [EPS, ETA]], axis=0) / np.diff(rec.t_s)[:, None]
        rate_rms = float(np.sqrt(np.nanmean(rate**2)))
        rate_max = float(np.nanmax(np.abs(rate)))
    else:
        rate_rms = rate_max = math.nan
    sat = 100.0 * float(np.count_nonzero(rec.saturated)) / max(1, rec.t_s.size)
    return FlightScore(
        transient_rms_m=window_rms_m(rec, t0, t1),
        transient_peak_m=peak,
        settling_s=settling,
        overshoot_m=overshoot,
        steady_rms_m=window_rms_m(rec, s0, s1),
        pitch_rate_rms_rad_s=rate_rms,
        pitch_rate_max_rad_s=rate_max,
        saturated_pct=sat,
        lost=1.0 if lost else 0.0,
    )


__all__ = ["LABELS", "SETTLE_BAND_M", "FlightScore", "score", "windows"]
