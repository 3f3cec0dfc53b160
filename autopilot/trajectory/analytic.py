"""Analytic trajectories: the paper's spiral-then-circle, hover and straight lines."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from autopilot.trajectory.base import Trajectory
from heli_common.config import spec
from heli_common.state import FloatArray


@dataclass(frozen=True)
class PaperSpiralCircle(Trajectory):
    """Zhu & Huo Section 5: xc = R sin(2 pi t/T), yc = R (cos(2 pi t/T) - 1), zc = min(v t, v t1).

    The climb stops abruptly at ``climb_end_s`` (the slope jump the paper shows at 40 s).
    """

    radius_m: float = spec("m", 0.0, 1000.0, default=10.0)
    period_s: float = spec("s", 0.0, 1e5, lo_open=True, default=80.0)
    climb_rate_m_s: float = spec("m/s", -10.0, 10.0, default=0.5)
    climb_end_s: float = spec("s", 0.0, 1e5, default=40.0)
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True, default=120.0)

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float)
        w = 2.0 * math.pi / self.period_s
        r = self.radius_m
        s, c = np.sin(w * t), np.cos(w * t)
        climbing = t <= self.climb_end_s
        out = np.empty((t.size, 9))
        out[:, 0] = r * s
        out[:, 1] = r * (c - 1.0)
        out[:, 2] = self.climb_rate_m_s * np.minimum(t, self.climb_end_s)
        out[:, 3] = r * w * c
        out[:, 4] = -r * w * s
        out[:, 5] = np.where(climbing, self.climb_rate_m_s, 0.0)
        out[:, 6] = -r * w * w * s
        out[:, 7] = -r * w * w * c
        out[:, 8] = 0.0
        return out

    def evaluate_row(self, t_s: float) -> FloatArray:
        w = 2.0 * math.pi / self.period_s
        r, s, c = self.radius_m, math.sin(w * t_s), math.cos(w * t_s)
        climb = self.climb_rate_m_s
        return np.array([
            r * s, r * (c - 1.0), climb * min(t_s, self.climb_end_s),
            r * w * c, -r * w * s, climb if t_s <= self.climb_end_s else 0.0,
            -r * w * w * s, -r * w * w * c, 0.0,
        ])  # fmt: skip


@dataclass(frozen=True)
class StraightLine(Trajectory):
    """Constant velocity from a start point: pos = start + vel t (a trimmed climb or cruise)."""

    start_nwu_m: tuple[float, float, float] = spec("m", -1e6, 1e6, default=(0.0, 0.0, 0.0))
    vel_nwu_m_s: tuple[float, float, float] = spec("m/s", -50.0, 50.0, default=(0.0, 0.0, 0.0))
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True, default=60.0)

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1, 1)
        out = np.zeros((t.shape[0], 9))
        out[:, 0:3] = np.asarray(self.start_nwu_m) + t * np.asarray(self.vel_nwu_m_s)
        out[:, 3:6] = self.vel_nwu_m_s
        return out
