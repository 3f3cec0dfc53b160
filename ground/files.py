"""Mission and trajectory files <-> the mission items heli-ground uploads.

Four inputs, chosen by the file name's extension (:func:`load_mission`):

* ``.waypoints`` / ``.txt``: the plain-text "QGC WPL 110" format (mavlink.io/en/file_formats)
  that QGroundControl, Mission Planner and MAVProxy read and write: a header line, then one
  tab-separated line per item ``INDEX CURRENT FRAME COMMAND P1 P2 P3 P4 X Y Z AUTOCONTINUE``.
  **Line 0 is the home position** (the convention QGroundControl and Mission Planner write
  and ArduPilot expects); heli-ground reads it as :attr:`MissionFile.home` and does NOT
  upload it: this vehicle's home is fixed by its ``--home`` option (HOME_POSITION,
  HOME_LAT/LON/ALT) and has no "item 0 is home" rule, so uploading line 0 would add a
  waypoint at ground level at home as the first item (which is what MAVProxy's
  ``wp load`` does: it uploads every line). The items uploaded are lines 1..n, renumbered
  from 0. :func:`write_waypoints` always writes home on line 0. X/Y are degrees in global
  frames and metres in local frames, as in the legacy MISSION_ITEM; "nan" is a valid value.
* ``.plan``: QGroundControl's JSON plan (mission version 2): ``mission.items`` of type
  ``SimpleItem`` (7 ``params``, ``null`` = NaN) and ``mission.plannedHomePosition``
  ``[lat, lon, alt AMSL]``. Complex items (surveys, corridor scans) are refused: they are
  QGroundControl's own patterns, expanded into simple items only inside QGroundControl.
  Errors name the JSON path (``mission.items[3].params``): Python's JSON parser keeps no
  line numbers for values, only for syntax errors.
* ``.toml``: a timed trajectory: a ``[trajectory]`` table as in the scenario files (``kind``
  plus that class's parameters, built by :func:`autopilot.trajectory.factory.trajectory_from_table`)
  and an optional ``[encoding]`` table (``dt_s``, default 0.5 s, the step the codec's
  fidelity study recommends; ``breaks_s``, the corner times, default ``[climb_end_s]`` for
  the paper's spiral, the arc's ends for an ``arc_turn``). A scenario file
  (``configs/scenario_paper.toml``) is accepted as is: its other tables are for the
  simulator and are ignored here.
* ``.csv``: timed trajectory samples ``t,x,y,z[,yaw]`` (header required; seconds from the
  start, NWU metres about home, yaw NWU radians), interpolated by the vehicle with cubic
  splines.

Timed trajectories become mission items with :mod:`autopilot.trajectory_codec` (header
MAV_CMD_USER_1 + samples MAV_CMD_WAYPOINT_USER_1 in MAV_FRAME_LOCAL_NED). Every error is a
:class:`FileFormatError` naming the file and, where the format has lines, the line.
"""

from __future__ import annotations

import csv
import json
import math
import re
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from autopilot import trajectory_codec as codec
from autopilot.trajectory.analytic import PaperSpiralCircle
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.csv_table import table_columns
from autopilot.trajectory.factory import trajectory_from_table
from autopilot.trajectory.manoeuvres import ArcTurn
from autopilot.trajectory.sampled import SampledTrajectory
from heli_common.config import ConfigError
from heli_common.geo import GeoPoint
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem
from heli_common.wire.mavlink.wire import f32_text

WPL_HEADER = "QGC WPL 110"
WPL_COLUMNS = 12
DEFAULT_DT_S = 0.5  # trajectory_codec: finer steps make the acceleration feedforward noisier
MAV_AUTOPILOT_GENERIC = 0
MAV_TYPE_HELICOPTER = 4
PLAN_CRUISE_SPEED_M_S = 2.0  # FlightLimits.cruise_speed_m_s, for QGroundControl's time estimates


