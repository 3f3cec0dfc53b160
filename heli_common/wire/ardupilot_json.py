"""ArduPilot's JSON SITL backend on the wire: servo frames in, vehicle state out.

The firmware side is ``libraries/SITL/SIM_JSON.cpp`` (docs/ardupilot-json.md cites its
functions). Pure functions, no I/O: :mod:`heli_plant.ardupilot_link` owns the socket.

* Firmware -> physics, one UDP datagram a step (``JSON::output_servos``): little-endian
  ``uint16 magic, uint16 frame_rate, uint32 frame_count, uint16 pwm[N]``; N = 16 with
  magic 18458, N = 32 with magic 29569 (``SERVO_32_ENABLE``). 40 or 72 bytes, no padding.
* Physics -> firmware, one datagram a step: ``b"\\n" + compact JSON + b"\\n"``, read by
  ``JSON::recv_fdm`` / ``JSON::parse_sensors``, a ``strstr`` + ``sscanf("[%f, %f, %f]")``
  scanner that is not a JSON parser: a space after a colon breaks it, so the JSON here is
  always compact; NaN and infinities would be parsed as such, so they are refused here.

Frames: the wire is earth NED / body FRD; the bench's plant state is earth NWU / body FLU
(:mod:`heli_common.state`), converted through :mod:`heli_common.frames` only.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from heli_common.frames import NF_POS, NF_QUAT, NF_RATES, NF_VEL, flu_to_frd, state_to_ned_fields
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import N_STATE, FloatArray

__all__ = [
    "ANSWER", "HEADER", "MAGIC_16", "MAGIC_32", "MAX_DATAGRAM_BYTES", "PACKET_BYTES", "QUAT_NORM_TOL",
    "Refusal", "RefusalReason", "ServoFrame", "encode_servo_packet", "json_state_from_plant",
    "parse_servo_packet", "state_json",
]  # fmt: skip

MAGIC_16: Final = 18458  # struct servo_packet_16 (SIM_JSON.h)
MAGIC_32: Final = 29569  # struct servo_packet_32, sent when SERVO_32_ENABLE = 1
HEADER: Final = struct.Struct("<HHI")  # magic, frame_rate [Hz], frame_count
_PACKETS: Final = {MAGIC_16: struct.Struct("<HHI16H"), MAGIC_32: struct.Struct("<HHI32H")}
PACKET_BYTES: Final = {magic: s.size for magic, s in _PACKETS.items()}  # 40 and 72
# the most one UDP datagram can carry: a receive buffer this size never truncates one
MAX_DATAGRAM_BYTES: Final = 65535
# a state's quaternion whose norm is further than this from 1 is a caller's bug, not rounding
QUAT_NORM_TOL: Final = 1e-3


class RefusalReason(enum.Enum):
    """Why a datagram is not a servo frame. The value names the counter that counts it."""

    SHORT = "short"  # fewer bytes than the header, or than its magic's packet
    OVERSIZED = "oversized"  # more bytes than its magic's packet
    MAGIC = "magic"  # neither 18458 nor 29569
    FRAME_RATE = "frame_rate"  # 0 Hz: no time step can be derived from it


@dataclass(frozen=True, slots=True)
class Refusal:
    """A datagram that is not a servo frame, and why."""

    reason: RefusalReason
    detail: str


@dataclass(frozen=True, slots=True)
class ServoFrame:
    """One servo frame as the firmware sent it.

    ``pwm_us`` is a tuple (read-only) of 16 or 32 pulse widths [us]; 0 is what the firmware
    sends for a channel with no output. ArduPilot helicopter channels: SERVO1-3 swashplate,
    SERVO4 tail, SERVO8 HeliRSC (rotor speed / interlock).
    """

    magic: int
    frame_rate_hz: int  # the physics step the firmware asks for is 1 / frame_rate_hz
    frame_count: int  # +1 a step; repeated on a re-send; from 0 again when SITL restarts
    pwm_us: tuple[int, ...]

    @property
    def dt_s(self) -> float:
        return 1.0 / self.frame_rate_hz

    def channel(self, n: int) -> int:
        """SERVOn's pulse width [us], ``n`` counted from 1 as ArduPilot counts them."""
        if not 1 <= n <= len(self.pwm_us):
            raise IndexError(f"SERVO{n}: this frame has channels 1..{len(self.pwm_us)}")
        return self.pwm_us[n - 1]


