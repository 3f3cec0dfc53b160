"""A trajectory from a table of samples (a CSV file, or arrays), interpolated so that the
reference is continuous in acceleration and its velocity and acceleration are the exact
derivatives of its position (exact feedforward: never NaN).

The file: one header row naming the columns, in any order (names case-insensitive), then
one row per sample; blank lines and lines starting with ``#`` are skipped (comments), so
errors name the *file line* (as a text editor or a spreadsheet numbers it) and the data
row (1 = the first sample). Earth NWU (x north, y west, z up), SI units:

* required: ``t_s`` (time from the start of the flight), ``x_m``, ``y_m``, ``z_m``
* optional: ``vx_m_s, vy_m_s, vz_m_s`` (velocity), ``ax_m_s2, ay_m_s2, az_m_s2``
  (acceleration, only with velocity), each group all three or none; ``yaw_rad``.

The plain ``t, x, y, z[, yaw]`` (``heli-ground fly``'s header) names the same columns, and a
flight's ``run.csv`` flies back: its ``t_s, x_m, y_m, z_m`` (the flown truth; ``t, x, y, z`` in a
run.csv from before the one schema), the rest ignored.

The interpolant, per axis, by what the table gives:

* position only: the C2 cubic spline (scipy CubicSpline, not-a-knot ends), the spline the
  vehicle itself puts through uploaded samples (:class:`~autopilot.trajectory.sampled.
  SampledTrajectory` without breaks: the same reference from the same samples);
* position and velocity: piecewise quintics through both, the knots' accelerations
  chosen so that the jerk is continuous too and zero at the two ends: among all curves
  with a square-integrable jerk through these positions and velocities it is the one with
  the least integral of squared jerk (one tridiagonal solve);
* position, velocity and acceleration: the quintic Hermite interpolant through all three
  (C2, each piece determined by its two rows alone).

Yaw: the reference (:mod:`autopilot.reference`) carries no yaw command; the controller
points the nose along the path (yaw augmentation). The ``yaw_rad`` column is read,
checked and kept (:meth:`CsvTrajectory.yaw_nwu_rad`, as SampledTrajectory keeps the yaw of
uploaded samples) for a controller that will follow it; today it is not flown.

Before the first row (when it is after t = 0) and after the last, the reference holds that
row's position with zero velocity and acceleration (the controller brakes to a hover; a
table that does not end at rest steps its velocity there); ``duration_s`` is the last
row's time.

:func:`trajectory_from_csv` reads a file; a scenario's ``[trajectory] kind = "csv"`` with
``path`` (:mod:`autopilot.trajectory.factory`) names one.
"""

from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_banded

from autopilot.metrics import CSV_HEADER as RECORD_HEADER
from autopilot.metrics import LEGACY_CSV_HEADER
from autopilot.reference import ACC_0, N_REF, POS_0, REF_ACC, REF_POS, REF_VEL, VEL_0
from autopilot.trajectory.sampled import TimedSamples
from heli_common.config import ConfigError
from heli_common.state import FloatArray

TIME = "t_s"
POSITION = ("x_m", "y_m", "z_m")
VELOCITY = ("vx_m_s", "vy_m_s", "vz_m_s")
ACCELERATION = ("ax_m_s2", "ay_m_s2", "az_m_s2")
YAW = "yaw_rad"
REQUIRED = (TIME, *POSITION)
COLUMNS = (*REQUIRED, *VELOCITY, *ACCELERATION, YAW)  # every accepted column, in the usual order
# the plain header (heli-ground fly's t,x,y,z[,yaw], the most common form) names the same
PLAIN = {"t": TIME, "x": POSITION[0], "y": POSITION[1], "z": POSITION[2], "yaw": YAW}
MIN_ROWS = 2  # one interval: two rows determine a piece (a line, or a quintic when derivatives are given)


