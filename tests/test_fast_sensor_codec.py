"""SimCodec's sensor datagram (HIL_SENSOR, HIL_GPS, AHRS2) against pymavlink 2.4.50: same bytes,
same values, and one corrupted frame costs only that frame.

The project's dialect (``heli_common.wire.mavlink.udp.mavlink2``, pymavlink's ``development``) has
HIL_SENSOR and HIL_GPS but not AHRS2, an ArduPilot message: the reference packer and parser
are ``ardupilotmega``, whose HIL_SENSOR and HIL_GPS are checked to be the project dialect's.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Sequence
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as apm

from heli_common.wire.mavlink.fast import (
    MSG_ID_AHRS2,
    MSG_ID_HIL_GPS,
    MSG_ID_HIL_SENSOR,
    Ahrs2,
    Decoded,
    HilGps,
    HilSensor,
    SimCodec,
)
from heli_common.wire.mavlink.udp import mavlink2

# at least ~200 examples per property; the ``thorough`` profile runs more
N_EXAMPLES = max(200, settings().max_examples)


def _ints(lo: int, hi: int) -> st.SearchStrategy[int]:
    return st.one_of(st.sampled_from([lo, hi, 0, lo + 1, hi - 1]), st.integers(lo, hi))


U8 = _ints(0, 255)
U16 = _ints(0, 2**16 - 1)
U32 = _ints(0, 2**32 - 1)
U64 = _ints(0, 2**64 - 1)
I16 = _ints(-(2**15), 2**15 - 1)
I32 = _ints(-(2**31), 2**31 - 1)
# float32 values (NaN, inf, subnormals included) and doubles that round to a finite float32
# (or to 0: tiny doubles exercise the truncation of trailing zero bytes)
F32 = st.one_of(
    st.sampled_from([0.0, -0.0, math.nan, math.inf, -math.inf, 3.4028234e38, -3.4028234e38, 1e-45, 1e-300]),
    st.floats(width=32),
    st.floats(-3.4e38, 3.4e38),
)
IMU = st.tuples(F32, F32, F32, F32, F32, F32)
GPS = st.none() | st.tuples(U64, I32, I32, I32, I16, I16, I16)
AHRS = st.none() | st.tuples(F32, F32, F32)
sensor_args = st.tuples(U64, IMU, F32, U32, GPS, AHRS)


def f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def same(a: Any, b: Any) -> bool:
    """Field equality, NaN equal to NaN (and -0.0 apart from 0.0), arrays elementwise."""
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)
    return bool(a == b) and type(a) is type(b)


def assert_same_message(ours: Decoded, theirs: Any) -> None:
    assert ours.get_type() == theirs.get_type()
    assert ours.msgid == theirs.get_msgId()
    assert (ours.sysid, ours.compid, ours.seq) == (
        theirs.get_srcSystem(),
        theirs.get_srcComponent(),
        theirs.get_seq(),
    )
    names = theirs.get_fieldnames()
    assert list(ours._fields[4:]) == names  # pymavlink's field names in pymavlink's order
    for name in names:
        assert same(getattr(ours, name), getattr(theirs, name)), name


def pm_parse(data: bytes, dialect: Any = apm) -> list[Any]:
    mav = dialect.MAVLink(None)
    mav.robust_parsing = True
    return [m for m in (mav.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]


def pm_pack(msgs: Sequence[Any], sysid: int, compid: int, seq0: int) -> bytes:
    mav = apm.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    out = b""
    for k, m in enumerate(msgs):
        mav.seq = (seq0 + k) & 0xFF
        out += m.pack(mav)
    return out


def ground_speed(vn: int, ve: int) -> int:
    return min(65535, round(math.hypot(vn, ve)))


def sensor_reference(args: tuple[Any, ...]) -> list[Any]:
    """The messages ``encode_sensors(*args)`` stands for, as pymavlink objects."""
    t_us, imu, palt, fields, gps, ahrs = args
    out = [apm.MAVLink_hil_sensor_message(t_us, *imu, 0, 0, 0, 0, 0, palt, 0, fields, 0)]
    if gps is not None:
        t_fix, lat, lon, alt, vn, ve, vd = gps
        out.append(
            apm.MAVLink_hil_gps_message(
                t_fix, 3, lat, lon, alt, 65535, 65535, ground_speed(vn, ve), vn, ve, vd, 65535, 10, 0, 0
            )
        )
    if ahrs is not None:
        out.append(apm.MAVLink_ahrs2_message(*ahrs, 0, 0, 0))
    return out


def test_project_dialect_has_the_same_layouts() -> None:
    for name in ("MAVLink_hil_sensor_message", "MAVLink_hil_gps_message"):
        ours, ref = getattr(mavlink2, name), getattr(apm, name)
        assert (ours.id, ours.crc_extra, ours.unpacker.format, ours.fieldnames) == (
            ref.id, ref.crc_extra, ref.unpacker.format, ref.fieldnames)  # fmt: skip
    ids = (apm.MAVLink_hil_sensor_message.id, apm.MAVLink_hil_gps_message.id, apm.MAVLink_ahrs2_message.id)
    assert ids == (MSG_ID_HIL_SENSOR, MSG_ID_HIL_GPS, MSG_ID_AHRS2)


# -- (a) our bytes are pymavlink's bytes -------------------------------------------------
@settings(max_examples=N_EXAMPLES)
@given(sensor_args, U8, U8, U8)
def test_encode_sensors_matches_pymavlink(args: tuple[Any, ...], sysid: int, compid: int, seq: int) -> None:
    codec = SimCodec(sysid, compid)
    codec.seq = seq
    data = codec.encode_sensors(*args)
    ref = sensor_reference(args)
    assert codec.seq == (seq + len(ref)) & 0xFF
    assert data == pm_pack(ref, sysid, compid, seq)


# -- (b) our bytes decode, with ours and with pymavlink's parser, to the values given ----
@settings(max_examples=N_EXAMPLES)
@given(sensor_args, U8, U8, U8)
def test_encode_sensors_decodes_to_the_values(
    args: tuple[Any, ...], sysid: int, compid: int, seq: int
) -> None:
    t_us, imu, palt, fields, gps, ahrs = args
    codec = SimCodec(sysid, compid)
    codec.seq = seq
    data = codec.encode_sensors(*args)
    ours = SimCodec().decode(data)
    theirs = pm_parse(data)
    types = ["HIL_SENSOR"] + ["HIL_GPS"] * (gps is not None) + ["AHRS2"] * (ahrs is not None)
    assert [m.get_type() for m in ours] == [m.get_type() for m in theirs] == types
    for k, (o, t) in enumerate(zip(ours, theirs, strict=True)):
        assert (o.sysid, o.compid, o.seq) == (sysid, compid, (seq + k) & 0xFF)
        assert_same_message(o, t)

    sens = ours[0]
    assert isinstance(sens, HilSensor) and sens.msgid == MSG_ID_HIL_SENSOR
    assert sens.time_usec == t_us and sens.fields_updated == fields and sens.id == 0
    assert same([sens.xacc, sens.yacc, sens.zacc, sens.xgyro, sens.ygyro, sens.zgyro], [f32(v) for v in imu])
    assert same(sens.pressure_alt, f32(palt))
    zeros = (sens.xmag, sens.ymag, sens.zmag, sens.abs_pressure, sens.diff_pressure, sens.temperature)
    assert same(zeros, (0.0,) * 6)
    rest = ours[1:]
    if gps is not None:
        g = rest.pop(0)
        assert isinstance(g, HilGps) and g.msgid == MSG_ID_HIL_GPS
        t_fix, lat, lon, alt, vn, ve, vd = gps
        assert (g.time_usec, g.lat, g.lon, g.alt, g.vn, g.ve, g.vd) == (t_fix, lat, lon, alt, vn, ve, vd)
        assert (g.fix_type, g.eph, g.epv, g.vel, g.cog) == (3, 65535, 65535, ground_speed(vn, ve), 65535)
        assert (g.satellites_visible, g.id, g.yaw) == (10, 0, 0)
    if ahrs is not None:
        a = rest.pop(0)
        assert isinstance(a, Ahrs2) and a.msgid == MSG_ID_AHRS2
        assert same([a.roll, a.pitch, a.yaw], [f32(v) for v in ahrs])
        assert same((a.altitude, a.lat, a.lng), (0.0, 0, 0))
    assert rest == []


def test_project_dialect_parses_hil_sensor_and_hil_gps() -> None:
    data = SimCodec(1, 51).encode_sensors(
        5_000_000, (0.1, -0.2, -9.8, 0.01, 0.02, -0.03), 12.5, 0x1C3F,
        (4_990_000, 473_977_418, 85_455_939, 488_123, 150, -230, 12), None,
    )  # fmt: skip
    sens, gps = pm_parse(data, mavlink2)
    assert sens.get_type() == "HIL_SENSOR" and sens.fields_updated == 0x1C3F and sens.pressure_alt == 12.5
    assert gps.get_type() == "HIL_GPS" and (gps.lat, gps.lon, gps.alt, gps.vel) == (
        473_977_418, 85_455_939, 488_123, 275)  # fmt: skip


# pymavlink's bytes decode to pymavlink's values, every field free (extensions included)
any_sensor_message = st.one_of(
    st.builds(apm.MAVLink_hil_sensor_message, U64, *[F32] * 13, U32, U8),
    st.builds(
        apm.MAVLink_hil_gps_message, U64, U8, I32, I32, I32, U16, U16, U16, I16, I16, I16, U16, U8, U8, U16
    ),
    st.builds(apm.MAVLink_ahrs2_message, F32, F32, F32, F32, I32, I32),
)


@settings(max_examples=N_EXAMPLES)
@given(st.lists(any_sensor_message, min_size=1, max_size=4), U8, U8, U8)
def test_decode_pymavlink_packed_sensors(msgs: list[Any], sysid: int, compid: int, seq: int) -> None:
    data = pm_pack(msgs, sysid, compid, seq)
    codec = SimCodec()
    ours = codec.decode(data)
    theirs = pm_parse(data)
    assert len(ours) == len(theirs) == len(msgs)
    for o, t in zip(ours, theirs, strict=True):
        assert_same_message(o, t)
    assert codec.counters() == dict.fromkeys(codec.counters(), 0) | {"decoded": len(msgs)}


def test_all_zero_payloads_are_truncated_and_zero_extended() -> None:
    codec = SimCodec()
    data = codec.encode_sensors(0, (0.0,) * 6, 0.0, 0, (0, 0, 0, 0, 0, 0, 0), (0.0, 0.0, 0.0))
    assert data == pm_pack(sensor_reference((0, (0.0,) * 6, 0.0, 0, (0,) * 7, (0.0,) * 3)), 1, 1, 0)
    # HIL_SENSOR and AHRS2 keep one byte; HIL_GPS ends in its zero extensions (id, yaw)
    assert data[1] == 1 and data[13 + 1] == 39 - 3 and data[-13 + 1] == 1 and len(data) == 13 + 48 + 13
    sens, gps, ahrs = codec.decode(data)
    assert sens == HilSensor(107, 1, 1, 0, 0, *(0.0,) * 13, 0, 0)
    assert gps == HilGps(113, 1, 1, 1, 0, 3, 0, 0, 0, 65535, 65535, 0, 0, 0, 0, 65535, 10, 0, 0)
    assert ahrs == Ahrs2(178, 1, 1, 2, 0.0, 0.0, 0.0, 0.0, 0, 0)
    assert codec.decoded == 3 and codec.bad_crc == codec.truncated == 0


def test_ground_speed_is_clamped_to_uint16() -> None:
    codec = SimCodec()
    data = codec.encode_sensors(1, (0.0,) * 6, 0.0, 0, (1, 0, 0, 0, -32768, -32768, 0), None)
    _, gps = codec.decode(data)
    assert isinstance(gps, HilGps) and gps.vel == 46341  # hypot fits uint16 for int16 inputs
    assert ground_speed(-32768, -32768) == 46341 and ground_speed(3, 4) == 5


def test_out_of_range_values_raise_and_use_no_sequence_number() -> None:
    codec = SimCodec()
    codec.seq = 7
    imu = (0.0,) * 6
    with pytest.raises(struct.error):
        codec.encode_sensors(-1, imu, 0.0, 0, None, None)
    with pytest.raises(struct.error):
        codec.encode_sensors(0, imu[:5], 0.0, 0, None, None)
    with pytest.raises(struct.error):
        codec.encode_sensors(0, imu, 0.0, 2**32, None, None)
    with pytest.raises(struct.error):  # the GPS frame fails after HIL_SENSOR packed
        codec.encode_sensors(0, imu, 0.0, 0, (0, 2**31, 0, 0, 0, 0, 0), None)
    with pytest.raises(struct.error):
        codec.encode_sensors(0, imu, 0.0, 0, (0, 0, 0, 0, 40000, 0, 0), None)
    with pytest.raises(OverflowError):  # the AHRS2 frame fails after the other two packed
        codec.encode_sensors(0, imu, 0.0, 0, (0,) * 7, (1e39, 0.0, 0.0))
    assert codec.seq == 7
    codec.encode_sensors(0, imu, 0.0, 0, (0,) * 7, (0.0,) * 3)
    assert codec.seq == 10


# -- (c) a corrupted byte costs only its own frame --------------------------------------
def _reference() -> tuple[bytes, list[bytes]]:
    codec = SimCodec(1, 51)
    codec.seq = 254  # the three frames straddle the sequence wrap
    data = codec.encode_sensors(
        12_345_678, (0.12, -0.34, -9.81, 0.015, -0.025, 0.035), 48.75, 0x1C3F,
        (12_340_000, 473_977_418, 85_455_939, 488_123, 150, -230, 12), (0.05, -0.1, 2.5),
    )  # fmt: skip
    frames, i = [], 0
    while i < len(data):
        n = 12 + data[i + 1]
        frames.append(data[i : i + n])
        i += n
    return data, frames


DATA, FRAMES = _reference()
REFERENCE = SimCodec().decode(DATA)
FAILURES = ("bad_crc", "truncated", "unknown", "unsupported", "garbage")
# header offsets whose corruption is not (always) a CRC failure: magic, length, incompat
# flags (the signed bit moves the frame end) and the message id (unknown, or another's CRC)
NOT_CRC_ONLY = {0, 1, 2, 7, 8, 9}


def test_reference_datagram() -> None:
    assert [type(m) for m in REFERENCE] == [HilSensor, HilGps, Ahrs2]
    assert [m.seq for m in REFERENCE] == [254, 255, 0]
    assert b"".join(FRAMES) == DATA


@settings(max_examples=N_EXAMPLES)
@given(st.integers(0, len(DATA) - 1), st.integers(1, 255))
def test_one_corrupted_byte_loses_one_frame(pos: int, xor: int) -> None:
    bad = bytearray(DATA)
    bad[pos] ^= xor
    codec = SimCodec()
    out = codec.decode(bytes(bad))
    k = next(j for j in range(len(FRAMES)) if pos < sum(len(f) for f in FRAMES[: j + 1]))
    assert out == REFERENCE[:k] + REFERENCE[k + 1 :]
    assert codec.decoded == len(FRAMES) - 1
    offset = pos - sum(len(f) for f in FRAMES[:k])
    if offset in NOT_CRC_ONLY:
        assert sum(getattr(codec, c) for c in FAILURES) >= 1
    else:  # sequence, ids, payload or the CRC itself: exactly one CRC failure
        assert codec.counters() == dict.fromkeys(codec.counters(), 0) | {"decoded": 2, "bad_crc": 1}


def test_corrupted_payload_byte_in_each_frame() -> None:
    for k, frame in enumerate(FRAMES):
        start = sum(len(f) for f in FRAMES[:k])
        bad = bytearray(DATA)
        bad[start + 10] ^= 0x01  # first payload byte
        codec = SimCodec()
        assert codec.decode(bytes(bad)) == REFERENCE[:k] + REFERENCE[k + 1 :]
        assert codec.bad_crc == 1 and codec.decoded == 2, frame
