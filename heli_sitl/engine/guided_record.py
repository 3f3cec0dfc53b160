"""A guided flight flown by another firmware (ArduPilot through ``heli-sitl up --firmware
ardupilot`` and ``heli-ground fly --guided``) as a :class:`~autopilot.metrics.FlightRecord`,
so the comparison's scorecard (:func:`heli_sitl.studies.scorecard.score`) reads it exactly as it reads
the TLC's and the PID's flights.

What the record holds, over the trajectory's time ``[0, duration]``: the plant's truth
(``plant.csv``, 100 Hz, on the firmware's clock), the reference the ground station streamed
(``track.csv``'s targets, NED -> NWU, interpolated to the plant's rows; velocity and
acceleration by differences of it: the feed-forward the firmware was sent is not logged),
and the blade pitches the swashplate made of the firmware's servo outputs. The heading
command and the saturation flags are the firmware's own business: NaN and none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from autopilot.metrics import FlightRecord
from ground.plots import read_csv_columns
from heli_common.frames import flip_rows
from heli_common.state import PITCH_LABELS, STATE_NAMES


def guided_record(plant_csv: Path, track_csv: Path, duration_s: float, extra: dict[str, object] | None = None
                  ) -> FlightRecord:  # fmt: skip
    tr, pl = read_csv_columns(track_csv), read_csv_columns(plant_csv)
    if tr["t_vehicle_s"].size < 2:
        raise ValueError(f"{track_csv}: fewer than two rows")
    t0 = float(tr["t_vehicle_s"][0] - tr["t_traj_s"][0])
    tt = pl["t_s"] - t0
    m = (tt >= -1e-9) & (tt <= duration_s + 1e-9)
    if m.sum() < 2:
        raise ValueError(f"{plant_csv}: no rows in the trajectory's time [0, {duration_s:g}] s")
    t = pl["t_s"][m]
    target_ned = np.column_stack([np.interp(t, tr["t_vehicle_s"], tr[f"target_{k}_m"]) for k in "ned"])
    pos = flip_rows(target_ned)
    vel = np.gradient(pos, t, axis=0)
    acc = np.gradient(vel, t, axis=0)
    x = np.column_stack([pl[n][m] for n in STATE_NAMES])
    pitches = np.column_stack([pl[n][m] for n in PITCH_LABELS])
    return FlightRecord(
        t_s=t, x=x, ref=np.hstack([pos, vel, acc]), pitches=pitches, psi_cmd=np.full(t.size, np.nan),
        saturated=np.zeros(t.size, dtype=bool), wall_s=float("nan"), extra=dict(extra or {}),
        traj_t_s=tt[m],
    )  # fmt: skip