def table_columns(header: list[str]) -> tuple[list[str], list[int] | None]:
    """A trajectory table's header as the SI column names (the plain ``t, x, y, z, yaw`` named
    as ``t_s, x_m, ...``), and which columns to keep: None for all; for a flight's run.csv its
    truth ``t, x, y, z`` (a flown record flies back), the rest ignored. Every trajectory reader
    (this one, ``heli-ground fly``'s) reads a header through here."""
    raw = [h.strip().lower() for h in header]
    keep = None
    for record, truth in ((RECORD_HEADER, REQUIRED), (LEGACY_CSV_HEADER, ("t", "x", "y", "z"))):
        if set(record) <= set(raw):  # a flight's record (today's run.csv, or one from before)
            keep = [raw.index(c) for c in truth]
            raw = [raw[j] for j in keep]
            break
    return [PLAIN.get(name, name) for name in raw], keep


class CsvTrajectory(TimedSamples):
    """C2 trajectory through samples: time [s], position NWU [m], optional velocity [m/s],
    acceleration [m/s^2] (needs velocity) and yaw [rad] (kept, not flown: see the module)."""

    def __init__(
        self,
        t_s: npt.ArrayLike,
        pos_nwu_m: npt.ArrayLike,
        vel_nwu_m_s: npt.ArrayLike | None = None,
        acc_nwu_m_s2: npt.ArrayLike | None = None,
        yaw_nwu_rad: npt.ArrayLike | None = None,
    ) -> None:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        n = t.size
        if n < MIN_ROWS:
            raise ValueError(f"need at least {MIN_ROWS} samples, got {n}")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"sample times must be finite (sample {_first(~np.isfinite(t))}, 0-based)")
        if not np.all(np.diff(t) > 0.0):
            raise ValueError(f"sample times must increase (sample {_first(np.diff(t) <= 0.0) + 1}, 0-based)")
        if t[0] < 0.0:
            raise ValueError(f"sample times start at t >= 0 (the flight's start), got {t[0]}")
        pos = _samples(pos_nwu_m, n, "pos_nwu_m")
        vel = None if vel_nwu_m_s is None else _samples(vel_nwu_m_s, n, "vel_nwu_m_s")
        acc = None if acc_nwu_m_s2 is None else _samples(acc_nwu_m_s2, n, "acc_nwu_m_s2")
        if acc is not None and vel is None:
            raise ValueError("acceleration samples need velocity samples")
        self._keep_samples(t, pos, yaw_nwu_rad)
        # imported here: scipy.interpolate costs every process that loads the trajectories 0.3 s
        from scipy.interpolate import CubicSpline, PPoly

        pp: PPoly
        if vel is None:
            pp = CubicSpline(t, pos, axis=0, bc_type="not-a-knot")
        else:
            if acc is None:
                acc = _least_jerk_accelerations(t, pos, vel)
            pp = PPoly.construct_fast(_quintic_hermite(t, pos, vel, acc), t)
        self._pp = pp
        self._pp_vel = pp.derivative(1)
        self._pp_acc = pp.derivative(2)
        # the same pieces as plain lists for evaluate_row (one time per control tick):
        # [interval][axis][power, highest first] for position, velocity, acceleration
        self._knots: list[float] = t.tolist()
        self._coef = [np.transpose(p.c, (1, 2, 0)).tolist() for p in (pp, self._pp_vel, self._pp_acc)]

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        lo, hi = self._t[0], self._t[-1]
        tc = np.clip(t, lo, hi)
        inside = ((t >= lo) & (t <= hi))[:, None]
        out = np.empty((t.size, N_REF))
        out[:, REF_POS] = self._pp(tc)
        # outside the table the reference holds the end row: zero derivatives
        out[:, REF_VEL] = np.where(inside, self._pp_vel(tc), 0.0)
        out[:, REF_ACC] = np.where(inside, self._pp_acc(tc), 0.0)
        return out

    def evaluate_row(self, t_s: float) -> FloatArray:
        """As ``sample`` at one time, by Horner on the pieces' coefficients (no array set-up)."""
        x = self._knots
        t = min(max(float(t_s), x[0]), x[-1])
        inside = x[0] <= float(t_s) <= x[-1]
        i = min(max(bisect.bisect_right(x, t) - 1, 0), len(x) - 2)
        d = t - x[i]
        out = [0.0] * N_REF
        for first, coef in zip((POS_0, VEL_0, ACC_0), self._coef if inside else self._coef[:1], strict=False):
            for axis, c in enumerate(coef[i]):
                v = 0.0
                for ck in c:
                    v = v * d + ck
                out[first + axis] = v
        return np.array(out)



