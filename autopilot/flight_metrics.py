"""A flight's figures as one typed value: what the summary, a campaign's row and the Python
API all read (one parser of a :class:`~autopilot.metrics.FlightRecord`, not one per caller).

The error windows are the record's own (``[0, end]``, ``[10, end]``, ``[45, end]`` of
trajectory time, keyed ``"45-120"`` for a 120 s trajectory); a flight is lost when it leaves
the safety envelope (:mod:`autopilot.envelope`: the one rule of every verdict), and converged
when its error stays within ``converge_m`` from some time to the end: two figures apart.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from autopilot.envelope import DEFAULT, Envelope, tilt_rad
from autopilot.metrics import FlightRecord

CONVERGE_M = 0.5  # converged: the error stays below this to the end


def window_value(by_window: Mapping[str, float], start_s: float) -> float:
    """The figure of the window that starts at ``start_s`` ("45-120" starts at 45), NaN if the
    flight was too short to have one."""
    return next((v for k, v in by_window.items() if float(k.split("-")[0]) == start_s), math.nan)


@dataclass(frozen=True)
class FlightMetrics:
    rms_m: Mapping[str, float]  # RMS 3-D position error per window ("0-120", "10-120", "45-120")
    max_err_m: Mapping[str, float]  # largest 3-D position error per window
    max_tilt_rad: float  # largest angle between the body's up axis and the vertical
    saturated_ticks: int  # ticks with a pitch command at its limit
    saturated_fraction: float  # the same, as a fraction of the ticks
    max_servo_rate_rad_s: float  # largest commanded pitch rate, any channel
    pitch_travel_rad: float  # summed |change| of every commanded pitch
    converge_s: float  # from when the error stays below converge_m to the end (NaN: never)
    converged: bool
    lost_reason: str  # "" when not lost
    # RMS 3-D position error over the scenario's own error_windows_s ("0-11": [0, 11] s of
    # trajectory time); empty when the scenario names none
    rms_windows_m: Mapping[str, float] = dataclasses.field(default_factory=dict)

    @property
    def lost(self) -> bool:
        return bool(self.lost_reason)

    @property
    def rms_0_m(self) -> float:
        return window_value(self.rms_m, 0.0)

    @property
    def rms_10_m(self) -> float:
        return window_value(self.rms_m, 10.0)

    @property
    def rms_45_m(self) -> float:
        return window_value(self.rms_m, 45.0)

    @property
    def max_err_after_10_s_m(self) -> float:
        return window_value(self.max_err_m, 10.0)

    @classmethod
    def of(
        cls, rec: FlightRecord, converge_m: float = CONVERGE_M, envelope: Envelope = DEFAULT
    ) -> FlightMetrics:
        s = rec.summary()
        n = int(rec.t_s.size)
        tilt = tilt_rad(rec.x)
        with np.errstate(invalid="ignore"):
            dt = np.diff(rec.t_s)[:, None]
            rate = np.abs(np.diff(rec.pitches, axis=0)) / dt if n > 1 else np.zeros((1, 4))
        err = rec.pos_err_m
        above = np.flatnonzero(~(err < converge_m))  # NaN counts as above
        if not above.size:
            converge_s = float(rec.t_s[0]) if n else math.nan
        elif above[-1] + 1 < n:
            converge_s = float(rec.t_s[above[-1] + 1])
        else:
            converge_s = math.nan
        converged = not math.isnan(converge_s)
        reason = envelope.leaves(rec)
        saturated = int(s.get("saturated_ticks", 0))
        return cls(
            rms_m=dict(s["rms_pos_err_m"]),
            max_err_m=dict(s["max_pos_err_m"]),
            max_tilt_rad=float(np.nanmax(tilt)) if tilt.size else math.nan,
            saturated_ticks=saturated,
            saturated_fraction=saturated / n if n else 0.0,
            max_servo_rate_rad_s=float(np.nanmax(rate)) if rate.size else math.nan,
            pitch_travel_rad=float(np.nansum(np.abs(np.diff(rec.pitches, axis=0)))),
            converge_s=converge_s,
            converged=converged,
            lost_reason=reason,
            rms_windows_m=dict(s.get("rms_pos_err_windows_m", {})),
        )

    @classmethod
    def from_summary(cls, summary: Mapping[str, object]) -> FlightMetrics:
        """From a summary.json (a process run's): its error windows, tilt and saturation;
        what only the arrays tell (servo rate, travel, convergence) is NaN, not converged."""
        rms, mx = summary["rms_pos_err_m"], summary["max_pos_err_m"]
        if not isinstance(rms, Mapping) or not isinstance(mx, Mapping):
            raise ValueError("summary: rms_pos_err_m and max_pos_err_m must be tables of windows")
        sat = summary.get("saturated_ticks", 0)
        ticks = summary.get("ticks", 0)
        n_sat = int(sat) if isinstance(sat, (int, float)) else 0
        n = int(ticks) if isinstance(ticks, (int, float)) else 0
        windows = summary.get("rms_pos_err_windows_m", {})
        if not isinstance(windows, Mapping):
            raise ValueError("summary: rms_pos_err_windows_m must be a table of windows")
        return cls(
            rms_m={str(k): float(v) for k, v in rms.items()},
            max_err_m={str(k): float(v) for k, v in mx.items()},
            max_tilt_rad=math.nan, saturated_ticks=n_sat, saturated_fraction=n_sat / n if n else math.nan,
            max_servo_rate_rad_s=math.nan, pitch_travel_rad=math.nan, converge_s=math.nan,
            converged=False, lost_reason="", rms_windows_m={str(k): float(v) for k, v in windows.items()},
        )  # fmt: skip

    def row(self) -> dict[str, float | int | bool | str]:
        """The campaign's columns (configs/campaigns: ``metrics``), by their names there."""
        return {
            "rms_0_m": self.rms_0_m,
            "rms_10_m": self.rms_10_m,
            "rms_45_m": self.rms_45_m,
            "max_err_10_m": self.max_err_after_10_s_m,
            "max_tilt_rad": self.max_tilt_rad,
            "saturated_ticks": self.saturated_ticks,
            "max_servo_rate_rad_s": self.max_servo_rate_rad_s,
            "pitch_travel_rad": self.pitch_travel_rad,
            "converge_s": self.converge_s,
            "converged": self.converged,
            "diverged": self.lost,
            "diverged_reason": self.lost_reason,
        }
