"""Telemetry logs: record everything received to a pymavlink ``.tlog``, read it back, and turn
the vehicle's telemetry into the columns of ``run.csv`` (the in-process simulator's CSV).

A ``.tlog`` record is a big-endian uint64 unix time [us] followed by one MAVLink packet as
received (heli_common.wire.mavlink.udp.TlogWriter; ``mavlogdump.py`` reads it).

Columns (:data:`autopilot.metrics.CSV_HEADER`, the paper's NWU/FLU frames, SI units), one
row per LOCAL_POSITION_NED of the vehicle:

* ``t_s``: flight time [s], as in ``run.csv``: the vehicle's clock (LOCAL_POSITION_NED
  .time_boot_ms, the time the controller saw, not the reception time, so network jitter
  does not bend the curves) minus the arming tick's. The vehicle sends a HEARTBEAT and that
  tick's LOCAL_POSITION_NED in the tick it arms, so the first LOCAL_POSITION_NED after the
  first armed HEARTBEAT is t = 0. A log with no arming in it keeps the time since boot
  (:func:`tlog_time_origin` says which).
* ``x_m, y_m, z_m``: LOCAL_POSITION_NED converted NED -> NWU (heli_common.frames).
* ``phi_rad, theta_rad, psi_rad``: the ATTITUDE of the same tick (FRD -> FLU); psi unwrapped, as run.csv.
* ``x_ref_m, y_ref_m, z_ref_m``: POSITION_TARGET_LOCAL_NED (10 Hz) interpolated linearly to the
  row's time (the reference is smooth; holding it would lag by up to 100 ms, ~0.2 m at
  2 m/s); held for up to :data:`STALE_S` after the last sample; NaN when there is no
  target (disarmed: the vehicle sends none).
* ``psi_ref_rad``: POSITION_TARGET_LOCAL_NED.yaw, the controller's own yaw command (FRD ->
  FLU), unwrapped and resampled like the targets; NaN where the vehicle gives none (a
  type_mask with POSITION_TARGET_TYPEMASK_YAW_IGNORE, or no target: disarmed).
* ``phi_ref_rad, theta_ref_rad``: ATTITUDE_TARGET (10 Hz, FRD quaternion -> FLU Euler), the
  controller's roll and pitch commands, resampled like the targets; NaN without one.
* ``theta_m_rad, theta_t_rad, eps_rad, eta_rad``: SERVO_OUTPUT_RAW (10 Hz, resampled like the targets)
  mapped back through the inverse of heli_common.wire.servo_map.to_pwm_us with the airframe's
  pitch limits (or the LIM_* parameters seen in the log); the PWM quantum of 1 us is
  (hi - lo) / 1000 rad of pitch, and a saturated command reads as its limit. The control
  moves faster than 10 Hz, so these are a 10 Hz view of the pitches, not every tick's.
"""

from __future__ import annotations

import csv
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from autopilot.metrics import CSV_HEADER
from heli_common import frames
from heli_common.geo import GeoPoint
from heli_common.state import FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.wire import servo_map
from heli_common.wire.mavlink.udp import Message, TlogWriter, mavlink2

__all__ = ["STALE_S", "TlogError", "TlogStats", "TlogWriter", "read_tlog", "tlog_columns", "tlog_home",
           "tlog_time_origin", "tlog_to_mcap", "write_csv"]

Columns = dict[str, npt.NDArray[np.float64]]
STALE_S = 0.35  # a 10 Hz message older than this (3.5 periods) is not "the current" one
PITCH_PARAMS = (("LIM_TM_MIN", "LIM_TM_MAX"), ("LIM_TT_MIN", "LIM_TT_MAX"),
                ("LIM_EPS_MIN", "LIM_EPS_MAX"), ("LIM_ETA_MIN", "LIM_ETA_MAX"))  # fmt: skip
_V1_MAGIC, _V2_MAGIC = 0xFE, 0xFD
_SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED
_MAX_SKEW_US = 86_400 * 10**6  # a record stamped a day away from its neighbour is garbage


class TlogError(ValueError):
    """A file that is not a telemetry log."""


@dataclass
class TlogStats:
    records: int = 0
    bad_bytes: int = 0  # skipped while resynchronising (corrupt or truncated records)