def parse_servo_packet(data: bytes) -> ServoFrame | Refusal:
    """Decode one datagram from ``JSON::output_servos``, or say why it is not one.

    Never raises: every byte string is either a frame or a :class:`Refusal`. A uint16 or a
    uint32 has no NaN and no infinity, so no field can be "non-finite"; the one value that
    cannot be used is a frame rate of 0 Hz. (A uint16 frame rate is at most 65535 Hz, so no
    separate upper bound can be exceeded.)
    """
    n = len(data)
    if n < HEADER.size:
        return Refusal(RefusalReason.SHORT, f"{n} bytes, fewer than the {HEADER.size}-byte header")
    magic, frame_rate, frame_count = HEADER.unpack_from(data)
    packet = _PACKETS.get(magic)
    if packet is None:
        return Refusal(RefusalReason.MAGIC, f"magic {magic} is neither {MAGIC_16} nor {MAGIC_32}")
    if n < packet.size:
        return Refusal(RefusalReason.SHORT, f"{n} bytes, magic {magic} needs {packet.size}")
    if n > packet.size:
        return Refusal(RefusalReason.OVERSIZED, f"{n} bytes, magic {magic} needs {packet.size}")
    if frame_rate == 0:
        return Refusal(RefusalReason.FRAME_RATE, "frame rate 0 Hz")
    fields = packet.unpack(data)
    return ServoFrame(magic, frame_rate, frame_count, tuple(fields[3:]))


def encode_servo_packet(frame_rate_hz: int, frame_count: int, pwm_us: Sequence[int]) -> bytes:
    """The datagram the firmware would send (for tests and fakes): 16 PWMs give magic
    18458, 32 give 29569. Raises ValueError on a value its field cannot hold."""
    magic = {16: MAGIC_16, 32: MAGIC_32}.get(len(pwm_us))
    if magic is None:
        raise ValueError(f"a servo packet carries 16 or 32 PWMs, got {len(pwm_us)}")
    try:
        return _PACKETS[magic].pack(magic, frame_rate_hz, frame_count, *pwm_us)
    except struct.error as exc:
        raise ValueError(f"servo packet field out of range: {exc}") from None


# -- the state answer ---------------------------------------------------------------------
_VecIn = Sequence[float] | npt.NDArray[np.float64]


def _finite(name: str, values: _VecIn, n: int) -> list[float]:
    out = [float(v) for v in values]
    if len(out) != n:
        raise ValueError(f"{name} needs {n} components, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} is not finite: {out} (the firmware would fly on it: never sent)")
    return out


# The answer's values in the order written; gyro, accel_body, velocity and quaternion are
# float32 on the firmware's side, timestamp and position double
ANSWER = Layout("state answer", ("timestamp", 1), ("gyro", 3), ("accel_body", 3), ("position", 3),
                ("velocity", 3), ("quaternion", 4))  # fmt: skip
_A_TIME = ANSWER.offset("timestamp")
_A_GYRO = ANSWER.offset("gyro")
_A_ACCEL = ANSWER.offset("accel_body")
_A_POS = ANSWER.offset("position")
_A_VEL = ANSWER.offset("velocity")
_A_QUAT = ANSWER.offset("quaternion")
_N_VALUES = ANSWER.size
_FIELDS = tuple((name, ANSWER.size_of(name)) for name in ANSWER.names)
# the fields the firmware stores as float32 (Vector3f, Quaternion), as [start, end) ranges
_F32_BLOCKS = tuple((ANSWER.offset(n), ANSWER.offset(n) + ANSWER.size_of(n))
                    for n in ("gyro", "accel_body", "velocity", "quaternion"))  # fmt: skip

# what _to_wire found: the answer is sent only on _WIRE_OK; the others name the refusal
_WIRE_OK, _WIRE_NOT_FINITE, _WIRE_NEGATIVE_TIME, _WIRE_BAD_NORM, _WIRE_OVERFLOW = range(5)

# compact JSON (no space anywhere: parse_sensors steps over `"key":` and expects `[`), the
# numbers as Python's shortest round-trip repr (%r), which is what json.dumps writes for a
# float; %-formatting because it is the cheapest formatter at 1200 answers a second
_TEMPLATE = (
    '\n{"timestamp":%r,"imu":{"gyro":[%r,%r,%r],"accel_body":[%r,%r,%r]},"position":[%r,%r,%r],'
    '"velocity":[%r,%r,%r],"quaternion":[%r,%r,%r,%r]}\n'
)


