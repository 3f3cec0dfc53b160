"""A flight as an MCAP file with Foxglove's well-known schemas (Foxglove, Lichtblick,
PlotJuggler and the ROS 2 tools open it), written after the flight from run.csv's columns.

Why here and why so: the writer only needs run.csv's columns (:data:`autopilot.metrics.CSV_HEADER`,
then the rotor plant's :data:`~autopilot.metrics.ROTOR_CSV`) and the bench's home
(:mod:`heli_common.geo`), so it sits in the autopilot layer beside the other post-flight
writer (:mod:`autopilot.flight_log`, the .tlog): the in-process flight (heli_sitl), the
autopilot process and the ground tools' .tlog conversion (ground) all reach it without
breaking the layers. It uses the small pure-Python ``mcap`` library (the format's reference
implementation) with Foxglove's schemas in their JSON-schema form (``jsonschema`` schema
encoding, ``json`` message encoding), not the ``foxglove-sdk``: the SDK is a compiled
extension built around a live WebSocket server and a process-wide logging context, while a
post-flight file needs none of that; the JSON form is what Foxglove documents for its
schemas and every viewer reads it, and the messages stay readable (``mcap cat --json``).
The ``mcap`` package is imported only when a file is written (never in the control loop).

Channels (every message stamped with simulation time: log_time = publish_time = t_s in ns;
a flight's first ticks may have t_s < 0 in a process run's warm-up: those are shifted so the
earliest stamp is 0, see :func:`stamps_ns`):

* ``/tf`` foxglove.FrameTransforms: ``world`` -> ``body`` (the vehicle), ``body`` -> ``rotor``
  (the main rotor hub, unrotated) and, where run.csv has the rotor plant's flapping a1, b1,
  ``rotor`` -> ``disc`` (the tip-path plane tilted forward by a1 and right by b1:
  R = Ry(a1) Rx(b1) in FLU); without flapping ``disc`` coincides with ``rotor``.
* ``/pose`` and ``/reference/pose`` foxglove.PoseInFrame in ``world``: the vehicle's pose and
  the reference's (position, yaw command; level: the reference has no roll or pitch).
* ``/scene`` foxglove.SceneUpdate, written once at the first stamp: a fuselage box
  (``body``), the rotor disc as a thin cylinder (``disc``), the reference path as a line
  strip (``world``).
* ``/fix`` foxglove.LocationFix: the position as latitude, longitude and altitude (WGS-84,
  m AMSL) about the home (:data:`heli_common.defaults.HOME` unless given), through
  :func:`heli_common.geo.nwu_to_geo`.
* ``/run`` the run.csv row, a JSON object with every column by run.csv's name (SI units in
  the names), then ``pos_err_m`` (the 3-D tracking error, |reference - position|, for the
  plots; run.csv has the two, not their difference); NaN (a value the flight does not have)
  is written as null.

Frames: Foxglove wants right-handed frames; the bench's earth frame ``world`` is NWU (x
north, y west, z up) and the body frame FLU (x forward, y left, z up): both right-handed
with z up, so the viewers' gravity-down views show the vehicle the right way up and no
axis is flipped. Quaternions are unit, Hamilton (x, y, z, w as Foxglove orders them),
from run.csv's ZYX Euler angles: R = Rz(psi) Ry(theta) Rx(phi), body -> earth.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from heli_common.defaults import HOME
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.state import FloatArray

__all__ = ["CHANNELS", "McapMissingError", "quaternions_zyx", "read_run_csv", "write_mcap",
           "write_mcap_from_csv"]

CHANNELS = ("/tf", "/pose", "/reference/pose", "/scene", "/fix", "/run")
WORLD, BODY, ROTOR, DISC = "world", "body", "rotor", "disc"
NEEDED = ("t_s", "x_m", "y_m", "z_m", "phi_rad", "theta_rad", "psi_rad")
# the X-Cell 60's main hub and rotor (heli_common/vehicle airframe's defaults) and a fuselage box
HUB_ABOVE_CG_M = 0.235
HUB_AHEAD_CG_M = 0.0
ROTOR_RADIUS_M = 0.775
FUSELAGE_M = (1.0, 0.2, 0.3)


class McapMissingError(RuntimeError):
    """The ``mcap`` package is not installed."""


def _mcap_writer() -> Any:
    try:
        from mcap.writer import Writer
    except ImportError as exc:  # a plain dependency (pyproject.toml); say so if it was left out
        raise McapMissingError("writing an MCAP log needs the 'mcap' package: pip install mcap") from exc
    return Writer


# -- Foxglove's schemas, JSON-schema form -----------------------------------------------
def _obj(props: dict[str, Any]) -> dict[str, Any]:
    return {"type": "object", "properties": props}


_NUM: dict[str, Any] = {"type": "number"}
_TIME = _obj({"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}})
_VEC3 = _obj({"x": _NUM, "y": _NUM, "z": _NUM})
_QUAT = _obj({"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_POSE = _obj({"position": _VEC3, "orientation": _QUAT})
_COLOR = _obj({"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_STR: dict[str, Any] = {"type": "string"}
_FRAME_TRANSFORM = _obj({"timestamp": _TIME, "parent_frame_id": _STR, "child_frame_id": _STR,
                         "translation": _VEC3, "rotation": _QUAT})  # fmt: skip
_ARR: dict[str, Any] = {"type": "array"}
_ENTITY = _obj({
    "timestamp": _TIME, "frame_id": _STR, "id": _STR, "lifetime": _TIME, "frame_locked": {"type": "boolean"},
    "metadata": _ARR, "arrows": _ARR, "texts": _ARR, "triangles": _ARR, "models": _ARR, "spheres": _ARR,
    "cubes": {"type": "array", "items": _obj({"pose": _POSE, "size": _VEC3, "color": _COLOR})},
    "cylinders": {"type": "array", "items": _obj({"pose": _POSE, "size": _VEC3, "bottom_scale": _NUM,
                                                  "top_scale": _NUM, "color": _COLOR})},
    "lines": {"type": "array", "items": _obj({
        "type": {"type": "integer", "description": "0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},
        "pose": _POSE, "thickness": _NUM, "scale_invariant": {"type": "boolean"},
        "points": {"type": "array", "items": _VEC3}, "color": _COLOR, "colors": _ARR,
        "indices": _ARR})},
})  # fmt: skip
SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.FrameTransforms": _obj({"transforms": {"type": "array", "items": _FRAME_TRANSFORM}}),
    "foxglove.PoseInFrame": _obj({"timestamp": _TIME, "frame_id": _STR, "pose": _POSE}),
    "foxglove.SceneUpdate": _obj({"deletions": _ARR, "entities": {"type": "array", "items": _ENTITY}}),
    "foxglove.LocationFix": _obj({
        "timestamp": _TIME, "frame_id": _STR, "latitude": _NUM, "longitude": _NUM, "altitude": _NUM,
        "position_covariance": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9},
        "position_covariance_type": {"type": "integer", "description": "0 UNKNOWN"},
    }),
}  # fmt: skip


def run_schema(columns: tuple[str, ...]) -> dict[str, Any]:
    """The ``/run`` channel's schema: every column a number (null where the flight has none)."""
    return {"title": "heli_sitl.RunRow", "description": "run.csv's row (NWU/FLU, SI units in the names)",
            "type": "object", "properties": {c: {"type": ["number", "null"]} for c in columns}}  # fmt: skip


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