def read_tlog(path: Path | str, stats: TlogStats | None = None) -> Iterator[tuple[float, Message]]:
    """(unix time [s], message) for every valid record, in file order.

    A corrupt stretch is skipped by resynchronising on the next plausible record (a known
    magic byte, a time stamp near the previous one, a good CRC), as mavlogdump does; a
    truncated last record (recording cut short) is ignored.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise TlogError(f"{p}: cannot read: {exc}") from exc
    st = stats if stats is not None else TlogStats()
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    i, n = 0, len(data)
    last_us: int | None = None
    while i + 8 < n:
        got = _record_at(mav, data, i, last_us)
        if got is None:
            i += 1
            st.bad_bytes += 1
            continue
        t_us, msg, size = got
        i += size
        last_us = t_us
        st.records += 1
        yield t_us / 1e6, msg
    st.bad_bytes += max(0, n - i)  # a truncated last record
    if st.records == 0 and n > 0:
        raise TlogError(f"{p}: no MAVLink records (not a .tlog?)")


def _record_at(
    mav: mavlink2.MAVLink, data: bytes, i: int, last_us: int | None
) -> tuple[int, Message, int] | None:
    """The record at offset ``i``: (time [us], message, size), or None if there is none."""
    (t_us,) = struct.unpack_from(">Q", data, i)
    if last_us is not None and abs(t_us - last_us) > _MAX_SKEW_US:
        return None
    j = i + 8
    magic = data[j]
    if magic == _V2_MAGIC and j + 3 <= len(data):
        size = 12 + data[j + 1] + (13 if data[j + 2] & _SIGNED else 0)
    elif magic == _V1_MAGIC and j + 2 <= len(data):
        size = 8 + data[j + 1]
    else:
        return None
    if j + size > len(data):
        return None
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
    try:
        msgs = mav.parse_buffer(data[j : j + size]) or []
    except Exception:  # pymavlink raises assorted errors on garbage even when robust
        return None
    if len(msgs) != 1 or msgs[0].get_type() == "BAD_DATA":
        return None
    return t_us, msgs[0], 8 + size


def _streams(path: Path | str, system_id: int, limits0: FloatArray) -> dict[str, Any]:
    """One pass over the log: the vehicle's position rows and its 10 Hz streams, as arrays.

    The pitch limits and the yaw-hold speed are taken as the log's PARAM_VALUEs say at
    each moment (the limits can change while disarmed), starting from the airframe's.
    """
    limits = limits0.copy()
    arming_seen = False
    t_arm_s: float | None = None
    rows: list[list[float]] = []  # t, x, y, z (NWU), phi, theta, psi (FLU)
    tgt: list[list[float]] = []  # t, pos, vel, acc (NWU), psi command (NaN: not given)
    srv: list[list[float]] = []  # t, theta_m, theta_t, eps, eta
    att: list[list[float]] = []  # t, phi and theta commands (FLU)
    last_att: tuple[float, float, float] | None = None
    for _, m in read_tlog(path):
        if m.get_srcSystem() != system_id:
            continue
        kind = m.get_type()
        if kind == "HEARTBEAT" and m.get_srcComponent() == 1:
            arming_seen = arming_seen or bool(m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
        elif kind == "ATTITUDE":
            # The vehicle sends ATTITUDE and LOCAL_POSITION_NED of one tick together.
            last_att = frames.euler_frd_to_flu((m.roll, m.pitch, m.yaw))
        elif kind == "LOCAL_POSITION_NED" and last_att is not None:
            rows.append([m.time_boot_ms / 1e3, *frames.ned_to_nwu((m.x, m.y, m.z)), *last_att])
            if arming_seen and t_arm_s is None:
                t_arm_s = rows[-1][0]
        elif kind == "POSITION_TARGET_LOCAL_NED":
            yaw_given = not m.type_mask & mavlink2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            psi = frames.euler_frd_to_flu((0.0, 0.0, m.yaw))[2] if yaw_given else math.nan
            tgt.append([m.time_boot_ms / 1e3, *frames.ned_to_nwu((m.x, m.y, m.z)),
                        *frames.ned_to_nwu((m.vx, m.vy, m.vz)), *frames.ned_to_nwu((m.afx, m.afy, m.afz)),
                        psi])  # fmt: skip
        elif kind == "ATTITUDE_TARGET":
            if not m.type_mask & mavlink2.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE:
                phi, theta, _ = frames.euler_frd_to_flu(frames.quaternion_to_euler(m.q))
                att.append([m.time_boot_ms / 1e3, phi, theta])
        elif kind == "SERVO_OUTPUT_RAW":
            pwm = np.array([m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw], dtype=float)
            n = (pwm - servo_map.PWM_CENTRE_US) / servo_map.PWM_HALF_RANGE_US
            # time_usec is 32 bits on the wire: place it next to the latest row's time
            t_s = _unwrap_us32(int(m.time_usec), rows[-1][0] if rows else 0.0)
            srv.append([t_s, *servo_map.from_normalized(n, limits)])
        elif kind == "PARAM_VALUE":
            name = str(m.param_id).split("\0", 1)[0]
            for k, (lo_name, hi_name) in enumerate(PITCH_PARAMS):
                if name == lo_name:
                    limits[k, 0] = float(m.param_value)
                elif name == hi_name:
                    limits[k, 1] = float(m.param_value)
    return {
        "rows": np.array(rows, dtype=float).reshape(-1, 7),
        "target": np.array(tgt, dtype=float).reshape(-1, 11),
        "servo": np.array(srv, dtype=float).reshape(-1, 5),
        "att_cmd": np.array(att, dtype=float).reshape(-1, 3),
        "t_arm_s": t_arm_s,
    }


def _resample(t_rows: FloatArray, t_s: FloatArray, values: FloatArray) -> FloatArray:
    """``values`` (sampled at ``t_s``) at ``t_rows``: linear between two samples at most
    STALE_S apart, held up to STALE_S after the last one, NaN elsewhere (no stream)."""
    out = np.full((t_rows.size, values.shape[1]), np.nan)
    if t_s.size == 0:
        return out
    k = np.searchsorted(t_s, t_rows, side="right") - 1  # the sample at or before each row
    for r, kk in enumerate(k):
        if kk < 0 or t_rows[r] - t_s[kk] > STALE_S:
            continue
        if kk + 1 < t_s.size and t_s[kk + 1] - t_s[kk] <= STALE_S and t_s[kk + 1] > t_s[kk]:
            w = (t_rows[r] - t_s[kk]) / (t_s[kk + 1] - t_s[kk])
            out[r] = (1.0 - w) * values[kk] + w * values[kk + 1]
        else:
            out[r] = values[kk]
    return out


def tlog_columns(
    path: Path | str, *, system_id: int = 1, airframe: Airframe | None = None
) -> Columns:
    """The run.csv columns (see the module docstring) from the vehicle's telemetry in a tlog."""
    af = airframe or Airframe.load()
    st = _streams(path, system_id, servo_map.limits_array(af.limits.as_tuple()))
    rows, tgt, srv, att = st["rows"], st["target"], st["servo"], st["att_cmd"]
    t0 = st["t_arm_s"] or 0.0
    for a in (rows, tgt, srv, att):
        a[:, 0] -= t0
    t = rows[:, 0]
    given = ~np.isnan(tgt[:, 10])
    tgt[given, 10] = np.unwrap(tgt[given, 10])  # a continuous yaw command resamples right
    cmd = _resample(t, tgt[:, 0], tgt[:, 1:])
    pitches = _resample(t, srv[:, 0], srv[:, 1:])
    att_cmd = _resample(t, att[:, 0], att[:, 1:])
    psi_cmd = cmd[:, 9]
    cols = {
        "t_s": t, "x_m": rows[:, 1], "y_m": rows[:, 2], "z_m": rows[:, 3],
        "phi_rad": rows[:, 4], "theta_rad": rows[:, 5],
        "psi_rad": np.unwrap(rows[:, 6]) if t.size else rows[:, 6],
        "x_ref_m": cmd[:, 0], "y_ref_m": cmd[:, 1], "z_ref_m": cmd[:, 2], "psi_ref_rad": psi_cmd,
        "theta_m_rad": pitches[:, 0], "theta_t_rad": pitches[:, 1], "eps_rad": pitches[:, 2],
        "eta_rad": pitches[:, 3], "phi_ref_rad": att_cmd[:, 0], "theta_ref_rad": att_cmd[:, 1],
    }  # fmt: skip
    return {k: np.ascontiguousarray(cols[k], dtype=float) for k in CSV_HEADER}