class FileFormatError(ValueError):
    """A mission or trajectory file that cannot be used; the message names file and line."""

    def __init__(self, path: Path | str, line: int | None, reason: str) -> None:
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {reason}")
        self.path = Path(path)
        self.line = line
        self.reason = reason


@dataclass(frozen=True)
class MissionFile:
    """What a file holds: the items to upload (seq 0..n-1) and what is known about them."""

    items: tuple[MissionItem, ...]
    kind: str  # "waypoints", "plan" or "trajectory"
    home: GeoPoint | None = None  # the file's home (WPL line 0, plannedHomePosition)
    duration_s: float | None = None  # timed trajectories: flight time from the start

    @property
    def is_trajectory(self) -> bool:
        return codec.is_timed_trajectory(self.items)


@dataclass(frozen=True)
class TrajectorySamples:
    """Timed samples: t [s] from the start, NWU position [m] about home, optional NWU yaw [rad]."""

    t_s: npt.NDArray[np.float64]
    pos_nwu_m: npt.NDArray[np.float64]  # (n, 3)
    yaw_nwu_rad: npt.NDArray[np.float64] | None = None

    def to_items(self) -> list[MissionItem]:
        return codec.encode(self.t_s, self.pos_nwu_m, self.yaw_nwu_rad)


# ----------------------------------------------------------------------------- dispatch


