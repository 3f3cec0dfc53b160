"""A flight as an MCAP file with Foxglove's well-known schemas (Foxglove, Lichtblick,
PlotJuggler and the ROS 2 tools open it), written after the flight from run.csv's columns.

Why here and why so: the writer only needs run.csv's columns (:data:`autopilot.metrics.CSV_HEADER`,
then the rotor plant's :data:`~autopilot.metrics.ROTOR_CSV`) and the bench's home
(:mod:`heli_common.geo`), so it sits in the autopilot layer beside the other post-flight
writer (:mod:`autopilot.flight_log`, the .tlog): the in-process flight (heli_sitl), the
autopilot process and the ground tools' .tlog conversion (ground) all reach it.

Encoding: Foxglove's schemas in their ROS 2 form (``ros2msg`` schemas, ``cdr`` messages,
:mod:`autopilot.foxglove_msgs`), written in bulk (:mod:`autopilot.mcap_bulk`). Every message
of a channel has the same size and layout (its frame ids and sequence lengths do not change
from tick to tick), so each channel's payload is encoded once as a template
(:func:`autopilot.ros2msg.encode`) and a whole flight's numbers are written into all its
messages at once with numpy: a 120 s flight (12001 ticks, 60006 messages, 12.4 MB) costs
22-51 ms on the 2 shared cores here (0.56-0.59 of the compiled flight's own time;
``benchmarks/bench_mcap.py``), where JSON messages through the ``mcap`` library's ``Writer``
cost 0.7-1.8 s (string formatting and ~10 us of Python per message). CDR rather than protobuf: Foxglove's
protobuf schemas stamp with ``google.protobuf.Timestamp``, whose varint seconds and nanoseconds
change length from tick to tick, so no fixed layout; CDR's are fixed-width integers, and
its schema is plain text (no descriptor to build, no protobuf package to write it). Foxglove
and Lichtblick decode ``ros2msg``/``cdr`` without ROS; PlotJuggler reads it with its ROS 2
parser (its MCAP loader); ``mcap cat`` shows the records, ``mcap-ros2-support`` decodes them.

Channels (every message stamped with simulation time: log_time = publish_time = t_s in ns;
a flight's first ticks may have t_s < 0 in a process run's warm-up: those are shifted so the
earliest stamp is 0, see :func:`stamps_ns`):

* ``/tf`` foxglove_msgs/msg/FrameTransforms: ``world`` -> ``body`` (the vehicle), ``body`` ->
  ``rotor`` (the main rotor hub, unrotated) and ``rotor`` -> ``disc`` (the tip-path plane
  tilted forward by a1 and right by b1 where run.csv has the rotor plant's flapping:
  R = Ry(a1) Rx(b1) in FLU; without flapping ``disc`` coincides with ``rotor``).
* ``/pose`` and ``/reference/pose`` foxglove_msgs/msg/PoseInFrame in ``world``: the vehicle's
  pose and the reference's (position, yaw command; level: the reference has no roll or pitch).
* ``/scene`` foxglove_msgs/msg/SceneUpdate, once at the first stamp: a fuselage box
  (``body``), the rotor disc as a thin cylinder (``disc``), the reference path as a line
  strip (``world``).
* ``/fix`` foxglove_msgs/msg/LocationFix: the position as latitude, longitude and altitude
  (WGS-84, m AMSL) about the home (:data:`heli_common.defaults.HOME` unless given), through
  :func:`heli_common.geo.nwu_to_geo`; heading from psi (clockwise from north); velocity NaN
  (not in run.csv).
* ``/run`` heli_sitl/msg/RunRow: run.csv's row, one float64 per column by run.csv's name (SI
  units in the names), then ``pos_err_m`` (the 3-D tracking error, |reference - position|,
  for the plots); NaN where the flight has no value. :func:`read_run_mcap` reads it back.

Frames: Foxglove wants right-handed frames; the bench's earth frame ``world`` is NWU (x
north, y west, z up) and the body frame FLU (x forward, y left, z up): both right-handed
with z up, so the viewers' gravity-down views show the vehicle the right way up and no
axis is flipped. Quaternions are unit, Hamilton (x, y, z, w as Foxglove orders them),
from run.csv's ZYX Euler angles: R = Rz(psi) Ry(theta) Rx(phi), body -> earth.

Which numbers: :func:`write_mcap` writes the columns it is given. A run's ``flight.mcap``
(:func:`write_mcap_as_csv`, what :meth:`autopilot.metrics.FlightRecord.write_csv` calls)
carries exactly run.csv's numbers (its 9 significant digits, :func:`csv_values`, without
reading the file back); :func:`write_mcap_from_csv` converts a run.csv on disk.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from autopilot.foxglove_msgs import MSGS
from autopilot.mcap_bulk import Channel, McapMissingError, TickStream, write_ticks
from autopilot.ros2msg import Offsets, encode, schema_text, valid_name
from heli_common.defaults import HOME
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.state import FloatArray

__all__ = ["CHANNELS", "McapMissingError", "csv_values", "quaternions_zyx", "read_run_csv", "read_run_mcap",
           "write_mcap", "write_mcap_as_csv", "write_mcap_from_csv"]  # fmt: skip

CHANNELS = ("/tf", "/pose", "/reference/pose", "/scene", "/fix", "/run")
SCHEMA_NAMES = {"/tf": "foxglove_msgs/msg/FrameTransforms", "/pose": "foxglove_msgs/msg/PoseInFrame",
                "/reference/pose": "foxglove_msgs/msg/PoseInFrame", "/scene": "foxglove_msgs/msg/SceneUpdate",
                "/fix": "foxglove_msgs/msg/LocationFix", "/run": "heli_sitl/msg/RunRow"}  # fmt: skip
WORLD, BODY, ROTOR, DISC = "world", "body", "rotor", "disc"
NEEDED = ("t_s", "x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")
# the X-Cell 60's main hub and rotor (heli_common/vehicle airframe's defaults) and a fuselage box
HUB_ABOVE_CG_M = 0.235
HUB_AHEAD_CG_M = 0.0
ROTOR_RADIUS_M = 0.775
FUSELAGE_M = (1.0, 0.2, 0.3)
CSV_DIGITS = 9  # run.csv's number format (autopilot.metrics.format_rows: %.9g)
FRAMES_NOTE = "world NWU, body FLU (right-handed, z up)"
_IDENTITY = (0.0, 0.0, 0.0, 1.0)


def _msg_type(schema_name: str) -> str:
    """``pkg/msg/Name`` (MCAP's ROS 2 schema name) -> ``pkg/Name`` (the .msg texts' key)."""
    pkg, _, name = schema_name.split("/")
    return f"{pkg}/{name}"


# -- the numbers --------------------------------------------------------------------------
def quaternions_zyx(phi: FloatArray, theta: FloatArray, psi: FloatArray) -> FloatArray:
    """(N, 4) unit quaternions (x, y, z, w) of R = Rz(psi) Ry(theta) Rx(phi), per row
    (as :func:`heli_common.frames.euler_to_quaternion`, vectorised, Foxglove's order)."""
    cr, sr = np.cos(phi / 2), np.sin(phi / 2)
    cp, sp = np.cos(theta / 2), np.sin(theta / 2)
    cy, sy = np.cos(psi / 2), np.sin(psi / 2)
    q = np.column_stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                         cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])  # fmt: skip
    out: FloatArray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def stamps_ns(t_s: FloatArray) -> np.ndarray[Any, np.dtype[np.int64]]:
    """Simulation time in integer ns (MCAP's stamps are unsigned: a negative start is shifted
    to 0, the offset kept by the ``/run`` channel's own t_s)."""
    shift = max(0.0, -float(np.min(t_s))) if t_s.size else 0.0
    return np.round((t_s + shift) * 1e9).astype(np.int64)