@njit
def _to_wire(v: FloatArray) -> tuple[int, float]:
    """The answer's values (layout :data:`ANSWER`) made what the firmware stores, in place:
    the quaternion normalised, the float32 fields rounded to float32 (IEEE round-to-nearest-
    even, the cast). Returns ``(_WIRE_* status, the quaternion's norm)``; on a status other
    than ``_WIRE_OK`` the values must not be sent (and may be half converted)."""
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return _WIRE_NOT_FINITE, math.nan
    if v[_A_TIME] < 0.0:
        return _WIRE_NEGATIVE_TIME, math.nan
    sum_sq = 0.0
    for i in range(_A_QUAT, _A_QUAT + 4):
        sum_sq += v[i] * v[i]
    norm = math.sqrt(sum_sq)
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        return _WIRE_BAD_NORM, norm
    for i in range(_A_QUAT, _A_QUAT + 4):
        v[i] = v[i] / norm
    for start, end in _F32_BLOCKS:
        for i in range(start, end):
            r = np.float64(np.float32(v[i]))
            if math.isinf(r):  # finite before: a float32 cannot hold it (Vector3f)
                return _WIRE_OVERFLOW, norm
            v[i] = r
    return _WIRE_OK, norm


def _format(v: FloatArray) -> bytes:
    return (_TEMPLATE % tuple(v.tolist())).encode("ascii")


def state_json(
    timestamp_s: float,
    gyro_frd_rad_s: _VecIn,
    accel_frd_m_s2: _VecIn,
    pos_ned_m: _VecIn,
    vel_ned_m_s: _VecIn,
    quat_wxyz: _VecIn,
) -> bytes:
    """The answer to one servo frame: ``b"\\n" + compact JSON + b"\\n"``.

    * ``timestamp`` [s]: physics time, a double (``atof``); it should start near 0 and grow
      by one step a frame: the firmware's clock advances by its increments.
    * ``imu.gyro`` [rad/s, body FRD], ``imu.accel_body`` [m/s^2, specific force, body FRD]
      (at rest, level: (0, 0, -g)): float32 (``Vector3f``).
    * ``position`` [m, NED from home]: double (``Vector3d``, ``%lf``).
    * ``velocity`` [m/s, earth NED]: float32.
    * ``quaternion`` [w, x, y, z], body FRD -> earth NED (ArduPilot's ``q1..q4``): float32;
      normalised here, refused if its norm is further than :data:`QUAT_NORM_TOL` from 1.

    The float32 fields are rounded here, where the rounding is IEEE round-to-nearest-even,
    and written as the result's exact double repr: the firmware's ``sscanf("%f")`` (strtof)
    then stores exactly this float32, with no second rounding of its own.

    Never ``attitude`` (the quaternion wins anyway), never ``no_time_sync`` (it takes the
    firmware off lockstep timing). Raises ValueError on a non-finite value: NaN never
    reaches the firmware, whose ``sscanf`` would read ``NaN`` as a number.
    """
    parts = (gyro_frd_rad_s, accel_frd_m_s2, pos_ned_m, vel_ned_m_s, quat_wxyz)
    try:  # plain floats first: a wrong type or length is named before anything is converted
        v = [float(timestamp_s)]
        for a in parts:
            v += a.tolist() if isinstance(a, np.ndarray) else [float(c) for c in a]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"state answer: not numbers: {exc}") from None
    if len(v) != _N_VALUES:
        _explain(timestamp_s, *parts)
    w = np.array(v, dtype=np.float64)
    status, norm = _to_wire(w)
    if status != _WIRE_OK:
        _refuse(status, norm, v, timestamp_s, parts)
    return _format(w)


def _refuse(status: int, norm: float, v: list[float], timestamp_s: float, parts: tuple[_VecIn, ...]) -> None:
    """Raise the ValueError for a ``_WIRE_*`` refusal of the values ``v``."""
    if status == _WIRE_NOT_FINITE:
        _explain(timestamp_s, *parts)
    if status == _WIRE_NEGATIVE_TIME:
        raise ValueError(f"timestamp {v[_A_TIME]} s is negative")
    if status == _WIRE_BAD_NORM:
        raise ValueError(f"quaternion {v[_A_QUAT:]} has norm {norm}, not 1")
    raise ValueError(f"{v} overflows a float32 (the firmware's Vector3f)")