def load_mission(path: Path | str, dt_s: float | None = None) -> MissionFile:
    """Read any supported file (by extension) into the items to upload.

    ``dt_s`` overrides the sampling step of a TOML trajectory.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".waypoints", ".txt"):
        return read_waypoints(p)
    if suffix == ".plan":
        return read_plan(p)
    if suffix == ".toml":
        return read_trajectory_toml(p, dt_s)
    if suffix == ".csv":
        samples = read_trajectory_csv(p)
        try:
            items = samples.to_items()
        except ValueError as exc:
            raise FileFormatError(p, None, f"trajectory: {exc}") from exc
        return MissionFile(tuple(items), "trajectory", None, float(samples.t_s[-1]))
    raise FileFormatError(p, None, "unknown file type: expected .waypoints, .plan, .toml or .csv")


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, None, f"cannot read: {exc}") from exc


# ----------------------------------------------------------------------------- x/y encoding


def _xy_to_file(item: MissionItem) -> tuple[float, float]:
    """MISSION_ITEM_INT x/y -> the float x/y of the legacy MISSION_ITEM (and of the files)."""
    if item.frame in ms.GLOBAL_FRAMES:
        return item.x / ms.DEG_E7, item.y / ms.DEG_E7
    if item.frame in ms.LOCAL_FRAMES:
        return item.x / ms.LOCAL_E4, item.y / ms.LOCAL_E4
    return float(item.x), float(item.y)


def _xy_from_file(frame: int, x: float, y: float) -> tuple[int, int]:
    """File x/y -> MISSION_ITEM_INT x/y (raises ValueError with the reason).

    Rounded, not truncated: 47.3977420 deg must stay 473977420 (MAVProxy truncates and
    loses 1e-7 deg, ~1 cm, now and then).
    """
    if frame in ms.GLOBAL_FRAMES:
        if math.isnan(x) and math.isnan(y):
            return 0, 0  # "no position given" (land here), 0/0 in MISSION_ITEM_INT
        if not (math.isfinite(x) and -90.0 <= x <= 90.0):
            raise ValueError(f"latitude {x} is not in [-90, 90]")
        if not (math.isfinite(y) and -180.0 <= y <= 180.0):
            raise ValueError(f"longitude {y} is not in [-180, 180]")
        return round(x * ms.DEG_E7), round(y * ms.DEG_E7)
    scale = ms.LOCAL_E4 if frame in ms.LOCAL_FRAMES else 1.0
    out = []
    for name, v in (("x", x), ("y", y)):
        if not math.isfinite(v):
            if scale == 1.0:  # MAV_FRAME_MISSION: x/y unused by every command this vehicle flies
                out.append(0)
                continue
            raise ValueError(f"{name} is not finite: {v}")
        scaled = round(v * scale)
        if not ms.INT32_MIN <= scaled <= ms.INT32_MAX:
            raise ValueError(f"{name} = {v} does not fit MISSION_ITEM_INT")
        out.append(scaled)
    return out[0], out[1]


def _fmt64(v: float) -> str:
    """Local x/y (metres = int / 1e4): repr reads back to the same double, so round(v * 1e4) too."""
    return "nan" if math.isnan(v) else repr(float(v))


def _fmt_deg(v: float) -> str:
    # 8 decimals: finer than the 1e-7 degE7 quantum, so round(x * 1e7) recovers the integer.
    return f"{v:.8f}"


# ----------------------------------------------------------------------------- QGC WPL 110


def read_waypoints(path: Path | str) -> MissionFile:
    """A QGC WPL 110 file -> items (lines 1..n, renumbered from 0) and home (line 0)."""
    p = Path(path)
    lines = _read_text(p).splitlines()
    if not lines or not re.fullmatch(r"QGC WPL \d+", lines[0].strip()):
        raise FileFormatError(p, 1, f"expected the header {WPL_HEADER!r}")
    if lines[0].strip() != WPL_HEADER:
        raise FileFormatError(p, 1, f"unsupported version {lines[0].strip()!r}; expected {WPL_HEADER!r}")
    rows: list[tuple[int, MissionItem]] = []
    for lineno, text in enumerate(lines[1:], start=2):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        rows.append((lineno, _wpl_item(p, lineno, text, expected_index=len(rows))))
    if not rows:
        raise FileFormatError(p, None, "no items (line 0, home, is required)")
    home_line, home_item = rows[0]
    home = _wpl_home(p, home_line, home_item)
    items = tuple(replace(it, seq=i, current=False) for i, (_, it) in enumerate(rows[1:]))
    return MissionFile(items, "waypoints", home)


def _wpl_item(p: Path, lineno: int, text: str, expected_index: int) -> MissionItem:
    # Tabs per the format; any whitespace is accepted, as QGroundControl does.
    fields = text.split()
    if len(fields) != WPL_COLUMNS:
        raise FileFormatError(p, lineno, f"expected {WPL_COLUMNS} columns, got {len(fields)}")
    names = ("index", "current", "frame", "command")
    ints: list[int] = []
    for name, tok in zip(names, fields[0:4], strict=True):
        ints.append(_int_field(p, lineno, name, tok))
    autocontinue = _int_field(p, lineno, "autocontinue", fields[11])
    floats: list[float] = []
    for k, tok in enumerate(fields[4:11]):
        try:
            floats.append(float(tok))
        except ValueError:
            raise FileFormatError(p, lineno, f"column {k + 5}: not a number: {tok!r}") from None
    index, current, frame, command = ints
    if index != expected_index:
        raise FileFormatError(p, lineno, f"index {index}, expected {expected_index} (items must be in order)")
    if current not in (0, 1) or autocontinue not in (0, 1):
        raise FileFormatError(p, lineno, "current and autocontinue must be 0 or 1")
    if not 0 <= command <= 65535 or not 0 <= frame <= 255:
        raise FileFormatError(p, lineno, f"frame {frame} / command {command} out of range")
    try:
        x, y = _xy_from_file(frame, floats[4], floats[5])
        return MissionItem(
            seq=index, frame=frame, command=command,
            param1=floats[0], param2=floats[1], param3=floats[2], param4=floats[3],
            x=x, y=y, z=floats[6], autocontinue=bool(autocontinue), current=bool(current),
        )  # fmt: skip
    except ValueError as exc:
        raise FileFormatError(p, lineno, str(exc)) from exc


def _int_field(p: Path, lineno: int, name: str, tok: str) -> int:
    try:
        v = float(tok)
    except ValueError:
        raise FileFormatError(p, lineno, f"{name}: not a number: {tok!r}") from None
    if not (math.isfinite(v) and v.is_integer()):
        raise FileFormatError(p, lineno, f"{name}: expected an integer, got {tok!r}")
    return int(v)


def _wpl_home(p: Path, lineno: int, item: MissionItem) -> GeoPoint | None:
    """Line 0 -> home, when it says where home is: a position in a global AMSL frame.

    None (home unknown) for 0/0 lat/lon, which some tools write for "no home", and for a
    relative-altitude frame, whose altitude AMSL is not in the file.
    """
    if item.frame not in ms.AMSL_FRAMES or (item.x == 0 and item.y == 0):
        return None
    if not math.isfinite(item.z):
        raise FileFormatError(p, lineno, "line 0 (home): altitude is not finite")
    return GeoPoint(item.lat_deg, item.lon_deg, item.z)


def write_waypoints(path: Path | str, items: Sequence[MissionItem], home: GeoPoint) -> None:
    """Write QGC WPL 110: home on line 0, then the items (their seq + 1)."""
    out = [WPL_HEADER]
    home_item = MissionItem(
        0, ms.FRAME_GLOBAL, ms.CMD_WAYPOINT, x=round(home.lat_deg * ms.DEG_E7),
        y=round(home.lon_deg * ms.DEG_E7), z=home.alt_amsl_m, current=True,
    )  # fmt: skip
    for i, it in enumerate([home_item, *items]):
        x, y = _xy_to_file(it)
        is_global = it.frame in ms.GLOBAL_FRAMES
        cols = [
            str(i), str(int(it.current if i == 0 else 0)), str(it.frame), str(it.command),
            *(f32_text(v) for v in (it.param1, it.param2, it.param3, it.param4)),
            _fmt_deg(x) if is_global else _fmt64(x), _fmt_deg(y) if is_global else _fmt64(y),
            f32_text(it.z), str(int(it.autocontinue)),
        ]  # fmt: skip
        out.append("\t".join(cols))
    Path(path).write_text("\n".join(out) + "\n", encoding="utf-8")


# ----------------------------------------------------------------------------- QGC .plan


def read_plan(path: Path | str) -> MissionFile:
    """A QGroundControl .plan (JSON) -> its simple mission items and planned home."""
    p = Path(path)
    try:
        doc = json.loads(_read_text(p))
    except json.JSONDecodeError as exc:
        raise FileFormatError(p, exc.lineno, f"not valid JSON: {exc.msg} (column {exc.colno})") from exc
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        raise FileFormatError(p, None, 'not a QGroundControl plan: "fileType" must be "Plan"')
    mission = doc.get("mission")
    if not isinstance(mission, dict):
        raise FileFormatError(p, None, 'missing "mission" object')
    if mission.get("version", 2) != 2:
        raise FileFormatError(p, None, f"mission.version {mission.get('version')!r}: only version 2 is read")
    raw_items = mission.get("items")
    if not isinstance(raw_items, list):
        raise FileFormatError(p, None, "mission.items: expected a list")
    items = [_plan_item(p, i, raw) for i, raw in enumerate(raw_items)]
    home = _plan_home(p, mission.get("plannedHomePosition"))
    return MissionFile(tuple(items), "plan", home)


def _plan_item(p: Path, i: int, raw: Any) -> MissionItem:
    where = f"mission.items[{i}]"
    if not isinstance(raw, dict):
        raise FileFormatError(p, None, f"{where}: expected an object")
    kind = raw.get("type")
    if kind == "ComplexItem":
        pattern = raw.get("complexItemType", "?")
        raise FileFormatError(p, None, f"{where}: complex item {pattern!r} is not supported "
                                       "(QGroundControl expands it only when it uploads)")  # fmt: skip
    if kind != "SimpleItem":
        raise FileFormatError(p, None, f"{where}.type: expected \"SimpleItem\", got {kind!r}")
    command, frame = raw.get("command"), raw.get("frame")
    for name, v, hi in (("command", command, 65535), ("frame", frame, 255)):
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= hi:
            raise FileFormatError(p, None, f"{where}.{name}: expected an integer in [0, {hi}], got {v!r}")
    params = raw.get("params")
    if not isinstance(params, list) or len(params) != 7:
        raise FileFormatError(p, None, f"{where}.params: expected 7 values")
    vals: list[float] = []
    for k, v in enumerate(params):
        if v is None:
            vals.append(math.nan)  # QGroundControl writes NaN ("not set") as null
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            vals.append(float(v))
        else:
            raise FileFormatError(p, None, f"{where}.params[{k}]: expected a number or null, got {v!r}")
    auto = raw.get("autoContinue", True)
    if not isinstance(auto, bool):
        raise FileFormatError(p, None, f"{where}.autoContinue: expected true or false")
    assert isinstance(command, int) and isinstance(frame, int)
    try:
        x, y = _xy_from_file(frame, vals[4], vals[5])
        return MissionItem(i, frame, command, vals[0], vals[1], vals[2], vals[3], x, y, vals[6],
                           autocontinue=auto)  # fmt: skip
    except ValueError as exc:
        raise FileFormatError(p, None, f"{where}.params: {exc}") from exc


def _plan_home(p: Path, raw: Any) -> GeoPoint | None:
    if raw is None:
        return None
    if not (isinstance(raw, list) and len(raw) == 3 and all(isinstance(v, (int, float)) for v in raw)):
        raise FileFormatError(p, None, "mission.plannedHomePosition: expected [lat, lon, alt]")
    try:
        return GeoPoint(float(raw[0]), float(raw[1]), float(raw[2]))
    except ValueError as exc:
        raise FileFormatError(p, None, f"mission.plannedHomePosition: {exc}") from exc


def write_plan(path: Path | str, items: Sequence[MissionItem], home: GeoPoint) -> None:
    """Write a QGroundControl plan (mission version 2, no fence, no rally points)."""
    out_items = []
    for i, it in enumerate(items):
        x, y = _xy_to_file(it)
        values = (it.param1, it.param2, it.param3, it.param4, x, y, it.z)
        params = [None if math.isnan(v) else v for v in values]
        out_items.append({
            "autoContinue": it.autocontinue, "command": it.command, "doJumpId": i + 1,
            "frame": it.frame, "params": params, "type": "SimpleItem",
        })  # fmt: skip
    doc = {
        "fileType": "Plan",
        "groundStation": "heli-ground",
        "version": 1,
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "mission": {
            "version": 2,
            "firmwareType": MAV_AUTOPILOT_GENERIC,
            "vehicleType": MAV_TYPE_HELICOPTER,
            "cruiseSpeed": PLAN_CRUISE_SPEED_M_S,
            "hoverSpeed": PLAN_CRUISE_SPEED_M_S,
            "items": out_items,
            "plannedHomePosition": [home.lat_deg, home.lon_deg, home.alt_amsl_m],
        },
    }
    Path(path).write_text(json.dumps(doc, indent=4) + "\n", encoding="utf-8")


# ----------------------------------------------------------------------------- trajectory TOML


def load_trajectory(path: Path | str) -> Trajectory:
    """A timed trajectory file (.toml or .csv) as the trajectory itself, for a ground station
    that streams it (``heli-ground fly --guided``); CSV samples become the C2 cubic splines the
    vehicle would build from them."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".toml":
        return _toml_trajectory(p)[2]
    if suffix == ".csv":
        s = read_trajectory_csv(p)
        try:
            return SampledTrajectory(s.t_s, s.pos_nwu_m, s.yaw_nwu_rad)
        except ValueError as exc:
            raise FileFormatError(p, None, f"trajectory: {exc}") from exc
    raise FileFormatError(p, None, "a streamed trajectory is a .toml or .csv file (a mission is uploaded "
                                   "with heli-ground fly, without --guided)")