_POW10 = 10.0 ** np.arange(23)  # exact doubles: 10**0 .. 10**22


def csv_values(a: FloatArray, digits: int = CSV_DIGITS) -> FloatArray:
    """``a`` as run.csv holds it: each value the double nearest to its ``%.{digits}g`` text,
    computed without formatting (float('%.9g' % v) for every v, bit for bit).

    The text is N * 10**-k with N the value's ``digits`` leading digits, rounded half to
    even; fl(|v| * 10**k) is within 1.2e-7 of the exact product (N < 1e9), so rint gives N
    except within that distance of a half, where Python's formatting decides (as for
    |k| > 22, where 10**k is not exact, and where log10 missed the exponent at a power of
    ten); N / 10**k is then the nearest double, IEEE division being correctly rounded."""
    v = np.asarray(a, dtype=float)
    x = np.abs(v)
    m = np.isfinite(x) & (x > 0)
    xs = np.where(m, x, 1.0)  # zeros and non-numbers pass through as they are
    k = (digits - 1) - np.floor(np.log10(xs))
    small = (k >= 0) & (k <= 22)  # the usual case: |v| < 1e9, a power of ten that is exact
    p = _POW10[np.where(small, k, 0).astype(np.intp)]
    scaled = xs * p
    n = np.rint(scaled)
    hard = ~small | (np.abs(np.abs(scaled - n) - 0.5) < 1e-6)  # near a half: the text decides
    hard |= (n < 10.0 ** (digits - 1)) | (n > 10.0**digits)  # log10 missed the exponent
    out: FloatArray = np.where(m, np.copysign(n / p, v), v)
    idx = np.flatnonzero(hard & m)
    if idx.size:
        out.flat[idx] = [float(f"%.{digits}g" % y) for y in v.flat[idx].tolist()]
    return out