def _first(mask: npt.NDArray[np.bool_]) -> int:
    return int(np.flatnonzero(mask)[0])


def _samples(values: npt.ArrayLike, n: int, name: str) -> FloatArray:
    a = np.asarray(values, dtype=float)
    if a.shape != (n, 3):
        raise ValueError(f"{name} must have shape ({n}, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (sample {_first(~np.all(np.isfinite(a), axis=1))}, 0-based)")
    return a


def _quintic_hermite(t: FloatArray, p: FloatArray, v: FloatArray, a: FloatArray) -> FloatArray:
    """PPoly coefficients (6, n-1, 3), highest power first, of the quintics that take each
    row's position, velocity and acceleration at both ends of each interval."""
    h = np.diff(t)[:, None]
    dp = p[1:] - p[:-1]
    v0, v1, a0, a1 = v[:-1], v[1:], a[:-1], a[1:]
    c = np.empty((6, t.size - 1, 3))
    c[0] = (12.0 * dp - 6.0 * (v0 + v1) * h - (a0 - a1) * h**2) / (2.0 * h**5)
    c[1] = (-30.0 * dp + (16.0 * v0 + 14.0 * v1) * h + (3.0 * a0 - 2.0 * a1) * h**2) / (2.0 * h**4)
    c[2] = (20.0 * dp - (12.0 * v0 + 8.0 * v1) * h - (3.0 * a0 - a1) * h**2) / (2.0 * h**3)
    c[3] = 0.5 * a0
    c[4] = v0
    c[5] = p[:-1]
    return c


def _least_jerk_accelerations(t: FloatArray, p: FloatArray, v: FloatArray) -> FloatArray:
    """The knots' accelerations that make the quintic Hermite pieces C3 with zero jerk at
    both ends (the least-squared-jerk interpolant of positions and velocities).

    On an interval of length h the quintic's jerk is S - (9 a0 - 3 a1) / h at its start and
    E + (9 a1 - 3 a0) / h at its end, S and E being fixed by the positions and velocities;
    equating the jerks at each inner knot and zeroing them at the ends is a strictly
    diagonally dominant tridiagonal system in the accelerations (9 against 3 + 3).
    """
    h = np.diff(t)[:, None]
    dp = p[1:] - p[:-1]
    v0, v1 = v[:-1], v[1:]
    s = 60.0 * dp / h**3 - (36.0 * v0 + 24.0 * v1) / h**2  # jerk at each interval's start, a = 0
    e = 60.0 * dp / h**3 - (24.0 * v0 + 36.0 * v1) / h**2  # jerk at each interval's end, a = 0
    g = 1.0 / h[:, 0]
    n = t.size
    ab = np.zeros((3, n))  # solve_banded's layout: super-, main and sub-diagonal
    ab[1, :-1] += 9.0 * g
    ab[1, 1:] += 9.0 * g
    ab[0, 1:] = -3.0 * g
    ab[2, :-1] = -3.0 * g
    rhs = np.zeros((n, 3))
    rhs[:-1] += s
    rhs[1:] -= e
    return np.asarray(solve_banded((1, 1), ab, rhs))


# ------------------------------------------------------------------------------ the file


