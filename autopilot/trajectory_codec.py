"""A time-parameterised trajectory carried by the standard MAVLink mission protocol.

Why: the ground script must be able to upload e.g. the paper's spiral so that the flight
matches the in-process reproduction, using nothing but MISSION_COUNT / MISSION_ITEM_INT
(so MAVProxy, pymavlink and any GCS library can carry it, and it is stored, downloaded
and cleared like any mission). Waypoints alone cannot say *when* to be where.

Encoding, format version 1 (all items mission_type MAV_MISSION_TYPE_MISSION):

* seq 0, the header: command MAV_CMD_USER_1 (31010), frame MAV_FRAME_MISSION,
  param1 = format version (1), param2 = number of samples N (>= 2),
  param3 = 1 if the samples carry yaw else 0, param4 = 0 (reserved),
  x = MAGIC (0x544C4354, "TLCT"), y = 0, z = 0 (reserved). It tells the vehicle that
  the mission is a timed trajectory, not a waypoint list.
* seq 1..N, one sample each: command MAV_CMD_WAYPOINT_USER_1 (31000), frame
  MAV_FRAME_LOCAL_NED (about home, the local origin), autocontinue 1,
  param1 = t [s] since the trajectory start (>= 0, strictly increasing),
  param2 = break mask (bit 0 north, bit 1 east, bit 2 down: the spline of that axis is
  split at this sample, i.e. its velocity may jump here; 0 elsewhere),
  param3 = 0 (reserved), param4 = yaw [deg] in NED (clockwise from north) or NaN,
  x = north [m] * 1e4, y = east [m] * 1e4 (int32: the spec's local-frame encoding for
  MISSION_ITEM_INT, 0.1 mm resolution), z = down [m] (float32).

The "user" commands are the ones MAVLink reserves for vehicle-defined meaning, so no
standard field (hold time, acceptance radius) is bent to carry time; a GCS still draws
WAYPOINT_USER items as waypoints. The vehicle interpolates the samples with C2 cubic
splines (:class:`autopilot.trajectory.sampled.SampledTrajectory`, not-a-knot, split at
breaks) and flies them from the mission start; positions are absolute (about home), not
relative to where the vehicle is when the mission starts.

Resolution on the wire: time float32 (7.6 us at 120 s), x/y 0.1 mm, z float32.
Fidelity against the analytic PaperSpiralCircle (120 s, 10 ms evaluation grid, through
the wire quantisation; :func:`fidelity`, tests/test_trajectory_codec.py):

  sampled every 1.0 s (122 items), z break at 40 s: pos 5.8e-5 m, vel 1.6e-4 m/s, acc 4.3e-4 m/s^2
  sampled every 0.5 s (242 items), z break at 40 s: pos 5.4e-5 m, vel 2.4e-4 m/s, acc 1.5e-3 m/s^2
  sampled every 0.5 s, no break: pos 2.1e-2 m, vel 0.25 m/s, acc 1.7 m/s^2 (ringing at 40 s)

The spline's own error at 0.5 s is tiny (pos 7e-7 m, vel 9e-6 m/s, acc 7e-5 m/s^2); the
0.1 mm x/y quantum, differentiated, dominates and grows as the step shrinks, so steps
below ~0.5 s make the acceleration feedforward noisier, not better.

Closed loop (heli_sitl.engine.closed_loop.simulate, paper scenario, 100 Hz): flying the decoded
0.5 s upload instead of the analytic spiral changes the flown position by at most
9e-5 m, the attitude by 2.5e-4 rad and the blade pitches by 6e-5 rad with the paper's
pseudo-differentiator feedforward (9e-5 m / 4.2e-4 rad / 1e-4 rad with exact feedforward).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.sampled import SampledTrajectory
from autopilot.trajectory.waypoints import (
    FlightLimits,
    MissionBuildError,
    build_waypoint_trajectory,
)
from heli_common.frames import flip
from heli_common.geo import GeoPoint
from heli_common.state import FloatArray
from heli_common.wire.mavlink import mission_items as ms

FORMAT_VERSION = 1
MAGIC = 0x544C4354  # "TLCT"
HEADER_COMMAND = ms.CMD_TRAJ_HEADER
SAMPLE_COMMAND = ms.CMD_TRAJ_SAMPLE


class CodecError(ValueError):
    """A malformed timed trajectory: ``seq`` is the item, ``result`` a MAV_MISSION_RESULT."""

    def __init__(self, seq: int, result: int, text: str) -> None:
        super().__init__(f"item {seq}: {text}")
        self.seq = seq
        self.result = result


def encode(
    t_s: npt.ArrayLike,
    pos_nwu_m: npt.ArrayLike,
    yaw_nwu_rad: npt.ArrayLike | None = None,
    break_mask: Sequence[int] | npt.NDArray[np.integer] | None = None,
) -> list[ms.MissionItem]:
    """Samples (time [s], NWU position [m], optional NWU yaw [rad]) -> mission items.

    The samples are validated by building the trajectory the vehicle will build, so an
    encodable input always decodes.
    """
    traj = SampledTrajectory(t_s, pos_nwu_m, yaw_nwu_rad, break_mask)
    t = traj.t_s
    pos = traj.pos_nwu_m
    mask = traj.break_mask
    yaw = None if yaw_nwu_rad is None else np.asarray(yaw_nwu_rad, dtype=float).reshape(-1)
    n = t.size
    if n + 1 > ms.UINT16_MAX:
        raise ValueError(f"too many samples for one mission: {n}")
    items = [
        ms.MissionItem(
            seq=0,
            frame=ms.FRAME_MISSION,
            command=HEADER_COMMAND,
            param1=FORMAT_VERSION,
            param2=n,
            param3=0.0 if yaw is None else 1.0,
            x=MAGIC,
        )
    ]
    for i in range(n):
        north, east, down = flip(pos[i])
        # NED yaw is clockwise from north: psi_ned = -psi_nwu (heli_common.frames).
        yaw_deg = math.nan if yaw is None else _wrap_deg(-math.degrees(float(yaw[i])))
        items.append(
            ms.MissionItem(
                seq=i + 1,
                frame=ms.FRAME_LOCAL_NED,
                command=SAMPLE_COMMAND,
                param1=float(t[i]),
                param2=float(mask[i]),
                param4=yaw_deg,
                x=_local_int(north),
                y=_local_int(east),
                z=down,
            )
        )
    return items


def _wrap_deg(angle_deg: float) -> float:
    return (angle_deg + 180.0) % 360.0 - 180.0


def _local_int(metres: float) -> int:
    value = round(metres * ms.LOCAL_E4)
    if not ms.INT32_MIN <= value <= ms.INT32_MAX:
        raise ValueError(f"local coordinate {metres} m does not fit MISSION_ITEM_INT")
    return value


def sample_times(duration_s: float, dt_s: float, breaks_s: Sequence[float] = ()) -> FloatArray:
    """A uniform grid 0, dt, ..., duration (duration always included) plus the break times.

    Grid points within 1 ms of a break give way to it: two samples that close would make
    the spline ill-conditioned (and nearly collide in float32 time on the wire).
    """
    if not (math.isfinite(duration_s) and duration_s > 0.0 and math.isfinite(dt_s) and dt_s > 0.0):
        raise ValueError("duration_s and dt_s must be finite and > 0")
    n = math.ceil(duration_s / dt_s - 1e-9)
    grid = np.unique(np.minimum(np.arange(n + 1) * dt_s, duration_s))
    extra = np.unique(np.asarray([b for b in breaks_s if 0.0 < b < duration_s], dtype=float))
    if extra.size:
        near = np.min(np.abs(grid[:, None] - extra[None, :]), axis=1) <= 1e-3
        near[0] = near[-1] = False  # the ends stay: a break that close to one is dropped
        grid = grid[~near]
        extra = extra[np.min(np.abs(extra[:, None] - grid[None, [0, -1]]), axis=1) > 1e-3]
    t = np.unique(np.concatenate([grid, extra]))
    return np.asarray(t, dtype=float)


def encode_trajectory(
    traj: Trajectory, dt_s: float, breaks_s: Sequence[float] = (), duration_s: float | None = None
) -> list[ms.MissionItem]:
    """Sample ``traj`` every ``dt_s`` (plus at ``breaks_s``) and encode it.

    At each break time the axes whose velocity jumps (compared just before and after,
    or every axis if the trajectory does not know its velocity) get their break bit.
    """
    duration = traj.duration_s if duration_s is None else duration_s
    t = sample_times(duration, dt_s, breaks_s)
    rows = traj.sample(t)
    mask = np.zeros(t.size, dtype=np.int64)
    eps = 1e-6
    for b in breaks_s:
        hits = np.flatnonzero(np.abs(t - b) <= 1e-9)
        if hits.size == 0:
            continue
        before, after = traj.sample(np.array([b - eps, b + eps]))[:, 3:6]
        jump = np.abs(after - before)
        bits = 0
        for axis in range(3):
            if not np.isfinite(jump[axis]) or jump[axis] > 1e-6:
                bits |= 1 << axis
        mask[hits[0]] = bits
    return encode(t, rows[:, 0:3], break_mask=mask)


def is_timed_trajectory(items: Sequence[ms.MissionItem]) -> bool:
    """True if the mission starts with the timed-trajectory header item."""
    return bool(items) and items[0].command == HEADER_COMMAND


def decode(items: Sequence[ms.MissionItem]) -> SampledTrajectory | None:
    """Mission items -> the trajectory, or None if they are not a timed trajectory.

    Raises :class:`CodecError` (with the MAV_MISSION_RESULT to report) if the header is
    there but the rest is malformed.
    """
    if not is_timed_trajectory(items):
        return None
    head = items[0]
    if head.x != MAGIC:
        raise CodecError(head.seq, ms.INVALID_X, f"header magic {head.x:#x} != {MAGIC:#x}")
    if head.param1 != FORMAT_VERSION:
        raise CodecError(head.seq, ms.INVALID_PARAM1, f"format version {head.param1}")
    n = int(head.param2) if math.isfinite(head.param2) and head.param2.is_integer() else -1
    if n < 2 or n != len(items) - 1:
        raise CodecError(head.seq, ms.INVALID_PARAM2, f"sample count {head.param2} vs {len(items) - 1} items")
    if head.param3 not in (0.0, 1.0):
        raise CodecError(head.seq, ms.INVALID_PARAM3, f"yaw flag {head.param3}")
    with_yaw = head.param3 == 1.0
    t = np.empty(n)
    pos = np.empty((n, 3))
    yaw = np.empty(n)
    mask = np.empty(n, dtype=np.int64)
    for i, it in enumerate(items[1:]):
        if it.command != SAMPLE_COMMAND:
            raise CodecError(it.seq, ms.UNSUPPORTED, f"command {it.command} inside a trajectory")
        if it.frame != ms.FRAME_LOCAL_NED:
            raise CodecError(it.seq, ms.UNSUPPORTED_FRAME, f"frame {it.frame}")
        if not math.isfinite(it.param1) or (i > 0 and it.param1 <= t[i - 1]) or it.param1 < 0.0:
            raise CodecError(it.seq, ms.INVALID_PARAM1, f"time {it.param1} not increasing")
        if not (math.isfinite(it.param2) and it.param2.is_integer() and 0 <= it.param2 <= 7):
            raise CodecError(it.seq, ms.INVALID_PARAM2, f"break mask {it.param2}")
        if with_yaw and not math.isfinite(it.param4):
            raise CodecError(it.seq, ms.INVALID_PARAM4, "yaw missing")
        if not math.isfinite(it.z):
            raise CodecError(it.seq, ms.INVALID_Z, f"z {it.z}")
        t[i] = it.param1
        pos[i] = flip((it.local_north_m, it.local_east_m, it.z))
        yaw[i] = -math.radians(it.param4) if with_yaw else 0.0
        mask[i] = int(it.param2)
    return SampledTrajectory(t, pos, yaw if with_yaw else None, mask)


def mission_to_trajectory(
    items: Sequence[ms.MissionItem],
    home: GeoPoint | None,
    start_nwu_m: Sequence[float],
    limits: FlightLimits | None = None,
    start_seq: int = 0,
) -> Trajectory:
    """A stored mission -> the trajectory to fly: timed trajectory or waypoint mission.

    Raises CodecError / MissionBuildError (both ValueError with ``seq`` and ``result``).
    A timed trajectory always starts at its t = 0 (``start_seq`` must be 0).
    """
    timed = decode(items)
    if timed is not None:
        if start_seq != 0:
            raise CodecError(start_seq, ms.INVALID_SEQUENCE, "a timed trajectory starts at seq 0")
        return timed
    return build_waypoint_trajectory(items, home, start_nwu_m, limits, start_seq)


def check_mission(
    items: Sequence[ms.MissionItem], home: GeoPoint | None, limits: FlightLimits | None = None
) -> int:
    """A ``MissionServer.check_mission`` candidate: can the mission be flown (from home)?"""
    if not items:
        return ms.ACCEPTED
    try:
        mission_to_trajectory(items, home, (0.0, 0.0, 0.0), limits)
    except (CodecError, MissionBuildError) as exc:
        return exc.result
    except ValueError:
        return ms.INVALID
    return ms.ACCEPTED


@dataclass(frozen=True)
class Fidelity:
    """Max errors of a decoded trajectory against a reference, on a fine time grid."""

    pos_m: float
    vel_m_s: float
    acc_m_s2: float
    n_items: int


def fidelity(
    reference: Trajectory,
    dt_s: float,
    breaks_s: Sequence[float] = (),
    eval_dt_s: float = 0.01,
    skip_s: float = 1e-3,
) -> Fidelity:
    """Encode ``reference`` every ``dt_s``, decode it, and measure the max errors.

    Times within ``skip_s`` of a break are skipped: there the reference's own derivative
    is discontinuous and either side is "right".
    """
    items = encode_trajectory(reference, dt_s, breaks_s)
    decoded = decode(items)
    assert decoded is not None
    t = np.arange(0.0, reference.duration_s + 0.5 * eval_dt_s, eval_dt_s)
    for b in breaks_s:
        t = t[np.abs(t - b) > skip_s]
    err = np.abs(decoded.sample(t) - reference.sample(t))
    return Fidelity(
        pos_m=float(np.max(err[:, 0:3])),
        vel_m_s=float(np.max(err[:, 3:6])),
        acc_m_s2=float(np.max(err[:, 6:9])),
        n_items=len(items),
    )
