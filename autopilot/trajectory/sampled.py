"""A trajectory from time-stamped samples, interpolated by C2 cubic splines (scipy CubicSpline).

Position, velocity and acceleration (NWU) come from the spline and its first two
derivatives, so the controller gets exact, smooth feedforward (no NaN inside the
sampled span). Boundary condition: not-a-knot (the spline is the unique cubic through
the first/last four samples there), which reproduces smooth curves to O(h^4) in position
without inventing zero end-velocities; see tests/test_trajectory_codec.py for the
measured fidelity against the paper's spiral.

A spline through a corner (a jump of velocity, e.g. the end of the paper's climb at
40 s) rings for several samples on both sides. ``break_mask`` marks such samples per axis
(bit 0 = x north, bit 1 = y west/east, bit 2 = z up/down: the axes are the same in NWU
and NED): the spline of a marked axis is split there into independent pieces sharing the
sample, so the corner is kept sharp and the rest stays C2. At a break the derivatives
are left-continuous (the earlier piece is used up to and including the break time), the
convention of PaperSpiralCircle (climbing while t <= 40 s), so a decoded spiral gives
the controller the very same reference on every tick, the break tick included.

Outside [t_first, t_last] the position is held at the end sample with zero velocity and
acceleration (the controller then brakes to a hover there).
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from autopilot.trajectory.base import Trajectory
from heli_common.state import FloatArray

N_AXES = 3


class TimedSamples(Trajectory):
    """What every trajectory through time-stamped samples keeps: the times, the positions
    and an optional yaw (unwrapped; linear between samples), and how it reports them."""

    _t: FloatArray
    _pos: FloatArray
    _yaw: FloatArray | None

    def _keep_samples(self, t: FloatArray, pos: FloatArray, yaw_nwu_rad: npt.ArrayLike | None) -> None:
        self._t = t
        self._pos = pos
        self.duration_s = float(t[-1])
        self._yaw = None
        if yaw_nwu_rad is not None:
            yaw = np.asarray(yaw_nwu_rad, dtype=float).reshape(-1)
            if yaw.shape != (t.size,):
                raise ValueError(f"yaw_nwu_rad must have {t.size} values, got {yaw.shape}")
            if not np.all(np.isfinite(yaw)):
                raise ValueError("yaw samples must be finite")
            self._yaw = np.unwrap(yaw)

    @property
    def t_s(self) -> FloatArray:
        return self._t.copy()

    @property
    def pos_nwu_m(self) -> FloatArray:
        return self._pos.copy()

    @property
    def has_yaw(self) -> bool:
        return self._yaw is not None

    def yaw_nwu_rad(self, t_s: npt.ArrayLike) -> FloatArray:
        """Commanded yaw (NWU psi, in [-pi, pi)): linear between unwrapped samples, held
        beyond the ends; NaN if none."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        if self._yaw is None:
            return np.full(t.size, np.nan)
        yaw = np.interp(t, self._t, self._yaw)
        return np.asarray((yaw + np.pi) % (2.0 * np.pi) - np.pi, dtype=float)


class SampledTrajectory(TimedSamples):
    """C2 cubic-spline trajectory through samples (t [s], pos NWU [m], optional yaw)."""

    def __init__(
        self,
        t_s: npt.ArrayLike,
        pos_nwu_m: npt.ArrayLike,
        yaw_nwu_rad: npt.ArrayLike | None = None,
        break_mask: Sequence[int] | npt.NDArray[np.integer] | None = None,
    ) -> None:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        pos = np.asarray(pos_nwu_m, dtype=float)
        n = t.size
        if n < 2:
            raise ValueError(f"need at least 2 samples, got {n}")
        if pos.shape != (n, N_AXES):
            raise ValueError(f"pos_nwu_m must have shape ({n}, 3), got {pos.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(pos))):
            raise ValueError("sample times and positions must be finite")
        if not np.all(np.diff(t) > 0.0):
            raise ValueError("sample times must be strictly increasing")
        if t[0] < 0.0:
            raise ValueError(f"sample times start at t >= 0 (mission start), got {t[0]}")
        mask = np.zeros(n, dtype=np.int64) if break_mask is None else np.asarray(break_mask)
        if mask.shape != (n,) or np.any(mask < 0) or np.any(mask > 2**N_AXES - 1):
            raise ValueError(f"break_mask must be {n} integers in [0, 7]")
        self._keep_samples(t, pos, yaw_nwu_rad)
        self._mask = mask.astype(np.int64)
        # imported here: scipy.interpolate costs every process that loads the trajectories 0.3 s
        from scipy.interpolate import CubicSpline

        # Per axis: the piece start times and their splines (split where the mask says).
        self._pieces: list[tuple[FloatArray, list[CubicSpline]]] = []
        for axis in range(N_AXES):
            cuts = [
                0,
                *[int(i) for i in np.flatnonzero(self._mask & (1 << axis)) if 0 < i < n - 1],
                n - 1,
            ]
            starts = np.array([t[a] for a in cuts[:-1]])
            splines = [
                CubicSpline(t[a : b + 1], pos[a : b + 1, axis], bc_type="not-a-knot")
                for a, b in itertools.pairwise(cuts)
            ]
            self._pieces.append((starts, splines))
        # The same splines as plain lists, for evaluate_row (one time per control tick).
        self._scalar = [
            (starts.tolist(), [sp.x.tolist() for sp in splines], [sp.c.tolist() for sp in splines])
            for starts, splines in self._pieces
        ]

    @property
    def break_mask(self) -> npt.NDArray[np.int64]:
        return self._mask.copy()

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        out = np.zeros((t.size, 9))
        inside = (t >= self._t[0]) & (t <= self._t[-1])
        tc = np.clip(t, self._t[0], self._t[-1])
        for axis, (starts, splines) in enumerate(self._pieces):
            # side="left": a time equal to a break belongs to the piece that ends there.
            piece = np.clip(np.searchsorted(starts, tc, side="left") - 1, 0, len(splines) - 1)
            for k, spline in enumerate(splines):
                sel = piece == k
                if not np.any(sel):
                    continue
                tk = tc[sel]
                out[sel, axis] = spline(tk)
                # Outside the span the vehicle holds the end sample: zero derivatives.
                out[sel, 3 + axis] = np.where(inside[sel], spline(tk, 1), 0.0)
                out[sel, 6 + axis] = np.where(inside[sel], spline(tk, 2), 0.0)
        return out

    def evaluate_row(self, t_s: float) -> FloatArray:
        """As ``sample`` at one time, by evaluating the cubic pieces directly (~10x faster)."""
        lo, hi = float(self._t[0]), float(self._t[-1])
        t = min(max(float(t_s), lo), hi)
        inside = lo <= float(t_s) <= hi
        out = [0.0] * 9
        for axis, (starts, knots, coefs) in enumerate(self._scalar):
            piece = min(max(bisect.bisect_left(starts, t) - 1, 0), len(knots) - 1)
            x, c = knots[piece], coefs[piece]
            i = min(max(bisect.bisect_right(x, t) - 1, 0), len(x) - 2)
            d = t - x[i]
            c0, c1, c2, c3 = c[0][i], c[1][i], c[2][i], c[3][i]
            out[axis] = ((c0 * d + c1) * d + c2) * d + c3
            if inside:
                out[3 + axis] = (3.0 * c0 * d + 2.0 * c1) * d + c2
                out[6 + axis] = 6.0 * c0 * d + 2.0 * c1
        return np.array(out)