def trajectory_from_csv(path: str | Path) -> CsvTrajectory:
    """Read a trajectory table (the module's format) into a :class:`CsvTrajectory`; a
    relative ``path`` is taken from the current directory. Every error is a ConfigError
    naming the file and, for a bad cell or row, its line in the file and its data row."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such trajectory table")
    try:
        text = p.read_text(encoding="utf-8-sig")  # utf-8-sig: spreadsheets write a BOM
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            rows.append((lineno, next(csv.reader([line]))))
        except csv.Error as exc:
            raise ConfigError(f"{p}: line {lineno}: bad CSV: {exc}") from exc
    accepted = ", ".join(COLUMNS)
    if not rows:
        raise ConfigError(f"{p}: empty: expected a header row naming the columns ({accepted})")
    head_line, header = rows[0]
    names, keep = table_columns(header)
    if keep is not None:
        rows = [(n, [cells[j] for j in keep] if len(cells) == len(header) else cells) for n, cells in rows]
        header = [header[j] for j in keep]
    unknown = [h.strip() for h, name in zip(header, names, strict=True) if name not in COLUMNS]
    if unknown:
        raise ConfigError(f"{p}: line {head_line}: unknown column(s) {unknown}; accepted: {accepted} "
                          "(or t, x, y, z, yaw; or a run.csv)")  # fmt: skip
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise ConfigError(f"{p}: line {head_line}: column(s) {twice} named more than once")
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        required = ", ".join(REQUIRED)
        raise ConfigError(f"{p}: line {head_line}: missing column(s) {missing}; required: {required}")
    for group, what in ((VELOCITY, "velocity"), (ACCELERATION, "acceleration")):
        have = [c for c in group if c in names]
        if have and len(have) < 3:
            raise ConfigError(
                f"{p}: line {head_line}: {what} needs all of {', '.join(group)} (got only {', '.join(have)})"
            )
    if ACCELERATION[0] in names and VELOCITY[0] not in names:
        raise ConfigError(f"{p}: line {head_line}: the acceleration columns need the velocity columns too")

    data = np.empty((len(rows) - 1, len(names)))
    for k, (lineno, cells) in enumerate(rows[1:]):
        where = f"{p}: line {lineno} (data row {k + 1})"
        if len(cells) != len(names):
            raise ConfigError(f"{where}: expected {len(names)} cells ({', '.join(names)}), got {len(cells)}")
        for j, (name, cell) in enumerate(zip(names, cells, strict=True)):
            try:
                value = float(cell)
            except ValueError:
                what = "empty" if not cell.strip() else f"not a number: {cell.strip()!r}"
                raise ConfigError(f"{where}: {name} is {what}") from None
            if not math.isfinite(value):
                raise ConfigError(f"{where}: {name} = {cell.strip()} is not a finite number")
            data[k, j] = value
        t = data[k, names.index(TIME)]
        if k == 0 and t < 0.0:
            raise ConfigError(f"{where}: t_s = {t} s: times start at t_s >= 0 (the flight's start)")
        if k > 0 and t <= data[k - 1, names.index(TIME)]:
            before = data[k - 1, names.index(TIME)]
            what = "repeats" if t == before else "goes back from"
            raise ConfigError(f"{where}: t_s = {t} s {what} the row before ({before} s): times must increase")
    if data.shape[0] < MIN_ROWS:
        raise ConfigError(
            f"{p}: {data.shape[0]} data row(s) (last line {rows[-1][0]}); a trajectory needs at least "
            f"{MIN_ROWS} (one interval to interpolate)"
        )

    def cols(group: tuple[str, ...]) -> FloatArray | None:
        return data[:, [names.index(c) for c in group]] if group[0] in names else None

    return CsvTrajectory(
        data[:, names.index(TIME)],
        data[:, [names.index(c) for c in POSITION]],
        cols(VELOCITY),
        cols(ACCELERATION),
        data[:, names.index(YAW)] if YAW in names else None,
    )
