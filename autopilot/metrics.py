"""A flight record (what every runner produces) and the paper's error figures from it."""

from __future__ import annotations

import csv
import functools
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from heli_common.state import EULER, PHI, PITCH_LABELS, PITCH_NAMES, POS, PSI, THETA, FloatArray


def ref_column(name: str) -> str:
    """The reference column beside a state column: ``x_m`` -> ``x_ref_m``, ``psi_rad`` ->
    ``psi_ref_rad`` (the unit stays last)."""
    base, unit = name.split("_", 1)
    return f"{base}_ref_{unit}"


# run.csv: one schema with the API's tables (FlightResult.to_pandas, Parquet): SI units last in
# every name, the state's names as heli_common.state.STATE_NAMES, each reference beside
TRACKED = ("x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")  # of STATE_NAMES
CSV_HEADER = (
    "t_s", *TRACKED, *(ref_column(n) for n in ("x_m", "y_m", "z_m", "psi_rad")), *PITCH_LABELS,
    ref_column("phi_rad"), ref_column("theta_rad"),
)  # fmt: skip
# the header run.csv had before (t, x, ..., x_cmd): such a file still flies back as a trajectory
LEGACY_CSV_HEADER = (
    "t", "x", "y", "z", "phi", "theta", "psi",
    "x_cmd", "y_cmd", "z_cmd", "psi_cmd", "theta_m", "theta_t", "eps", "eta", "phi_cmd", "theta_cmd",
)  # fmt: skip
# world.csv: the air (earth NWU) and the blade pitch each servo reached
WORLD_CSV_HEADER = ("t_s", "air_n_m_s", "air_w_m_s", "air_u_m_s", *(f"{n}_servo_rad" for n in PITCH_NAMES))
# est.csv, flying from sensors: the estimate the controller flew on, beside run.csv's truth,
# then the estimator's log (autopilot.estimation.log.EST_LOG_COLUMNS)
EST_CSV_STATE = ("t_s", *(f"{n.split('_', 1)[0]}_est_{n.split('_', 1)[1]}" for n in TRACKED))
# the rotor plant's own states after run.csv's columns: flapping (forward, right tilt of the
# tip-path plane [rad]), rotor speed [rad/s] and the governor's throttle [0, 1]
ROTOR_CSV = ("a1_rad", "b1_rad", "omega_rad_s", "throttle")
ROTOR_RECORD = ("a1_rad", "b1_rad", "omega_rad_s", "governor_int_rad", "throttle")