def _explain(*fields: object) -> None:
    """Raise the ValueError naming the field that is the wrong size or not finite."""
    for (name, n), values in zip(_FIELDS, fields, strict=True):
        _finite(name, np.asarray(values, dtype=np.float64).reshape(-1), n)
    raise ValueError("state answer: wrong number of values")  # (unreachable: one field is wrong)


@njit
def _plant_answer(
    t_s: float, x: FloatArray, accel_frd_x: float, accel_frd_y: float, accel_frd_z: float
) -> tuple[FloatArray, int]:
    """The answer's values (layout :data:`ANSWER`) from a plant state, converted by
    :func:`state_to_ned_fields` and made wire values by :func:`_to_wire`, in one compiled
    call; with the ``_WIRE_*`` status (a non-finite state is refused before converting)."""
    v = np.empty(_N_VALUES)
    for i in range(N_STATE):
        if not math.isfinite(x[i]):
            return v, _WIRE_NOT_FINITE
    f = state_to_ned_fields(x)
    v[_A_TIME] = t_s
    v[_A_GYRO : _A_GYRO + 3] = f[NF_RATES : NF_RATES + 3]
    v[_A_ACCEL], v[_A_ACCEL + 1], v[_A_ACCEL + 2] = accel_frd_x, accel_frd_y, accel_frd_z
    v[_A_POS : _A_POS + 3] = f[NF_POS : NF_POS + 3]
    v[_A_VEL : _A_VEL + 3] = f[NF_VEL : NF_VEL + 3]
    v[_A_QUAT : _A_QUAT + 4] = f[NF_QUAT : NF_QUAT + 4]
    status, _ = _to_wire(v)
    return v, status


def json_state_from_plant(t_s: float, x: npt.ArrayLike, accel_flu_m_s2: _VecIn) -> bytes:
    """:func:`state_json` from the plant state and its specific force.

    ``x`` is the 12-element plant state (:mod:`heli_common.state`): position earth NWU [m],
    velocity body FLU [m/s], ZYX Euler (phi, theta, psi) [rad] of body FLU in earth NWU,
    rates body FLU [rad/s]. ``accel_flu_m_s2`` is the specific force in body FLU (what an
    accelerometer reads: (0, 0, +g) level at rest). Position NWU -> NED, velocity body FLU
    -> earth NWU -> NED, rates and specific force FLU -> FRD, attitude as the body FRD ->
    earth NED quaternion, all by :mod:`heli_common.frames`.

    The backend's hot path (1200 answers a second): one compiled call converts, normalises
    and rounds, and the text is formatted once. Whatever that call refuses goes through
    :func:`state_json` with the same values, which raises the ValueError that says why.
    """
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (N_STATE,):
        raise ValueError(f"plant state must have shape ({N_STATE},), got {a.shape}")
    if isinstance(t_s, float | int) and len(accel_flu_m_s2) == 3:
        v, status = _plant_answer(float(t_s), a, *flu_to_frd(accel_flu_m_s2))
        if status == _WIRE_OK:
            return _format(v)
    # refused: the validating path, for the message (or odd input types, for their checks)
    _finite("plant state", a, N_STATE)  # before the compiled conversion, for a clear message
    f = state_to_ned_fields(a)
    return state_json(
        t_s,
        gyro_frd_rad_s=f[NF_RATES : NF_RATES + 3],
        accel_frd_m_s2=flu_to_frd(_finite("specific force", accel_flu_m_s2, 3)),
        pos_ned_m=f[NF_POS : NF_POS + 3],
        vel_ned_m_s=f[NF_VEL : NF_VEL + 3],
        quat_wxyz=f[NF_QUAT : NF_QUAT + 4],
    )


# -- the pacer: a ground station in the lockstep (heli_plant.pacer) ------------------------
PACE_PORT_OFFSET = 6  # beside the JSON port (9002 + 10 N): 9008 + 10 N
PACE = struct.Struct("<d")  # the physics time [s] up to which the client is ready


def encode_pace(until_s: float) -> bytes:
    """The pacer datagram: the physics may run to ``until_s``; NaN or +inf releases it."""
    return PACE.pack(until_s)
