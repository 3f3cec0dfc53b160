"""The safety envelope: a flight that leaves it is **lost**, whether or not it comes back.

One rule for every verdict the bench gives (the Python API's exit status, a campaign's
``diverged`` column, the comparison's and the tuner's ``lost``), read from the flight's
record alone. A flight is lost, with the first reason that applies:

* its state is not finite;
* its tilt (the angle between the body's up axis and the vertical) exceeds ``max_tilt_deg``
  at any tick: beyond 60 deg a helicopter of this size has lost most of its lift margin and
  is being flown by its recovery, not by its tracking;
* it strikes the ground: it reaches the ground (height at most ``ground_m``) descending
  faster than ``max_touchdown_m_s`` (a landing at the bench's 0.5 m/s is not a strike);
* after ``settle_s`` of trajectory time its position error exceeds ``max_error_m``: a
  helicopter 115 m off its path has left any airspace it was cleared for, even if it flies
  back (before: lost only if it tumbled or ended far off).

Whether a flight **converged** (its error within ``converge_m`` from some time to the end)
is a separate figure (:mod:`autopilot.flight_metrics`). Each threshold is configurable: a
campaign's ``[envelope]`` table, the comparison's and the API's ``envelope`` argument.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

from autopilot.metrics import FlightRecord
from heli_common.config import ConfigError
from heli_common.state import PHI, THETA, Z_U


def tilt_rad(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Per row of states ``x``: the angle between the body's up axis and the vertical [rad]."""
    with np.errstate(invalid="ignore"):
        return np.asarray(np.arccos(np.clip(np.cos(x[:, PHI]) * np.cos(x[:, THETA]), -1.0, 1.0)))


@dataclass(frozen=True)
class Envelope:
    settle_s: float = 10.0  # trajectory time after which the error limit applies (the [10, end] window)
    max_error_m: float = 10.0  # 3-D position error allowed after settle_s
    max_tilt_deg: float = 60.0  # at any tick
    ground_m: float = 0.0  # the ground's height (earth NWU z) the vehicle must not strike
    max_touchdown_m_s: float = 1.0  # descent rate at which touching the ground is a strike

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ConfigError(f"envelope: {f.name}: expected a finite number, got {v!r}")
        if self.settle_s < 0 or self.max_error_m <= 0 or self.max_touchdown_m_s <= 0:
            raise ConfigError("envelope: settle_s >= 0, max_error_m > 0 and max_touchdown_m_s > 0")
        if not 0.0 < self.max_tilt_deg < 180.0:
            raise ConfigError(f"envelope: max_tilt_deg: expected in (0, 180), got {self.max_tilt_deg}")

    @classmethod
    def from_table(cls, table: Mapping[str, object], source: str = "envelope") -> Envelope:
        """From a TOML table (unknown keys refused by name); missing keys keep the defaults."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(f"{source}: unknown key(s) {unknown}; known: {sorted(known)}")
        try:
            return cls(**{k: float(v) if isinstance(v, int) and not isinstance(v, bool) else v  # type: ignore[arg-type]
                          for k, v in table.items()})  # fmt: skip
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None

    def describe(self) -> str:
        return (f"lost: a non-finite state, tilt > {self.max_tilt_deg:g} deg, a ground strike "
                f"(> {self.max_touchdown_m_s:g} m/s down), or an error > {self.max_error_m:g} m "
                f"after {self.settle_s:g} s")  # fmt: skip

    def leaves(self, rec: FlightRecord) -> str:
        """Why the flight of ``rec`` is lost ("" when it stayed inside the envelope)."""
        x = rec.x
        if x.size == 0:
            return ""
        if not np.all(np.isfinite(x)):
            k = int(np.argmax(~np.all(np.isfinite(x), axis=1)))
            return f"non-finite state (t = {rec.t_s[k]:.2f} s)"
        tilt = np.degrees(tilt_rad(x))
        over = np.flatnonzero(tilt > self.max_tilt_deg)
        if over.size:
            k = int(over[0])
            return f"tilt > {self.max_tilt_deg:g} deg ({tilt[k]:.0f} deg at t = {rec.t_s[k]:.2f} s)"
        strike = self._strike(rec)
        if strike:
            return strike
        tt = rec.trajectory_time_s
        err = rec.pos_err_m
        with np.errstate(invalid="ignore"):
            late = tt >= self.settle_s - 1e-9  # NaN (holding, landing) is not trajectory time
        far = np.flatnonzero(late & (err > self.max_error_m))
        if far.size:
            k = int(far[np.argmax(err[far])])
            return (f"error > {self.max_error_m:g} m after {self.settle_s:g} s "
                    f"({err[k]:.1f} m at t = {rec.t_s[k]:.2f} s)")  # fmt: skip
        return ""

    def _strike(self, rec: FlightRecord) -> str:
        z = rec.x[:, Z_U]
        if z.size < 2:
            return ""
        dt = np.diff(rec.t_s)
        with np.errstate(divide="ignore", invalid="ignore"):
            down = np.where(dt > 0, (z[:-1] - z[1:]) / dt, 0.0)
        # the descent rate on the way in: the tick that reaches the ground is cut short by the
        # contact model's clamp, so the tick before it counts too
        approach = np.maximum(down, np.concatenate(([0.0], down[:-1])))
        hit = np.flatnonzero((z[1:] <= self.ground_m + 1e-6) & (approach > self.max_touchdown_m_s))
        if not hit.size:
            return ""
        k = int(hit[0]) + 1
        return f"ground strike ({approach[k - 1]:.1f} m/s down at t = {rec.t_s[k]:.2f} s)"


DEFAULT = Envelope()

__all__ = ["DEFAULT", "Envelope", "tilt_rad"]