@dataclass(frozen=True)
class FlightRecord:
    """One row per control tick; frames NWU/FLU, SI units."""

    t_s: FloatArray
    x: FloatArray  # (N, 12) plant state
    ref: FloatArray  # (N, 9) commanded pos, vel, acc
    pitches: FloatArray  # (N, 4)
    psi_cmd: FloatArray
    saturated: FloatArray
    wall_s: float
    att_cmd: FloatArray | None = None  # (N, 2) commanded roll, pitch where known
    extra: dict[str, Any] = field(default_factory=dict)
    # time along the flown trajectory (mission or timed trajectory; NaN while holding,
    # taking off, returning or landing); None: the whole record is the trajectory
    traj_t_s: FloatArray | None = None
    landing: FloatArray | None = None  # (N,) bool: ticks of a landing
    # the world, where one was simulated: the air velocity (earth NWU, m/s) and the blade
    # pitches the servos reached (rad), at the end of each tick's hold
    air_nwu_m_s: FloatArray | None = None
    servo_rad: FloatArray | None = None
    # flying from sensors: the estimate the controller flew on (N, 12) and the estimator's
    # log (N, len(EST_LOG_COLUMNS)); ``x`` stays the truth
    x_hat: FloatArray | None = None
    est_log: FloatArray | None = None
    # the rotor plant: per tick its states and throttle (N, len(ROTOR_RECORD)); row 0 the start
    rotor: FloatArray | None = None

    @classmethod
    def from_ticks(
        cls, t_s: FloatArray, x: FloatArray, ref: FloatArray, pitches: FloatArray,
        diags: FloatArray, wall_s: float, extra: dict[str, Any],
        traj_t_s: FloatArray | None = None, landing: FloatArray | None = None,
    ) -> FlightRecord:  # fmt: skip
        """From per-tick arrays, ``diags`` being the controller's diagnostics vectors."""
        from autopilot.tlc.controller import D_PHI_C, D_PSI_C, D_SAT_MASK, D_THETA_C

        return cls(
            t_s=t_s, x=x, ref=ref, pitches=pitches,
            psi_cmd=diags[:, D_PSI_C].copy(),
            att_cmd=diags[:, [D_PHI_C, D_THETA_C]].copy(),
            saturated=diags[:, D_SAT_MASK] != 0,
            wall_s=wall_s, extra=extra, traj_t_s=traj_t_s, landing=landing,
        )  # fmt: skip

    @functools.cached_property
    def pos_err_m(self) -> FloatArray:
        """3-D position error per tick [m]; computed once (every window and metric reads it)."""
        return np.asarray(np.linalg.norm(self.ref[:, 0:3] - self.x[:, POS], axis=1))

    @property
    def trajectory_time_s(self) -> FloatArray:
        """Time along the flown trajectory (NaN outside it): the error windows' time."""
        return self.t_s if self.traj_t_s is None else self.traj_t_s

    def window(self, t0: float, t1: float) -> FloatArray:
        tt = self.trajectory_time_s
        with np.errstate(invalid="ignore"):
            return np.asarray((tt >= t0 - 1e-9) & (tt <= t1 + 1e-9))

    def summary(self) -> dict[str, Any]:
        """Error figures over [0, end], [10, end], [45, end] of trajectory time (the same
        windows whether in-process or over processes; holds, take-offs and landings apart);
        ``end`` is the trajectory's last tick, or ``extra["summary_end_s"]``. The paper's
        [40, 45] figure only for the paper's scenario (``extra["scenario"] == "paper"``); the
        scenario's own ``error_windows_s`` (``extra["error_windows_s"]``) in
        ``rms_pos_err_windows_m``, keyed "t0-t1" (NaN: no tick in the window)."""
        if self.t_s.size == 0:  # never armed: no flight to measure
            return {"ticks": 0, "duration_s": 0.0, "rms_pos_err_m": {}, "max_pos_err_m": {},
                    "max_pos_err_40_45_m": None, "rms_pos_err_windows_m": {}, "wall_s": self.wall_s,
                    **self.extra}  # fmt: skip
        err = self.pos_err_m
        tt = self.trajectory_time_s
        flown = np.isfinite(tt)
        end = float(np.max(tt[flown])) if flown.any() else 0.0
        if self.extra.get("summary_end_s") is not None:
            end = min(end, float(self.extra["summary_end_s"]))
        rms: dict[str, float] = {}
        mx: dict[str, float] = {}
        for t0 in (0.0, 10.0, 45.0):
            m = self.window(t0, end)
            if m.any():
                key = f"{t0:g}-{end:g}"
                rms[key] = window_rms_m(self, t0, end)
                mx[key] = float(np.max(err[m]))
        # the scenario's own windows (``error_windows_s``), where the flight flew its trajectory
        windows = self.extra.get("error_windows_s") or ()
        jump = self.window(40.0, 45.0) if self.extra.get("scenario") == "paper" else np.zeros(0, bool)
        duration = float(self.t_s[-1] - self.t_s[0])
        out: dict[str, Any] = {
            "rms_pos_err_m": rms,
            "max_pos_err_m": mx,
            "max_pos_err_40_45_m": float(np.max(err[jump])) if jump.any() else None,
            "rms_pos_err_windows_m": {f"{a:g}-{b:g}": window_rms_m(self, a, b) for a, b in windows},
            "max_abs_phi_rad": float(np.max(np.abs(self.x[:, PHI]))),
            "max_abs_theta_rad": float(np.max(np.abs(self.x[:, THETA]))),
            "pitch_range_rad": {
                k: [float(self.pitches[:, i].min()), float(self.pitches[:, i].max())]
                for i, k in enumerate(PITCH_NAMES)
            },
            "saturated_ticks": int(np.count_nonzero(self.saturated)),
            "ticks": int(self.t_s.size),
            "duration_s": duration,
            "wall_s": self.wall_s,
            "realtime_factor": duration / self.wall_s if self.wall_s > 0 else None,
        }
        if self.x_hat is not None:
            out["estimate"] = self._estimate_summary(err, end)
        if self.rotor is not None:
            out["rotor"] = self._rotor_summary()
        if self.landing is not None and self.landing.any():
            lt = self.t_s[self.landing]
            land_err = float(np.max(err[self.landing]))
            out["landing"] = {"duration_s": float(lt[-1] - lt[0]), "max_pos_err_m": land_err}
        out.update(self.extra)
        return out

    def _estimate_summary(self, err: FloatArray, end: float) -> dict[str, Any]:
        """Flying from sensors: the error the controller saw (reference - estimate) beside
        the true one, and the estimate's own error (estimate - truth), per window."""
        assert self.x_hat is not None
        seen = np.linalg.norm(self.ref[:, 0:3] - self.x_hat[:, POS], axis=1)
        est = np.linalg.norm(self.x_hat[:, POS] - self.x[:, POS], axis=1)
        out: dict[str, Any] = {"rms_pos_err_seen_m": {}, "rms_est_err_m": {}, "max_est_err_m": {}}
        for t0 in (0.0, 10.0, 45.0):
            m = self.window(t0, end) & np.isfinite(est)
            if m.any():
                key = f"{t0:g}-{end:g}"
                out["rms_pos_err_seen_m"][key] = float(np.sqrt(np.mean(seen[m] ** 2)))
                out["rms_est_err_m"][key] = float(np.sqrt(np.mean(est[m] ** 2)))
                out["max_est_err_m"][key] = float(np.max(est[m]))
        if self.est_log is not None:
            from autopilot.estimation.kf import ACCEPTED, REJECTED, RESET
            from autopilot.estimation.log import EST_LOG_COLUMNS

            st = self.est_log[:, EST_LOG_COLUMNS.index("gps_status")]
            out["gps_fixes"] = {
                "accepted": int(np.sum(st == ACCEPTED)),
                "rejected": int(np.sum(st == REJECTED)),
                "resets": int(np.sum(st == RESET)),
            }
            nis = self.est_log[:, EST_LOG_COLUMNS.index("nis")]
            nis = nis[np.isfinite(nis)]
            out["mean_nis"] = float(np.mean(nis)) if nis.size else None
        return out

    def _rotor_summary(self) -> dict[str, Any]:
        """The rotor plant: rotor speed range and largest droop, flapping and throttle extremes."""
        assert self.rotor is not None
        # the governor's integral is the plant's own (NaN in a process run's record)
        cols = [ROTOR_RECORD.index(k) for k in ("a1_rad", "b1_rad", "omega_rad_s", "throttle")]
        r = self.rotor[np.all(np.isfinite(self.rotor[:, cols]), axis=1)]
        if r.size == 0:
            return {}
        om = r[:, ROTOR_RECORD.index("omega_rad_s")]
        thr = r[:, ROTOR_RECORD.index("throttle")]
        return {
            "omega_rad_s": [float(om.min()), float(om.max())],
            "max_droop_rad_s": float(om[0] - om.min()),
            "max_abs_a1_rad": float(np.max(np.abs(r[:, ROTOR_RECORD.index("a1_rad")]))),
            "max_abs_b1_rad": float(np.max(np.abs(r[:, ROTOR_RECORD.index("b1_rad")]))),
            "throttle": [float(thr.min()), float(thr.max())],
        }

    def write_est_csv(self, path: Path) -> bool:
        """est.csv: per tick, the estimate the controller flew on (position NWU, Euler) and
        the estimator's log; False (nothing written) when it flew on the truth."""
        if self.x_hat is None or self.est_log is None:
            return False
        from autopilot.estimation.log import EST_LOG_COLUMNS

        e = self.x_hat[:, EULER].copy()
        e[:, 2] = np.unwrap(e[:, 2])
        with path.open("w", newline="") as fh:
            csv.writer(fh).writerow((*EST_CSV_STATE, *EST_LOG_COLUMNS))
            write_rows(fh, np.column_stack([self.t_s, self.x_hat[:, POS], e, self.est_log]))
        return True

    def rows(self, psi_before: float | None = None) -> FloatArray:
        """The CSV rows; psi unwrapped (continuing from ``psi_before``, the unwrapped psi of
        the row before these, when the rows are a later part of a flight)."""
        psi = unwrap_after(self.x[:, PSI], psi_before)
        e = self.x[:, EULER].copy()
        e[:, 2] = psi
        att = self.att_cmd if self.att_cmd is not None else np.full((self.t_s.size, 2), np.nan)
        cols = [self.t_s, self.x[:, POS], e, self.ref[:, 0:3], self.psi_cmd, self.pitches, att]
        if self.rotor is not None:
            cols.append(self.rotor[:, [ROTOR_RECORD.index(k) for k in ROTOR_CSV]])
        return np.column_stack(cols)

    @property
    def header(self) -> tuple[str, ...]:
        """run.csv's columns: the paper's, then the rotor plant's where it flew."""
        return CSV_HEADER + (ROTOR_CSV if self.rotor is not None else ())

    def columns(self) -> dict[str, FloatArray]:
        """The CSV columns by name, for plotting."""
        rows = self.rows()
        return {name: rows[:, i] for i, name in enumerate(self.header)}

    def write_csv(self, path: Path, mcap: bool | None = None) -> None:
        """``path`` (run.csv's columns) and, beside a file named ``run.csv`` (every run's
        record; ``mcap`` True or False: whatever its name, or never), ``flight.mcap`` with the
        numbers the file holds (:mod:`autopilot.mcap_log`): after the flight, never in its loop."""
        rows = self.rows()
        with path.open("w", newline="") as fh:
            csv.writer(fh).writerow(self.header)
            write_rows(fh, rows)
        if mcap if mcap is not None else path.name == "run.csv":
            from autopilot.mcap_log import McapMissingError, write_mcap_as_csv

            try:  # run.csv's numbers, from the rows (reading the file back costs more than the MCAP)
                write_mcap_as_csv(self.header, rows, path.with_name("flight.mcap"))
            except McapMissingError as exc:  # the run's other outputs still follow
                warnings.warn(f"{path.with_name('flight.mcap')} not written: {exc}", stacklevel=2)

    def write_world_csv(self, path: Path) -> bool:
        """world.csv: per tick, the air (earth NWU, m/s) and the pitches the servos reached
        (rad), where the flight had a world; False (nothing written) without one."""
        if self.air_nwu_m_s is None or self.servo_rad is None:
            return False
        with path.open("w", newline="") as fh:
            csv.writer(fh).writerow(WORLD_CSV_HEADER)
            write_rows(fh, np.column_stack([self.t_s, self.air_nwu_m_s, self.servo_rad]))
        return True

    def write_summary(self, path: Path) -> dict[str, Any]:
        s = self.summary()
        path.write_text(json.dumps(s, indent=2) + "\n")
        return s


