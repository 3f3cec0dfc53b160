"""Fast MAVLink 2 codec for the messages of the sim link, byte-compatible with pymavlink.

Every lockstep tick the plant sends one datagram (HIL_STATE_QUATERNION, ATTITUDE,
LOCAL_POSITION_NED; or its sensors: HIL_SENSOR, HIL_GPS, AHRS2) and the autopilot answers
with one HIL_ACTUATOR_CONTROLS. pymavlink's
generic packer and parser spend 30-60 us per datagram in Python (message objects, per-byte
parser state, dynamic field ordering); this module spends a few microseconds by knowing the
four layouts in advance: one precompiled ``struct.Struct`` per payload, CRC-16/MCRF4XX from
``fastcrc`` (the C extension pymavlink itself uses), and plain tuples as results.

Wire format (MAVLink 2, unsigned)::

    0xFD len incompat=0 compat=0 seq sysid compid msgid[3, LE] payload[len] crc[2, LE]

The CRC covers everything after the magic byte plus the message's CRC_EXTRA. Payloads are
truncated as pymavlink does (trailing zero bytes stripped, at least one byte kept) and
zero-padded again when decoded. Payload layouts (fields sorted by size, largest first, as
the MAVLink generator orders them) come from pymavlink 2.4.50's ``common`` dialect:

    HIL_STATE_QUATERNION (115, CRC_EXTRA 4):   <Q4ffffiiihhhHHhhh   64 bytes
    ATTITUDE             (30,  CRC_EXTRA 39):  <Iffffff             28 bytes
    LOCAL_POSITION_NED   (32,  CRC_EXTRA 185): <Iffffff             28 bytes
    HIL_ACTUATOR_CONTROLS(93,  CRC_EXTRA 47):  <QQ16fB              81 bytes
    PARAM_SET            (23,  CRC_EXTRA 168): <fBB16sB            23 bytes (world settings, rare)
    WIND_COV             (231, CRC_EXTRA 105): <Qffffffff          40 bytes (the world's air)
    ACTUATOR_OUTPUT_STATUS(375, CRC_EXTRA 251): <QI32f            140 bytes (servo positions)
    HIL_SENSOR           (107, CRC_EXTRA 108): <Q13fIB             65 bytes (IMU, mag, baro)
    HIL_GPS              (113, CRC_EXTRA 124): <QiiiHHHhhhHBBBH    39 bytes (GPS fix, status)
    AHRS2                (178, CRC_EXTRA 47):  <ffffii             24 bytes (attitude source)

Extension fields (HIL_SENSOR ``id``; HIL_GPS ``id``, ``yaw``) follow the base fields in
their declared order, unsorted; pymavlink packs them in MAVLink 2 and then truncates, and
so does this module. AHRS2 is an ArduPilot message (``ardupilotmega`` dialect, not
``common``); its id and CRC_EXTRA are the same in every dialect that defines it.

Decoding walks a datagram frame by frame and never raises: frames with a bad CRC, a
declared length running past the datagram, or an unknown message id are counted and
skipped, and the walk resynchronises on the next 0xFD (or valid 0xFE) byte. Results are
NamedTuples whose field names are pymavlink's (``att.roll``, ``lpn.vx``, ``act.controls``)
and which answer ``get_type()``, so code written for pymavlink messages reads them as is.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable
from typing import Final, NamedTuple, TypeAlias

__all__ = [
    "CRC_BACKEND",
    "MSG_ID_AHRS2",
    "MSG_ID_ATTITUDE",
    "MSG_ID_HIL_ACTUATOR_CONTROLS",
    "MSG_ID_HIL_GPS",
    "MSG_ID_HIL_SENSOR",
    "MSG_ID_HIL_STATE_QUATERNION",
    "MSG_ID_LOCAL_POSITION_NED",
    "Ahrs2",
    "Attitude",
    "Decoded",
    "HilActuatorControls",
    "HilGps",
    "HilSensor",
    "HilStateQuaternion",
    "LocalPositionNed",
    "SimCodec",
    "crc16_mcrf4xx",
    "hil_alt_vel",
]

MSG_ID_ATTITUDE: Final = 30
MSG_ID_LOCAL_POSITION_NED: Final = 32
MSG_ID_HIL_ACTUATOR_CONTROLS: Final = 93
MSG_ID_HIL_STATE_QUATERNION: Final = 115
MSG_ID_PARAM_SET: Final = 23
MSG_ID_WIND_COV: Final = 231
MSG_ID_ACTUATOR_OUTPUT_STATUS: Final = 375
MSG_ID_HIL_SENSOR: Final = 107
MSG_ID_HIL_GPS: Final = 113
MSG_ID_AHRS2: Final = 178

_CRC_EXTRA_ATT: Final = 39
_CRC_EXTRA_LPN: Final = 185
_CRC_EXTRA_ACT: Final = 47
_CRC_EXTRA_HIL: Final = 4
_CRC_EXTRA_PARAM_SET: Final = 168
_CRC_EXTRA_WIND_COV: Final = 105
_CRC_EXTRA_AOS: Final = 251
_CRC_EXTRA_SENS: Final = 108
_CRC_EXTRA_GPS: Final = 124
_CRC_EXTRA_AHRS2: Final = 47
# msgid -> CRC_EXTRA, the per-message seed that makes a layout change fail the CRC
_CRC_EXTRA: Final[dict[int, int]] = {
    MSG_ID_ATTITUDE: _CRC_EXTRA_ATT,
    MSG_ID_LOCAL_POSITION_NED: _CRC_EXTRA_LPN,
    MSG_ID_HIL_ACTUATOR_CONTROLS: _CRC_EXTRA_ACT,
    MSG_ID_HIL_STATE_QUATERNION: _CRC_EXTRA_HIL,
    MSG_ID_PARAM_SET: _CRC_EXTRA_PARAM_SET,
    MSG_ID_WIND_COV: _CRC_EXTRA_WIND_COV,
    MSG_ID_ACTUATOR_OUTPUT_STATUS: _CRC_EXTRA_AOS,
    MSG_ID_HIL_SENSOR: _CRC_EXTRA_SENS,
    MSG_ID_HIL_GPS: _CRC_EXTRA_GPS,
    MSG_ID_AHRS2: _CRC_EXTRA_AHRS2,
}

_STX_V2: Final = 0xFD
_STX_V1: Final = 0xFE
_IFLAG_SIGNED: Final = 0x01
_SIGNATURE_LEN: Final = 13
_HEADER_LEN: Final = 10  # magic + 9
_MIN_FRAME: Final = _HEADER_LEN + 2  # an empty payload is legal on the wire

# The payload structs, identical to pymavlink's ``unpacker`` of each message class.
_HIL: Final = struct.Struct("<Q4ffffiiihhhHHhhh")
_ATT: Final = struct.Struct("<Iffffff")
_LPN: Final = _ATT  # same layout, kept apart by name for readability
_ACT: Final = struct.Struct("<QQ16fB")
_PSET: Final = struct.Struct("<fBB16sB")
_WCOV: Final = struct.Struct("<Qffffffff")
_AOS: Final = struct.Struct("<QI32f")
# time_usec, xacc..zgyro, xmag..zmag, abs_pressure, diff_pressure, pressure_alt, temperature,
# fields_updated, id (extension)
_SENS: Final = struct.Struct("<Q13fIB")
# time_usec, lat, lon, alt, eph, epv, vel, vn, ve, vd, cog, fix_type, satellites_visible,
# id (extension), yaw (extension)
_GPS: Final = struct.Struct("<QiiiHHHhhhHBBBH")
# roll, pitch, yaw, altitude, lat, lng
_AHRS2: Final = struct.Struct("<ffffii")
# after the magic byte: len, incompat, compat, seq, sysid, compid, msgid low 16, msgid high 8
_HDR: Final = struct.Struct("<BBBBBBHB")
_U16: Final = struct.Struct("<H")
_SIZE_HIL: Final = _HIL.size
_SIZE_ATT: Final = _ATT.size
_SIZE_LPN: Final = _LPN.size
_SIZE_ACT: Final = _ACT.size
_SIZE_PSET: Final = _PSET.size
_SIZE_WCOV: Final = _WCOV.size
_SIZE_AOS: Final = _AOS.size
_SIZE_SENS: Final = _SENS.size
_SIZE_GPS: Final = _GPS.size
_SIZE_AHRS2: Final = _AHRS2.size
# HIL_GPS's receiver status when the caller gives none: a 3D fix, a plausible satellite
# count, accuracies unknown (UINT16_MAX); the course is always unknown
_GPS_FIX_3D: Final = 3
_GPS_UNKNOWN_U16: Final = 0xFFFF
_GPS_SATELLITES: Final = 10
_GPS_STATUS_UNKNOWN: Final = (_GPS_FIX_3D, _GPS_SATELLITES, _GPS_UNKNOWN_U16, _GPS_UNKNOWN_U16)
_NO_MAG: Final = (0.0, 0.0, 0.0)


def _crc_table() -> tuple[int, ...]:
    """Byte-at-a-time table for CRC-16/MCRF4XX (reflected poly 0x1021 = 0x8408, init 0xFFFF,
    no final xor): it folds in the one CRC_EXTRA byte cheaper than a second C call, and is
    the whole CRC when fastcrc is missing."""
    table = []
    for byte in range(256):
        c = byte
        for _ in range(8):
            c = (c >> 1) ^ 0x8408 if c & 1 else c >> 1
        table.append(c)
    return tuple(table)


_CRC_TABLE: Final = _crc_table()


def _crc16_py(data: bytes | bytearray | memoryview, initial: int | None = None) -> int:
    crc = 0xFFFF if initial is None else initial
    table = _CRC_TABLE
    for b in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


_CrcFn: TypeAlias = Callable[[bytes | bytearray, int | None], int]
crc16_mcrf4xx: _CrcFn
try:  # pymavlink uses fastcrc the same way (common.py: ``mcrf4xx = fastcrc.crc16.mcrf4xx``)
    from fastcrc.crc16 import mcrf4xx as _fast_mcrf4xx

    crc16_mcrf4xx = _fast_mcrf4xx
    CRC_BACKEND: str = "fastcrc"
except ImportError:  # pragma: no cover - pymavlink 2.4.50 depends on fastcrc
    crc16_mcrf4xx = _crc16_py
    CRC_BACKEND = "python"


# Decoded messages: header (msgid, sysid, compid, seq), then pymavlink's fields by pymavlink's
# names in its ``fieldnames`` order, arrays as tuples.
class HilStateQuaternion(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    attitude_quaternion: tuple[float, ...]  # (w, x, y, z)
    rollspeed: float
    pitchspeed: float
    yawspeed: float
    lat: int
    lon: int
    alt: int
    vx: int
    vy: int
    vz: int
    ind_airspeed: int
    true_airspeed: int
    xacc: int
    yacc: int
    zacc: int

    def get_type(self) -> str:  # the pymavlink message name, for code written against it
        return "HIL_STATE_QUATERNION"


class Attitude(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_boot_ms: int
    roll: float
    pitch: float
    yaw: float
    rollspeed: float
    pitchspeed: float
    yawspeed: float

    def get_type(self) -> str:
        return "ATTITUDE"


class LocalPositionNed(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_boot_ms: int
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float

    def get_type(self) -> str:
        return "LOCAL_POSITION_NED"


class HilActuatorControls(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    controls: tuple[float, ...]  # 16
    mode: int
    flags: int

    def get_type(self) -> str:
        return "HIL_ACTUATOR_CONTROLS"


class ParamSet(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    param_value: float
    target_system: int
    target_component: int
    param_id: str
    param_type: int

    def get_type(self) -> str:
        return "PARAM_SET"


class WindCov(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    wind_ned_m_s: tuple[float, float, float]

    def get_type(self) -> str:
        return "WIND_COV"


class ActuatorOutputStatus(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    active: int
    actuator: tuple[float, ...]  # 32

    def get_type(self) -> str:
        return "ACTUATOR_OUTPUT_STATUS"


class HilSensor(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    xacc: float
    yacc: float
    zacc: float
    xgyro: float
    ygyro: float
    zgyro: float
    xmag: float
    ymag: float
    zmag: float
    abs_pressure: float
    diff_pressure: float
    pressure_alt: float
    temperature: float
    fields_updated: int
    id: int

    def get_type(self) -> str:
        return "HIL_SENSOR"


class HilGps(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    time_usec: int
    fix_type: int
    lat: int
    lon: int
    alt: int
    eph: int
    epv: int
    vel: int
    vn: int
    ve: int
    vd: int
    cog: int
    satellites_visible: int
    id: int
    yaw: int

    def get_type(self) -> str:
        return "HIL_GPS"


class Ahrs2(NamedTuple):
    msgid: int
    sysid: int
    compid: int
    seq: int
    roll: float
    pitch: float
    yaw: float
    altitude: float
    lat: int
    lng: int

    def get_type(self) -> str:
        return "AHRS2"


Decoded: TypeAlias = (
    HilStateQuaternion
    | Attitude
    | LocalPositionNed
    | HilActuatorControls
    | ParamSet
    | WindCov
    | ActuatorOutputStatus
    | HilSensor
    | HilGps
    | Ahrs2
)

# tuple.__new__ skips the NamedTuple's generated Python __new__ (half the cost of a result)
_new = tuple.__new__
# zero padding for MAVLink 2 truncated payloads, indexed by the number of missing bytes
_PAD: Final[tuple[bytes, ...]] = tuple(
    bytes(k) for k in range(max(_SIZE_HIL, _SIZE_ACT, _SIZE_AOS, _SIZE_SENS, _SIZE_GPS, _SIZE_AHRS2) + 1)
)


def hil_alt_vel(pos_ned_m: Iterable[float], vel_ned_m_s: Iterable[float]) -> tuple[int, tuple[int, int, int]]:
    """HIL_STATE_QUATERNION's ``alt`` [mm, up] and ``vx, vy, vz`` [cm/s, int16-clamped] from
    the NED position and velocity, rounded exactly as ``sim_protocol.state_messages`` does."""
    _, _, z = pos_ned_m
    vn, ve, vd = vel_ned_m_s
    return int(round(-z * 1000)), (_i16(vn * 100), _i16(ve * 100), _i16(vd * 100))


def _i16(v: float) -> int:
    return int(max(-32768, min(32767, round(v))))


class SimCodec:
    """Encoder (with its own wrapping sequence number) and decoder (with drop counters).

    ``seq`` is the sequence number of the next frame encoded; ``encode_state`` uses three,
    ``encode_sensors`` one to three.
    Counters (never reset by the codec): ``decoded`` frames returned, ``bad_crc`` (a complete
    frame of a known message whose CRC does not match: corruption or a wrong length byte),
    ``truncated`` (header or declared length runs past the datagram end), ``unknown`` (a
    message id the codec does not know: its CRC cannot be checked), ``unsupported`` (a frame with
    a good CRC that is signed, has unknown incompat flags, or is MAVLink 1) and ``garbage``
    (runs of bytes that start no frame). One corrupted region counts once: failures starting
    inside the span a previous failure claimed are not counted again.
    """

    __slots__ = (
        "_tail_act",
        "_tail_ahrs2",
        "_tail_att",
        "_tail_gps",
        "_tail_hil",
        "_tail_lpn",
        "_tail_sens",
        "bad_crc",
        "compid",
        "decoded",
        "garbage",
        "seq",
        "sysid",
        "truncated",
        "unknown",
        "unsupported",
    )

    def __init__(self, system_id: int = 1, component_id: int = 1) -> None:
        if not (0 <= system_id <= 255 and 0 <= component_id <= 255):
            raise ValueError(f"system/component id out of uint8 range: {system_id}, {component_id}")
        self.sysid = system_id
        self.compid = component_id
        self.seq = 0
        # the header bytes after len, flags and seq never change for a given sender and message
        self._tail_hil = bytes((system_id, component_id, MSG_ID_HIL_STATE_QUATERNION, 0, 0))
        self._tail_att = bytes((system_id, component_id, MSG_ID_ATTITUDE, 0, 0))
        self._tail_lpn = bytes((system_id, component_id, MSG_ID_LOCAL_POSITION_NED, 0, 0))
        self._tail_act = bytes((system_id, component_id, MSG_ID_HIL_ACTUATOR_CONTROLS, 0, 0))
        self._tail_sens = bytes((system_id, component_id, MSG_ID_HIL_SENSOR, 0, 0))
        self._tail_gps = bytes((system_id, component_id, MSG_ID_HIL_GPS, 0, 0))
        self._tail_ahrs2 = bytes((system_id, component_id, MSG_ID_AHRS2, 0, 0))
        self.decoded = 0
        self.bad_crc = 0
        self.truncated = 0
        self.unknown = 0
        self.unsupported = 0
        self.garbage = 0

    def counters(self) -> dict[str, int]:
        return {
            "decoded": self.decoded,
            "bad_crc": self.bad_crc,
            "truncated": self.truncated,
            "unknown": self.unknown,
            "unsupported": self.unsupported,
            "garbage": self.garbage,
        }

    # -- encoding ----------------------------------------------------------------------
    def encode_state(
        self,
        t_us: int,
        att: Iterable[float],
        quat: Iterable[float],
        lat_e7: int,
        lon_e7: int,
        alt_mm: int,
        vel_ned_cm_s: Iterable[int],
        pos_ned_m: Iterable[float],
        vel_ned_m_s: Iterable[float],
    ) -> bytes:
        """One datagram: HIL_STATE_QUATERNION, ATTITUDE, LOCAL_POSITION_NED (seq, +1, +2).

        ``att`` = (roll, pitch, yaw, rollspeed, pitchspeed, yawspeed) [rad, rad/s] FRD/NED,
        ``quat`` = (w, x, y, z); HIL_STATE_QUATERNION carries ``t_us`` and the body rates of
        ``att``, the other two ``t_us // 1000``; airspeeds and accelerations are 0, as in
        ``sim_protocol.state_messages`` (see :func:`hil_alt_vel` for ``alt_mm`` and
        ``vel_ned_cm_s``). Values outside a field's range raise ``struct.error`` (floats:
        ``OverflowError``) as pymavlink does; NaN and inf are sent as they are. Python floats
        pack fastest (``ndarray.tolist()``), numpy scalars work.
        """
        roll, pitch, yaw, p, q, r = att
        t_ms = t_us // 1000
        seq = self.seq
        crc = crc16_mcrf4xx
        table = _CRC_TABLE

        pay = _HIL.pack(t_us, *quat, p, q, r, lat_e7, lon_e7, alt_mm, *vel_ned_cm_s, 0, 0, 0, 0, 0)
        pay = pay.rstrip(b"\0") or b"\0"  # MAVLink 2 truncation, as pymavlink: keep >= 1 byte
        body = bytes((len(pay), 0, 0, seq)) + self._tail_hil + pay
        c = crc(body, 0xFFFF)
        c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_HIL) & 0xFF]
        f1 = b"\xfd" + body + _U16.pack(c)

        pay = _ATT.pack(t_ms, roll, pitch, yaw, p, q, r)
        pay = pay.rstrip(b"\0") or b"\0"
        body = bytes((len(pay), 0, 0, (seq + 1) & 0xFF)) + self._tail_att + pay
        c = crc(body, 0xFFFF)
        c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_ATT) & 0xFF]
        f2 = b"\xfd" + body + _U16.pack(c)

        pay = _LPN.pack(t_ms, *pos_ned_m, *vel_ned_m_s)
        pay = pay.rstrip(b"\0") or b"\0"
        body = bytes((len(pay), 0, 0, (seq + 2) & 0xFF)) + self._tail_lpn + pay
        c = crc(body, 0xFFFF)
        c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_LPN) & 0xFF]
        self.seq = (seq + 3) & 0xFF  # only now: a value that failed to pack used no number
        return b"".join((f1, f2, b"\xfd", body, _U16.pack(c)))

    def encode_sensors(
        self,
        t_us: int,
        imu: Iterable[float],
        pressure_alt_m: float,
        fields_updated: int,
        gps: Iterable[int] | None,
        ahrs: Iterable[float] | None,
        mag: Iterable[float] = _NO_MAG,
        gps_status: Iterable[int] | None = None,
    ) -> bytes:
        """One datagram: HIL_SENSOR, then HIL_GPS if ``gps``, then AHRS2 if ``ahrs`` (seq, +1, +2).

        ``imu`` = (xacc, yacc, zacc [m/s^2], xgyro, ygyro, zgyro [rad/s]) body FRD; HIL_SENSOR
        carries ``t_us``, ``imu``, ``mag`` = (xmag, ymag, zmag) [gauss] body FRD (0 if not
        given), ``pressure_alt_m`` and ``fields_updated`` (the HIL_SENSOR_UPDATED_FLAGS bits),
        pressures, temperature and ``id`` 0. ``gps`` = (time_usec, lat_e7, lon_e7, alt_mm,
        vn, ve, vd [cm/s]), with ``gps_status`` = (fix_type, satellites_visible, eph, epv)
        (the sim link's eph/epv: accuracies in cm, see :mod:`heli_common.wire.sensor_wire`); without
        it a 3D fix, 10 satellites and unknown accuracies (UINT16_MAX). The course is unknown
        (UINT16_MAX), the ground speed ``round(hypot(vn, ve))`` [cm/s], ``id`` and ``yaw`` 0.
        ``ahrs`` = (roll, pitch, yaw) [rad] with altitude, lat and lng 0. Out-of-range values
        raise as in :meth:`encode_state` and use no sequence number.
        """
        seq = self.seq
        crc = crc16_mcrf4xx
        table = _CRC_TABLE

        pay = _SENS.pack(t_us, *imu, *mag, 0.0, 0.0, pressure_alt_m, 0.0, fields_updated, 0)
        pay = pay.rstrip(b"\0") or b"\0"  # MAVLink 2 truncation, as pymavlink: keep >= 1 byte
        body = bytes((len(pay), 0, 0, seq)) + self._tail_sens + pay
        c = crc(body, 0xFFFF)
        c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_SENS) & 0xFF]
        parts = [b"\xfd", body, _U16.pack(c)]
        k = 1

        if gps is not None:
            t_fix, lat, lon, alt, vn, ve, vd = gps
            fix_type, sats, eph, epv = _GPS_STATUS_UNKNOWN if gps_status is None else gps_status
            vel = min(_GPS_UNKNOWN_U16, int(round(math.hypot(vn, ve))))
            pay = _GPS.pack(
                t_fix, lat, lon, alt, eph, epv, vel, vn, ve, vd, _GPS_UNKNOWN_U16, fix_type, sats, 0, 0,
            )  # fmt: skip
            pay = pay.rstrip(b"\0") or b"\0"
            body = bytes((len(pay), 0, 0, (seq + k) & 0xFF)) + self._tail_gps + pay
            c = crc(body, 0xFFFF)
            c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_GPS) & 0xFF]
            parts += (b"\xfd", body, _U16.pack(c))
            k += 1

        if ahrs is not None:
            pay = _AHRS2.pack(*ahrs, 0.0, 0, 0).rstrip(b"\0") or b"\0"
            body = bytes((len(pay), 0, 0, (seq + k) & 0xFF)) + self._tail_ahrs2 + pay
            c = crc(body, 0xFFFF)
            c = (c >> 8) ^ table[(c ^ _CRC_EXTRA_AHRS2) & 0xFF]
            parts += (b"\xfd", body, _U16.pack(c))
            k += 1

        self.seq = (seq + k) & 0xFF  # only now: a value that failed to pack used no number
        return b"".join(parts)

    def encode_actuators(self, t_us: int, controls: Iterable[float], mode: int, flags: int = 0) -> bytes:
        """One HIL_ACTUATOR_CONTROLS frame; ``controls`` must hold exactly 16 values."""
        pay = _ACT.pack(t_us, flags, *controls, mode).rstrip(b"\0") or b"\0"
        seq = self.seq
        self.seq = (seq + 1) & 0xFF
        body = bytes((len(pay), 0, 0, seq)) + self._tail_act + pay
        c = crc16_mcrf4xx(body, 0xFFFF)
        c = (c >> 8) ^ _CRC_TABLE[(c ^ _CRC_EXTRA_ACT) & 0xFF]
        return b"\xfd" + body + _U16.pack(c)

    # -- decoding ----------------------------------------------------------------------
    def decode(self, data: bytes | bytearray) -> list[Decoded]:
        """Every valid frame of ``data``, in order. Never raises; see the class counters."""
        out: list[Decoded] = []
        end = len(data)
        crc = crc16_mcrf4xx
        table = _CRC_TABLE
        i = 0
        fail_end = 0  # end of the span claimed by the last failed frame candidate
        junk_end = -1  # end of the last garbage run counted
        while i < end:
            magic = data[i]
            if magic == _STX_V2:
                if i + _MIN_FRAME <= end:
                    n, iflags, _, seq, sysid, compid, mid_lo, mid_hi = _HDR.unpack_from(data, i + 1)
                    msgid = mid_lo | (mid_hi << 16)
                    pend = i + _HEADER_LEN + n  # payload end = CRC start
                    fend = pend + 2 + (_SIGNATURE_LEN if iflags & _IFLAG_SIGNED else 0)
                    if fend <= end:
                        extra = _CRC_EXTRA.get(msgid)
                        if extra is not None:
                            c = crc(data[i + 1 : pend], 0xFFFF)
                            c = (c >> 8) ^ table[(c ^ extra) & 0xFF]
                            if c == data[pend] | (data[pend + 1] << 8):
                                if iflags:
                                    # Signed (the sim link never is) or a feature we cannot
                                    # parse: the CRC vouches for the frame, skip it whole.
                                    self.unsupported += 1
                                    i = fend
                                    fail_end = 0
                                    continue
                                p0 = i + _HEADER_LEN
                                if msgid == MSG_ID_ATTITUDE:
                                    t = (
                                        _ATT.unpack_from(data, p0)
                                        if n >= _SIZE_ATT
                                        else _ATT.unpack(data[p0:pend] + _PAD[_SIZE_ATT - n])
                                    )
                                    out.append(_new(Attitude, (msgid, sysid, compid, seq) + t))
                                elif msgid == MSG_ID_LOCAL_POSITION_NED:
                                    t = (
                                        _LPN.unpack_from(data, p0)
                                        if n >= _SIZE_LPN
                                        else _LPN.unpack(data[p0:pend] + _PAD[_SIZE_LPN - n])
                                    )
                                    out.append(_new(LocalPositionNed, (msgid, sysid, compid, seq) + t))
                                elif msgid == MSG_ID_HIL_STATE_QUATERNION:
                                    t = (
                                        _HIL.unpack_from(data, p0)
                                        if n >= _SIZE_HIL
                                        else _HIL.unpack(data[p0:pend] + _PAD[_SIZE_HIL - n])
                                    )
                                    out.append(
                                        _new(
                                            HilStateQuaternion,
                                            (msgid, sysid, compid, seq, t[0], t[1:5]) + t[5:],
                                        )
                                    )
                                elif msgid == MSG_ID_HIL_SENSOR:
                                    t = (
                                        _SENS.unpack_from(data, p0)
                                        if n >= _SIZE_SENS
                                        else _SENS.unpack(data[p0:pend] + _PAD[_SIZE_SENS - n])
                                    )
                                    out.append(_new(HilSensor, (msgid, sysid, compid, seq) + t))
                                elif msgid == MSG_ID_HIL_GPS:
                                    t = (
                                        _GPS.unpack_from(data, p0)
                                        if n >= _SIZE_GPS
                                        else _GPS.unpack(data[p0:pend] + _PAD[_SIZE_GPS - n])
                                    )
                                    # wire order: time, lat..cog, fix_type, satellites, id, yaw
                                    t = (msgid, sysid, compid, seq, t[0], t[11]) + t[1:11] + t[12:]
                                    out.append(_new(HilGps, t))
                                elif msgid == MSG_ID_AHRS2:
                                    t = (
                                        _AHRS2.unpack_from(data, p0)
                                        if n >= _SIZE_AHRS2
                                        else _AHRS2.unpack(data[p0:pend] + _PAD[_SIZE_AHRS2 - n])
                                    )
                                    out.append(_new(Ahrs2, (msgid, sysid, compid, seq) + t))
                                elif msgid == MSG_ID_WIND_COV:
                                    t = (
                                        _WCOV.unpack_from(data, p0)
                                        if n >= _SIZE_WCOV
                                        else _WCOV.unpack(data[p0:pend] + _PAD[_SIZE_WCOV - n])
                                    )
                                    out.append(_new(WindCov, (msgid, sysid, compid, seq, t[0], t[1:4])))
                                elif msgid == MSG_ID_ACTUATOR_OUTPUT_STATUS:
                                    t = (
                                        _AOS.unpack_from(data, p0)
                                        if n >= _SIZE_AOS
                                        else _AOS.unpack(data[p0:pend] + _PAD[_SIZE_AOS - n])
                                    )
                                    t = (msgid, sysid, compid, seq, t[0], t[1], t[2:])
                                    out.append(_new(ActuatorOutputStatus, t))
                                elif msgid == MSG_ID_PARAM_SET:
                                    v, ts, tc, pid, ptype = (
                                        _PSET.unpack_from(data, p0)
                                        if n >= _SIZE_PSET
                                        else _PSET.unpack(data[p0:pend] + _PAD[_SIZE_PSET - n])
                                    )
                                    name = pid.split(b"\0", 1)[0].decode("ascii", "replace")
                                    t = (msgid, sysid, compid, seq, v, ts, tc, name, ptype)
                                    out.append(_new(ParamSet, t))
                                else:  # HIL_ACTUATOR_CONTROLS; wire order: time, flags, controls, mode
                                    t = (
                                        _ACT.unpack_from(data, p0)
                                        if n >= _SIZE_ACT
                                        else _ACT.unpack(data[p0:pend] + _PAD[_SIZE_ACT - n])
                                    )
                                    out.append(
                                        _new(
                                            HilActuatorControls,
                                            (msgid, sysid, compid, seq, t[0], t[2:18], t[18], t[1]),
                                        )
                                    )
                                i = fend
                                fail_end = 0
                                continue
                            if i >= fail_end:
                                self.bad_crc += 1
                        elif i >= fail_end:
                            self.unknown += 1
                    elif i >= fail_end:
                        self.truncated += 1
                    claimed = fend
                else:
                    if i >= fail_end:
                        self.truncated += 1
                    claimed = end
                # Not a frame we can use. Its span is not trusted (the length byte may be
                # the corrupted one), so frames starting inside it are still looked for.
                if claimed > fail_end:
                    fail_end = claimed
                skip_from = fail_end  # only bytes skipped past the claimed span are garbage
            else:
                if magic == _STX_V1 and i + 8 <= end:
                    # MAVLink 1: FE len seq sysid compid msgid payload crc. Skipped whole when
                    # its CRC proves it is one; otherwise the FE is just a garbage byte.
                    fend = i + 8 + data[i + 1]
                    extra = _CRC_EXTRA.get(data[i + 5])
                    if extra is not None and fend <= end:
                        c = crc(data[i + 1 : fend - 2], 0xFFFF)
                        c = (c >> 8) ^ table[(c ^ extra) & 0xFF]
                        if c == data[fend - 2] | (data[fend - 1] << 8):
                            self.unsupported += 1
                            i = fend
                            fail_end = 0
                            continue
                # a byte that starts no frame
                skip_from = i if i >= fail_end else fail_end
            j = _next_magic(data, i + 1, end)
            if skip_from < j:
                # Garbage outside any failed frame's span: one count per contiguous run (a
                # false magic byte where the last skip stopped continues that run).
                if skip_from != junk_end:
                    self.garbage += 1
                junk_end = j
            i = j
        self.decoded += len(out)
        return out


def _next_magic(data: bytes | bytearray, start: int, end: int) -> int:
    j = data.find(b"\xfd", start)
    k = data.find(b"\xfe", start, j if j >= 0 else end)
    if k >= 0:
        return k
    return j if j >= 0 else end