def _timestamp(prefix: str, sec_nsec: tuple[Any, Any]) -> dict[str, Any]:
    return {f"{prefix}timestamp.sec": sec_nsec[0], f"{prefix}timestamp.nanosec": sec_nsec[1]}


def _vec(prefix: str, names: str, cols: Sequence[FloatArray] | FloatArray) -> dict[str, FloatArray]:
    return {f"{prefix}.{a}": c for a, c in zip(names, cols, strict=True)}


def _scene(ns: int, ref_xyz: FloatArray, radius_m: float) -> bytes:
    sec, nsec = divmod(ns, 1_000_000_000)
    stamp = {"sec": sec, "nanosec": nsec}
    origin = {"orientation": {"w": 1.0}}

    def entity(frame: str, name: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
        return {"timestamp": stamp, "frame_id": frame, "id": name, "frame_locked": True, **prims}

    fuselage = {"pose": origin, "size": dict(zip("xyz", FUSELAGE_M, strict=True)),
                "color": {"r": 0.2, "g": 0.4, "b": 0.9, "a": 1.0}}
    disc = {"pose": origin, "size": {"x": 2 * radius_m, "y": 2 * radius_m, "z": 0.01},
            "bottom_scale": 1.0, "top_scale": 1.0, "color": {"r": 0.6, "g": 0.6, "b": 0.6, "a": 0.5}}
    finite = ref_xyz[np.isfinite(ref_xyz).all(axis=1)]
    step = max(1, finite.shape[0] // 2000)  # a path of up to 4000 points draws it
    path = {"type": 0, "pose": origin, "thickness": 2.0, "scale_invariant": True,
            "points": finite[::step],
            "color": {"r": 1.0, "g": 0.5, "b": 0.0, "a": 1.0}}
    scene = {"entities": [
        entity(BODY, "fuselage", cubes=[fuselage]),
        entity(DISC, "rotor_disc", cylinders=[disc]),
        entity(WORLD, "reference_path", lines=[path]),
    ]}  # fmt: skip
    return encode(MSGS, "foxglove_msgs/SceneUpdate", scene)[0]


@functools.cache
def _texts(names: tuple[str, ...]) -> dict[str, str]:
    return {**MSGS, "heli_sitl/RunRow": run_msg(names)}


@functools.cache
def _channels(names: tuple[str, ...], has_ref: bool) -> tuple[Channel, ...]:
    """The channels of a flight with these run.csv columns (a flight's schemas, built once)."""
    topics = [t for t in CHANNELS if t != "/reference/pose" or has_ref]
    return tuple(Channel(t, SCHEMA_NAMES[t], schema_text(_msg_type(SCHEMA_NAMES[t]), _texts(names)).encode(),
                         metadata={"frames": FRAMES_NOTE}) for t in topics)  # fmt: skip


@functools.cache
def _template(names: tuple[str, ...], topic: str, value_json: str) -> tuple[bytes, Offsets]:
    """A channel's payload template (its constant fields, ``value_json``) and its layout, built once."""
    return encode(_texts(names), _msg_type(SCHEMA_NAMES[topic]), json.loads(value_json))


def run_msg(columns: Sequence[str]) -> str:
    """The ``/run`` channel's message definition: a float64 per column, by its name."""
    bad = [c for c in columns if not valid_name(c)]
    if bad:
        raise ValueError(f"MCAP log: not a ROS 2 field name: {', '.join(bad)}")
    return "".join(f"float64 {c}\n" for c in columns)


def write_mcap(
    columns: Mapping[str, FloatArray], path: Path | str, *, home: GeoPoint = HOME,
    hub_m: tuple[float, float, float] = (HUB_AHEAD_CG_M, 0.0, HUB_ABOVE_CG_M),
    rotor_radius_m: float = ROTOR_RADIUS_M,
) -> Path:  # fmt: skip
    """Write the flight in ``columns`` (run.csv's names; at least t_s, x_m, y_m, z_m,
    phi_rad, theta_rad, psi_rad; the references, a1_rad and b1_rad where present) to the MCAP
    file ``path``; returns it. ``hub_m`` is the main hub in the body frame (FLU)."""
    missing = [c for c in NEEDED if c not in columns]
    if missing:
        raise ValueError(f"MCAP log: the columns lack {', '.join(missing)}")
    col = {c: np.asarray(v, dtype=float) for c, v in columns.items()}
    has_ref = all(c in col for c in ("x_ref_m", "y_ref_m", "z_ref_m"))
    if has_ref and "pos_err_m" not in col:
        # the tracking error, for the plots: |reference - position| (NaN where no reference)
        col["pos_err_m"] = np.sqrt(sum((col[f"{a}_ref_m"] - col[f"{a}_m"]) ** 2 for a in "xyz"))
    names = tuple(col)
    n = col["t_s"].size
    ns = stamps_ns(col["t_s"])
    stamp = np.divmod(ns, 1_000_000_000)  # builtin_interfaces/Time: sec, nanosec
    xyz = (col["x_m"], col["y_m"], col["z_m"])
    q = quaternions_zyx(col["phi_rad"], col["theta_rad"], col["psi_rad"]).T
    flap = "a1_rad" in col and "b1_rad" in col
    zeros = np.zeros(n)
    q_disc = (quaternions_zyx(np.nan_to_num(col["b1_rad"]), np.nan_to_num(col["a1_rad"]), zeros).T
              if flap else np.tile(np.array(_IDENTITY)[:, None], (1, n)))  # fmt: skip
    # latitude, longitude, altitude about home: the flat-earth map, vectorised through one call's scale
    g0 = nwu_to_geo(home, (0.0, 0.0, 0.0))
    g1 = nwu_to_geo(home, (1.0, -1.0, 0.0))  # 1 m north, 1 m east
    lat = g0.lat_deg + (g1.lat_deg - g0.lat_deg) * xyz[0]
    lon = g0.lon_deg + (g1.lon_deg - g0.lon_deg) * -xyz[1]
    alt = home.alt_amsl_m + xyz[2]
    heading = np.mod(-col["psi_rad"], 2 * math.pi)  # clockwise from north; psi is counter-clockwise (z up)

    channels = _channels(names, has_ref)
    ch = {c.topic: i for i, c in enumerate(channels)}

    def stream(topic: str, value: Mapping[str, Any], values: dict[str, Any], valid: Any = None) -> TickStream:
        template, offsets = _template(names, topic, json.dumps(value, sort_keys=True))
        ok = None if valid is None or bool(np.all(valid)) else np.asarray(valid, bool)
        return TickStream(ch[topic], template, offsets, values, ok)

    def finite(*cols: FloatArray) -> Any:
        return np.logical_and.reduce([np.isfinite(c) for c in cols])

    tf0, tf2 = "transforms[0]", "transforms[2]"
    tf = {"transforms": [{"parent_frame_id": WORLD, "child_frame_id": BODY},
                         {"parent_frame_id": BODY, "child_frame_id": ROTOR,
                          "translation": dict(zip("xyz", hub_m, strict=True)), "rotation": {"w": 1.0}},
                         {"parent_frame_id": ROTOR, "child_frame_id": DISC}]}  # fmt: skip
    streams = [
        stream("/tf", tf, {**_timestamp(f"{tf0}.", stamp), **_timestamp("transforms[1].", stamp),
                           **_timestamp(f"{tf2}.", stamp), **_vec(f"{tf0}.translation", "xyz", xyz),
                           **_vec(f"{tf0}.rotation", "xyzw", q), **_vec(f"{tf2}.rotation", "xyzw", q_disc)},
               finite(*xyz, *q, *q_disc)),
        stream("/pose", {"frame_id": WORLD}, {**_timestamp("", stamp), **_vec("pose.position", "xyz", xyz),
                                              **_vec("pose.orientation", "xyzw", q)}, finite(*xyz, *q)),
    ]  # fmt: skip
    if has_ref:
        ref = (col["x_ref_m"], col["y_ref_m"], col["z_ref_m"])
        half = np.nan_to_num(col.get("psi_ref_rad", zeros)) / 2  # level: a turn about z only
        q_ref = (zeros, zeros, np.sin(half), np.cos(half))
        streams.append(stream("/reference/pose", {"frame_id": WORLD}, {
            **_timestamp("", stamp), **_vec("pose.position", "xyz", ref),
            **_vec("pose.orientation", "xyzw", q_ref)}, finite(*ref)))  # fmt: skip
    nan3 = {"x": math.nan, "y": math.nan, "z": math.nan}
    streams.append(stream("/fix", {"frame_id": BODY, "velocity": nan3,
                                   "color": {"r": 0.12, "g": 0.47, "b": 0.71, "a": 1.0}},
                          {**_timestamp("", stamp), "latitude": lat, "longitude": lon, "altitude": alt,
                           "heading": heading}, finite(lat, lon, alt)))  # fmt: skip
    streams.append(stream("/run", {}, col))
    ref_xyz = np.column_stack(ref if has_ref else xyz)
    once = [(ch["/scene"], _scene(int(ns[0]), ref_xyz, rotor_radius_m))] if n else []
    meta = {"home": f"{home.lat_deg},{home.lon_deg},{home.alt_amsl_m}", "frames": "world NWU, body FLU",
            "columns": ",".join(names)}  # fmt: skip
    return write_ticks(path, channels, ns, streams, once=once, metadata=("heli-tlc-sitl", meta),
                       library="heli-tlc-sitl (numpy CDR, mcap records)")  # fmt: skip


def write_mcap_as_csv(header: Sequence[str], rows: FloatArray, path: Path | str, **kw: Any) -> Path:
    """The MCAP of ``rows`` (run.csv's rows, columns named by ``header``) with the numbers
    run.csv holds (:func:`csv_values`): what every run writes beside its run.csv."""
    vals = csv_values(np.asarray(rows, dtype=float))
    return write_mcap({c: vals[:, i] for i, c in enumerate(header)}, path, **kw)


def read_run_csv(path: Path | str) -> dict[str, FloatArray]:
    """run.csv's columns by name (the file as written, so the MCAP carries what it carries)."""
    p = Path(path)
    with p.open() as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        data = np.empty((0, len(header)))
    return {c: data[:, i] for i, c in enumerate(header)}


def read_run_mcap(path: Path | str) -> dict[str, FloatArray]:
    """The ``/run`` channel of an MCAP of ours as run.csv's columns by name (float arrays;
    ``pos_err_m`` too), in file order. Reads the CDR rows of this writer and the JSON rows
    of the bench's earlier writer (null read as NaN)."""
    from mcap.reader import make_reader

    names: list[str] | None = None
    payloads: list[bytes] = []
    encoding = ""
    with Path(path).open("rb") as fh:
        for schema, channel, msg in make_reader(fh).iter_messages(topics=["/run"], log_time_order=False):
            if names is None:
                encoding = channel.message_encoding
                if encoding == "cdr":
                    assert schema is not None
                    names = [line.split()[1] for line in schema.data.decode().splitlines()
                             if line.strip() and not line.startswith("#")]  # fmt: skip
                elif encoding == "json":
                    names = []
                else:
                    raise ValueError(f"{path}: /run is {encoding!r}, not cdr or json")
            payloads.append(msg.data)
    if names is None:
        raise ValueError(f"{path}: no /run channel")
    if encoding == "json":
        rows = [json.loads(p) for p in payloads]
        keys = list(rows[0]) if rows else []
        return {k: np.array([math.nan if r.get(k) is None else r[k] for r in rows], dtype=float)
                for k in keys}  # fmt: skip
    dtype = np.dtype([("_encapsulation", "V4"), *((c, "<f8") for c in names)])
    data = np.frombuffer(b"".join(payloads), dtype=dtype)
    return {c: np.array(data[c]) for c in names}


def write_mcap_from_csv(run_csv: Path | str, path: Path | str | None = None, **kw: Any) -> Path:
    """``flight.mcap`` (or ``path``) beside a finished run.csv, from its columns."""
    src = Path(run_csv)
    return write_mcap(read_run_csv(src), src.with_name("flight.mcap") if path is None else path, **kw)