def window_rms_m(record: FlightRecord, t0_s: float, t1_s: float) -> float:
    """RMS 3-D position error [m] over [t0_s, t1_s] of trajectory time (the summary's
    windows, a scenario's ``error_windows_s``); NaN when no tick falls in the window."""
    m = record.window(t0_s, t1_s)
    if not m.any():
        return math.nan
    return float(np.sqrt(np.mean(record.pos_err_m[m] ** 2)))


def rotor_record(truth: FloatArray) -> FloatArray:
    """The rotor columns of :data:`ROTOR_RECORD` from what a plant process reports per state
    (a1, b1, rotor speed, throttle: the governor's integral is the plant's own, NaN here)."""
    out = np.full((truth.shape[0], len(ROTOR_RECORD)), np.nan)
    for i, k in enumerate(("a1_rad", "b1_rad", "omega_rad_s", "throttle")):
        out[:, ROTOR_RECORD.index(k)] = truth[:, i]
    return out


def unwrap_after(psi: FloatArray, psi_before: float | None) -> FloatArray:
    """``psi`` unwrapped, continuing from ``psi_before`` (the unwrapped value of the sample
    before these, when they are a later part of a flight; None: they are the first)."""
    if psi_before is None or not psi.size:
        return np.asarray(np.unwrap(psi))
    return np.asarray(np.unwrap(np.concatenate([[psi_before], psi]))[1:])


def format_rows(rows: FloatArray) -> str:
    """CSV lines in run.csv's number format (9 significant digits), one format per row:
    a few microseconds a row, so streaming the record costs the loop next to nothing."""
    fmt = ",".join(["%.9g"] * rows.shape[1]) + "\r\n"  # csv.writer's line ending
    return "".join(fmt % tuple(r) for r in rows.tolist())


def write_rows(fh: Any, rows: FloatArray) -> None:
    fh.write(format_rows(rows))