def _toml_trajectory(p: Path) -> tuple[str, dict[str, Any], Trajectory]:
    """(text, document, trajectory) of a TOML file with a ``[trajectory]`` table."""
    text = _read_text(p)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise FileFormatError(p, int(m.group(1)) if m else None, f"not valid TOML: {exc}") from exc
    table = doc.get("trajectory")
    if not isinstance(table, dict):
        raise FileFormatError(p, None, "missing table [trajectory] (kind = ... and its parameters)")
    try:
        traj = trajectory_from_table(table, str(p))
    except ConfigError as exc:
        key = re.search(r"trajectory[.:]\s*(\w+)", str(exc))
        line = _toml_line(text, "trajectory", key.group(1) if key else "kind")
        raise FileFormatError(p, line, str(exc).removeprefix(f"{p}: ")) from exc
    return text, doc, traj


def read_trajectory_toml(path: Path | str, dt_s: float | None = None) -> MissionFile:
    """``[trajectory]`` (+ optional ``[encoding]``) -> the timed-trajectory items."""
    p = Path(path)
    text, doc, traj = _toml_trajectory(p)
    enc = doc.get("encoding", {})
    if not isinstance(enc, dict):
        raise FileFormatError(p, _toml_line(text, "encoding", None), "[encoding] must be a table")
    unknown = set(enc) - {"dt_s", "breaks_s"}
    if unknown:
        key = sorted(unknown)[0]
        raise FileFormatError(p, _toml_line(text, "encoding", key),
                              f"encoding.{key}: unknown key; expected dt_s, breaks_s")  # fmt: skip
    step = dt_s if dt_s is not None else enc.get("dt_s", DEFAULT_DT_S)
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not (math.isfinite(step) and step > 0):
        raise FileFormatError(p, _toml_line(text, "encoding", "dt_s"),
                              f"encoding.dt_s: expected a number > 0, got {step!r}")  # fmt: skip
    breaks = enc.get("breaks_s", _default_breaks(traj))
    numbers = isinstance(breaks, list) and all(
        isinstance(b, (int, float)) and not isinstance(b, bool) and math.isfinite(b) for b in breaks
    )
    if not numbers:
        raise FileFormatError(p, _toml_line(text, "encoding", "breaks_s"),
                              "encoding.breaks_s: expected a list of times [s]")  # fmt: skip
    try:
        items = codec.encode_trajectory(traj, float(step), [float(b) for b in breaks])
    except ValueError as exc:
        raise FileFormatError(p, None, f"trajectory: {exc}") from exc
    return MissionFile(tuple(items), "trajectory", None, traj.duration_s)


