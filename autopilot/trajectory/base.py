"""The trajectory contract: ``evaluate(t)`` -> commanded position and its derivatives (NWU).

A trajectory is a pure function of time. ``sample(t)`` is the vectorised form the batch
runner uses; it returns an (N, 9) array [pos, vel, acc] with NaN where a derivative is
not known (the controller then relies on its pseudo-differentiators).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import numpy.typing as npt

from autopilot.reference import Reference
from heli_common.state import FloatArray


class Trajectory(ABC):
    """Commanded position (earth NWU) as a function of time from the start of the flight."""

    duration_s: float

    @abstractmethod
    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        """(N, 9) array: pos [m], vel [m/s], acc [m/s^2] in NWU at each time; NaN if unknown."""

    def evaluate_row(self, t_s: float) -> FloatArray:
        """``sample`` at one time, as the 9-vector the controller takes (once per control
        tick: kinds override it with a scalar path that avoids array set-up)."""
        row: FloatArray = self.sample(np.array([t_s]))[0]
        return row

    def evaluate(self, t_s: float) -> Reference:
        return Reference.from_row(self.sample(np.array([t_s]))[0])

    def initial_heading_rad(self) -> float | None:
        """Heading of the initial tangent, atan2(y'(0), x'(0)), if the trajectory knows it."""
        v = self.evaluate(0.0).vel_nwu_m_s
        if not np.all(np.isfinite(v[:2])) or float(np.hypot(v[0], v[1])) == 0.0:
            return None
        return float(np.arctan2(v[1], v[0]))