def tlog_time_origin(path: Path | str, *, system_id: int = 1) -> float | None:
    """The vehicle time since boot [s] at which it armed first in this log (the t = 0 of
    :func:`tlog_columns`), or None if the log holds no arming (t is then time since boot)."""
    st = _streams(path, system_id, servo_map.limits_array(Airframe.load().limits.as_tuple()))
    t_arm: float | None = st["t_arm_s"]
    return t_arm


def _unwrap_us32(t_us32: int, near_s: float) -> float:
    period = 2**32
    base = int(near_s * 1e6) - int(near_s * 1e6) % period
    candidates = [base - period + t_us32, base + t_us32, base + period + t_us32]
    return min(candidates, key=lambda c: abs(c - near_s * 1e6)) / 1e6


def write_csv(cols: Columns, path: Path | str) -> None:
    """The columns as run.csv (same header, same number format)."""
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_HEADER)
        n = len(cols["t_s"])
        for i in range(n):
            w.writerow([f"{cols[h][i]:.9g}" for h in CSV_HEADER])


def tlog_home(path: Path | str, system_id: int = 1) -> GeoPoint | None:
    """The vehicle's home from the log (the last HOME_POSITION, else GPS_GLOBAL_ORIGIN), or None."""
    home: GeoPoint | None = None
    origin: GeoPoint | None = None
    for _, m in read_tlog(path):
        kind = m.get_type()
        if kind not in ("HOME_POSITION", "GPS_GLOBAL_ORIGIN") or m.get_srcSystem() != system_id:
            continue
        try:
            g = GeoPoint(m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1e3)
        except ValueError:
            continue
        if kind == "HOME_POSITION":
            home = g
        else:
            origin = g
    return home or origin


def tlog_to_mcap(
    path: Path | str, out: Path | str, *, system_id: int = 1, airframe: Airframe | None = None
) -> tuple[Path, int]:
    """The vehicle's telemetry in a .tlog as an MCAP file (:mod:`autopilot.mcap_log`: the
    run.csv columns of :func:`tlog_columns`, positions about the log's home, the bench's
    home when the log has none); returns the file and the number of rows."""
    from autopilot.mcap_log import write_mcap
    from heli_common.defaults import HOME

    cols = tlog_columns(path, system_id=system_id, airframe=airframe)
    n = len(cols["t_s"])
    if n == 0:
        raise TlogError(f"{path}: no position telemetry (LOCAL_POSITION_NED) from system {system_id}")
    return write_mcap(cols, out, home=tlog_home(path, system_id) or HOME), n
