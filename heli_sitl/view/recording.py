"""Recorded flights as the replay reads them: run.csv's columns by name, from whichever file
a run left (:func:`load_recording`), and the :class:`ViewFrame` at any time of it.

Accepted: a run directory (its run.csv, else flight.parquet, flight.mcap, flight.tlog or
ground.tlog, in that order), or one of those files: ``run.csv`` (any CSV with run.csv's
header), ``flight.parquet`` (``Flight.save``), ``*.mcap`` (the run's MCAP,
``autopilot.mcap_log.read_run_mcap``), ``*.tlog`` (``heli-ground log``, the process runs'
flight.tlog: ground.log.tlog_columns).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heli_common.state import PITCH_LABELS, FloatArray
from heli_sitl.view.frame import ViewFrame

Columns = dict[str, FloatArray]
IN_A_DIRECTORY = ("run.csv", "flight.parquet", "flight.mcap", "flight.tlog", "ground.tlog")
NEEDED = ("t_s", "x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")


class RecordingError(ValueError):
    """The file is not a flight the view can replay (the reason, in one line)."""


def find_recording(path: Path) -> Path:
    """The file to replay: ``path`` itself, or the first of :data:`IN_A_DIRECTORY` in it."""
    if path.is_dir():
        for name in IN_A_DIRECTORY:
            if (path / name).is_file():
                return path / name
        raise RecordingError(f"{path}: no {', '.join(IN_A_DIRECTORY)} in this directory")
    if not path.is_file():
        raise RecordingError(f"{path}: no such file or directory")
    return path


def read_columns(path: Path) -> Columns:
    """run.csv's columns from any accepted file (see the module docstring); a file its reader
    cannot read is a :class:`RecordingError` naming the file and what is wrong with it."""
    suffix = path.suffix.lower()
    kinds = {".csv": "run.csv", ".parquet": "flight.parquet", ".mcap": "MCAP file", ".tlog": ".tlog"}
    if suffix not in kinds:
        raise RecordingError(f"{path}: not a run.csv, flight.parquet, .mcap or .tlog")
    try:
        cols = _read(path, suffix)
    except RecordingError:
        raise
    except Exception as exc:  # each reader's own errors (csv, Arrow, MCAP, MAVLink): one clear line
        why = f"{type(exc).__name__}: {exc}"
        raise RecordingError(f"{path}: cannot be read as a {kinds[suffix]} ({why})") from None
    missing = [c for c in NEEDED if c not in cols]
    if missing:
        raise RecordingError(f"{path}: no column {', '.join(missing)}")
    if len(cols["t_s"]) == 0:
        raise RecordingError(f"{path}: no rows")
    return cols


def _read(path: Path, suffix: str) -> Columns:
    if suffix == ".csv":
        from autopilot.mcap_log import read_run_csv

        return read_run_csv(path)
    if suffix == ".parquet":
        import pyarrow.parquet as pq

        table = pq.read_table(path)
        return {name: np.asarray(table.column(name).to_numpy(), dtype=float) for name in table.column_names}
    if suffix == ".mcap":
        from autopilot.mcap_log import read_run_mcap

        return read_run_mcap(path)
    from ground.log import tlog_columns

    return tlog_columns(path)


@dataclass(frozen=True)
class Recording:
    """A flight's columns with the lookups the replay needs."""

    source: Path
    cols: Columns

    @property
    def t_s(self) -> FloatArray:
        return self.cols["t_s"]

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def positions(self) -> FloatArray:
        return np.column_stack([self.cols[k] for k in ("x_m", "y_m", "z_m")])

    def reference(self) -> FloatArray | None:
        if not all(k in self.cols for k in ("x_ref_m", "y_ref_m", "z_ref_m")):
            return None
        return np.column_stack([self.cols[k] for k in ("x_ref_m", "y_ref_m", "z_ref_m")])

    def index_at(self, t_s: float) -> int:
        """The last row at or before ``t_s`` (the first row before the start)."""
        return max(int(np.searchsorted(self.t_s, t_s, side="right")) - 1, 0)

    def frame(self, i: int) -> ViewFrame:
        c = self.cols

        def get(name: str) -> float | None:
            v = c.get(name)
            return None if v is None or not math.isfinite(v[i]) else float(v[i])

        pos = (float(c["x_m"][i]), float(c["y_m"][i]), float(c["z_m"][i]))
        ref = tuple(get(k) for k in ("x_ref_m", "y_ref_m", "z_ref_m"))
        ref_ok = all(v is not None for v in ref)
        pitches = tuple(get(k) for k in PITCH_LABELS)
        a1, b1 = get("a1_rad"), get("b1_rad")
        return ViewFrame(
            t_s=float(c["t_s"][i]), pos_nwu_m=pos,
            euler_flu_rad=(float(c["phi_rad"][i]), float(c["theta_rad"][i]), float(c["psi_rad"][i])),
            ref_nwu_m=ref if ref_ok else None,  # type: ignore[arg-type]
            err_m=math.dist(pos, ref) if ref_ok else None,  # type: ignore[arg-type]
            pitches_rad=pitches if all(p is not None for p in pitches) else None,  # type: ignore[arg-type]
            rotor_speed_rad_s=get("omega_rad_s"),
            flapping_rad=(a1, b1) if a1 is not None and b1 is not None else None,
            mode="replay",
        )  # fmt: skip


def load_recording(path: Path | str) -> Recording:
    """The flight in ``path`` (a run directory or a file: the module docstring)."""
    src = find_recording(Path(path))
    return Recording(src, read_columns(src))