def _default_breaks(traj: object) -> list[float]:
    """The corners a known trajectory has (the spline must not smooth them away)."""
    if isinstance(traj, PaperSpiralCircle) and 0.0 < traj.climb_end_s < traj.duration_s:
        return [traj.climb_end_s]
    if isinstance(traj, ArcTurn):  # the arc's ends, where the lateral acceleration steps
        return [b for b in (traj.turn_start_s, traj.turn_end_s) if 0.0 < b < traj.duration_s]
    return []


def _toml_line(text: str, table: str, key: str | None) -> int | None:
    """1-based line of ``key`` in ``[table]`` (or of the table header), for error messages."""
    current: str | None = None
    header_line: int | None = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        m = re.fullmatch(r"\[\s*([A-Za-z0-9_.\-]+)\s*\]\s*(#.*)?", s)
        if m:
            current = m.group(1)
            if current == table:
                header_line = lineno
            continue
        if current == table and key is not None and re.match(rf"{re.escape(key)}\s*=", s):
            return lineno
    return header_line


# ----------------------------------------------------------------------------- trajectory CSV

CSV_REQUIRED = ("t", "x", "y", "z")
CSV_OPTIONAL = ("yaw",)
CSV_SI = {"t_s": "t", "x_m": "x", "y_m": "y", "z_m": "z", "yaw_rad": "yaw"}  # the API's names for the same