def _time(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _f(v: float) -> float | None:
    return v if math.isfinite(v) else None


def _pose(p: tuple[float, float, float], q: tuple[float, float, float, float]) -> dict[str, Any]:
    return {"position": {"x": p[0], "y": p[1], "z": p[2]},
            "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}}  # fmt: skip


_IDENTITY = (0.0, 0.0, 0.0, 1.0)


def _scene(ns: int, ref_xyz: FloatArray, radius_m: float) -> dict[str, Any]:
    stamp, forever = _time(ns), _time(0)
    empty: dict[str, list[Any]] = {k: [] for k in ("metadata", "arrows", "texts", "triangles", "models",
                                                   "spheres", "cubes", "cylinders", "lines")}  # fmt: skip

    def entity(frame: str, name: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
        return {"timestamp": stamp, "frame_id": frame, "id": name, "lifetime": forever,
                "frame_locked": True, **empty, **prims}  # fmt: skip

    origin = _pose((0.0, 0.0, 0.0), _IDENTITY)
    fuselage = {"pose": origin, "size": dict(zip("xyz", FUSELAGE_M, strict=True)),
                "color": {"r": 0.2, "g": 0.4, "b": 0.9, "a": 1.0}}
    disc = {"pose": origin, "size": {"x": 2 * radius_m, "y": 2 * radius_m, "z": 0.01},
            "bottom_scale": 1.0, "top_scale": 1.0, "color": {"r": 0.6, "g": 0.6, "b": 0.6, "a": 0.5}}
    finite = ref_xyz[np.isfinite(ref_xyz).all(axis=1)]
    step = max(1, finite.shape[0] // 5000)  # a few thousand points draw a path
    path = {"type": 0, "pose": _pose((0.0, 0.0, 0.0), _IDENTITY), "thickness": 2.0, "scale_invariant": True,
            "points": [{"x": x, "y": y, "z": z} for x, y, z in finite[::step].tolist()],
            "color": {"r": 1.0, "g": 0.5, "b": 0.0, "a": 1.0}, "colors": [], "indices": []}
    return {"deletions": [], "entities": [
        entity(BODY, "fuselage", cubes=[fuselage]),
        entity(DISC, "rotor_disc", cylinders=[disc]),
        entity(WORLD, "reference_path", lines=[path]),
    ]}  # fmt: skip


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
    cols = {c: np.asarray(v, dtype=float) for c, v in columns.items()}
    if all(c in cols for c in ("x_ref_m", "y_ref_m", "z_ref_m")) and "pos_err_m" not in cols:
        # the tracking error, for the plots: |reference - position| (NaN where no reference)
        cols["pos_err_m"] = np.sqrt(sum((cols[f"{a}_ref_m"] - cols[f"{a}_m"]) ** 2 for a in "xyz"))
    names = tuple(cols)
    data = np.column_stack([cols[c] for c in names])
    col = {c: data[:, i] for i, c in enumerate(names)}
    n = data.shape[0]
    ns = stamps_ns(col["t_s"]).tolist()
    xyz = np.column_stack([col["x_m"], col["y_m"], col["z_m"]])
    q = quaternions_zyx(col["phi_rad"], col["theta_rad"], col["psi_rad"])
    has_ref = all(c in col for c in ("x_ref_m", "y_ref_m", "z_ref_m"))
    ref = np.column_stack([col[c] for c in ("x_ref_m", "y_ref_m", "z_ref_m")]) if has_ref else None
    psi_ref = col.get("psi_ref_rad", np.full(n, np.nan))
    q_ref = quaternions_zyx(np.zeros(n), np.zeros(n), np.nan_to_num(psi_ref))
    flap = "a1_rad" in col and "b1_rad" in col
    q_disc = (quaternions_zyx(np.nan_to_num(col["b1_rad"]), np.nan_to_num(col["a1_rad"]), np.zeros(n))
              if flap else np.tile(_IDENTITY, (n, 1)))  # fmt: skip
    # latitude, longitude, altitude about home: the flat-earth map, vectorised through one call's scale
    g0 = nwu_to_geo(home, (0.0, 0.0, 0.0))
    g1 = nwu_to_geo(home, (1.0, -1.0, 0.0))  # 1 m north, 1 m east
    lat = g0.lat_deg + (g1.lat_deg - g0.lat_deg) * xyz[:, 0]
    lon = g0.lon_deg + (g1.lon_deg - g0.lon_deg) * -xyz[:, 1]
    alt = home.alt_amsl_m + xyz[:, 2]

    Writer = _mcap_writer()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    dumps = json.JSONEncoder(separators=(",", ":")).encode
    with out.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="heli-tlc-sitl (mcap-python)")
        ids: dict[str, int] = {}
        for topic, schema_name, schema in (
            ("/tf", "foxglove.FrameTransforms", SCHEMAS["foxglove.FrameTransforms"]),
            ("/pose", "foxglove.PoseInFrame", SCHEMAS["foxglove.PoseInFrame"]),
            ("/reference/pose", "foxglove.PoseInFrame", SCHEMAS["foxglove.PoseInFrame"]),
            ("/scene", "foxglove.SceneUpdate", SCHEMAS["foxglove.SceneUpdate"]),
            ("/fix", "foxglove.LocationFix", SCHEMAS["foxglove.LocationFix"]),
            ("/run", "heli_sitl.RunRow", run_schema(names)),
        ):
            sid = w.register_schema(name=schema_name, encoding="jsonschema", data=dumps(schema).encode())
            ids[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid,
                                            metadata={"frames": "world NWU, body FLU (right-handed, z up)"})
        w.add_metadata("heli-tlc-sitl", {"home": f"{home.lat_deg},{home.lon_deg},{home.alt_amsl_m}",
                                         "frames": "world NWU, body FLU", "columns": ",".join(names)})
        if n:
            scene = _scene(ns[0], ref if ref is not None else xyz, rotor_radius_m)
            w.add_message(ids["/scene"], log_time=ns[0], publish_time=ns[0], data=dumps(scene).encode())
        # per tick: string templates (JSON by construction) keep 12001 ticks to a fraction of a second
        cov = ",".join(["0"] * 9)
        tf_t = ('{"transforms":[{"timestamp":%s,"parent_frame_id":"world","child_frame_id":"body",'
                '"translation":{"x":%r,"y":%r,"z":%r},"rotation":{"x":%r,"y":%r,"z":%r,"w":%r}},'
                '{"timestamp":%s,"parent_frame_id":"body","child_frame_id":"rotor",'
                f'"translation":{{"x":{hub_m[0]!r},"y":{hub_m[1]!r},"z":{hub_m[2]!r}}},'
                '"rotation":{"x":0.0,"y":0.0,"z":0.0,"w":1.0}},'
                '{"timestamp":%s,"parent_frame_id":"rotor","child_frame_id":"disc",'
                '"translation":{"x":0.0,"y":0.0,"z":0.0},"rotation":{"x":%r,"y":%r,"z":%r,"w":%r}}]}')
        pose_t = ('{"timestamp":%s,"frame_id":"world","pose":{"position":{"x":%r,"y":%r,"z":%r},'
                  '"orientation":{"x":%r,"y":%r,"z":%r,"w":%r}}}')
        fix_t = ('{"timestamp":%s,"frame_id":"body","latitude":%r,"longitude":%r,"altitude":%r,'
                 f'"position_covariance":[{cov}],"position_covariance_type":0}}')
        run_t = "{" + ",".join(f'"{c}":%r' for c in names) + "}"
        finite_row = np.isfinite(data).all(axis=1).tolist()
        nan = math.nan
        ref_rows = ref.tolist() if ref is not None else [[nan, nan, nan]] * n
        for k, p, qi, qr, qd, pr, la, lo, al, row, fin in zip(
            ns, xyz.tolist(), q.tolist(), q_ref.tolist(), q_disc.tolist(), ref_rows, lat.tolist(),
            lon.tolist(), alt.tolist(), data.tolist(), finite_row, strict=True,
        ):  # fmt: skip
            sec, nsec = divmod(k, 1_000_000_000)
            ts = f'{{"sec":{sec},"nsec":{nsec}}}'
            if math.isfinite(sum(p) + sum(qi) + sum(qd)):  # a lost flight's last ticks may not be
                w.add_message(ids["/tf"], log_time=k, publish_time=k,
                              data=(tf_t % (ts, *p, *qi, ts, ts, *qd)).encode())
                w.add_message(ids["/pose"], log_time=k, publish_time=k,
                              data=(pose_t % (ts, *p, *qi)).encode())
            if all(math.isfinite(v) for v in pr):
                w.add_message(ids["/reference/pose"], log_time=k, publish_time=k,
                              data=(pose_t % (ts, *pr, *qr)).encode())
            if math.isfinite(la) and math.isfinite(lo) and math.isfinite(al):
                w.add_message(ids["/fix"], log_time=k, publish_time=k,
                              data=(fix_t % (ts, la, lo, al)).encode())
            w.add_message(ids["/run"], log_time=k, publish_time=k,
                          data=(run_t % tuple(row) if fin else run_t.replace("%r", "%s") % tuple(
                              map(_json_num, row))).encode())
        w.finish()
    return out


def _json_num(v: float) -> str:
    return repr(v) if math.isfinite(v) else "null"


def read_run_csv(path: Path | str) -> dict[str, FloatArray]:
    """run.csv's columns by name (the file as written, so the MCAP carries what it carries)."""
    p = Path(path)
    with p.open() as fh:
        header = fh.readline().strip().split(",")
    data = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        data = np.empty((0, len(header)))
    return {c: data[:, i] for i, c in enumerate(header)}


def write_mcap_from_csv(run_csv: Path | str, path: Path | str | None = None, **kw: Any) -> Path:
    """``flight.mcap`` (or ``path``) beside a finished run.csv, from its columns."""
    src = Path(run_csv)
    return write_mcap(read_run_csv(src), src.with_name("flight.mcap") if path is None else path, **kw)