def read_trajectory_csv(path: Path | str) -> TrajectorySamples:
    """``t,x,y,z[,yaw]`` rows (NWU metres, seconds, radians) -> samples; '#' lines are comments.
    The API's ``t_s,x_m,y_m,z_m[,yaw_rad]`` names the same columns, and a run.csv flies back
    (its t,x,y,z); velocity columns are refused: the vehicle splines the positions."""
    p = Path(path)
    rows = _csv_rows(p, _read_text(p).splitlines())
    if not rows:
        raise FileFormatError(p, None, "empty file: expected a header t,x,y,z[,yaw]")
    head_line, header = rows[0]
    si, keep = table_columns(header)  # the one reading of a trajectory header (and a run.csv)
    names = [CSV_SI.get(n, n) for n in si]
    if keep is not None:
        rows = [(n, [cells[j] for j in keep] if len(cells) == len(header) else cells) for n, cells in rows]
    if names[:4] != list(CSV_REQUIRED) or not set(names[4:]) <= set(CSV_OPTIONAL) or len(names) > 5:
        got = ",".join(header)
        raise FileFormatError(p, head_line, f"header {got!r}: expected t,x,y,z or t,x,y,z,yaw (or t_s,x_m,"
                              "y_m,z_m[,yaw_rad], or a run.csv): the vehicle splines positions")  # fmt: skip
    data: list[list[float]] = []
    lines: list[int] = []
    for lineno, row in rows[1:]:
        if len(row) != len(names):
            raise FileFormatError(p, lineno, f"expected {len(names)} values, got {len(row)}")
        vals: list[float] = []
        for name, tok in zip(names, row, strict=True):
            try:
                v = float(tok)
            except ValueError:
                raise FileFormatError(p, lineno, f"{name}: not a number: {tok.strip()!r}") from None
            if not math.isfinite(v):
                raise FileFormatError(p, lineno, f"{name}: not finite: {tok.strip()!r}")
            vals.append(v)
        if data and vals[0] <= data[-1][0]:
            raise FileFormatError(p, lineno, f"t = {vals[0]} s does not increase (previous {data[-1][0]} s)")
        if not data and vals[0] < 0.0:
            raise FileFormatError(p, lineno, f"t = {vals[0]} s: times start at >= 0 (the mission start)")
        data.append(vals)
        lines.append(lineno)
    if len(data) < 2:
        raise FileFormatError(p, None, f"need at least 2 samples, got {len(data)}")
    arr = np.array(data, dtype=float)
    yaw = arr[:, 4].copy() if len(names) == 5 else None
    return TrajectorySamples(arr[:, 0].copy(), arr[:, 1:4].copy(), yaw)


def _csv_rows(p: Path, lines: Iterable[str]) -> list[tuple[int, list[str]]]:
    out: list[tuple[int, list[str]]] = []
    for lineno, text in enumerate(lines, start=1):
        if not text.strip() or text.lstrip().startswith("#"):
            continue
        try:
            row = next(csv.reader([text]))
        except csv.Error as exc:
            raise FileFormatError(p, lineno, f"bad CSV: {exc}") from exc
        out.append((lineno, row))
    return out


def write_trajectory_csv(path: Path | str, samples: TrajectorySamples) -> None:
    """The inverse of :func:`read_trajectory_csv` (repr floats: lossless)."""
    header = ["t", "x", "y", "z"] + (["yaw"] if samples.yaw_nwu_rad is not None else [])
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for i in range(samples.t_s.size):
            row = [samples.t_s[i], *samples.pos_nwu_m[i]]
            if samples.yaw_nwu_rad is not None:
                row.append(samples.yaw_nwu_rad[i])
            w.writerow([repr(float(v)) for v in row])
