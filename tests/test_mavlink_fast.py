"""heli_common.wire.mavlink.fast against pymavlink 2.4.50: same bytes, same values, robust decoding."""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest
from fastcrc import crc16
from hypothesis import assume, given
from hypothesis import strategies as st

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as m2

from heli_common import frames
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import EULER, N_STATE, VEL
from heli_common.wire.mavlink import fast as mavlink_fast
from heli_common.wire.mavlink import sim_protocol
from heli_common.wire.mavlink.fast import (
    Attitude,
    Decoded,
    HilActuatorControls,
    HilStateQuaternion,
    LocalPositionNed,
    SimCodec,
    hil_alt_vel,
)

U8 = st.integers(0, 255)
U64 = st.integers(0, 2**64 - 1)
I32 = st.integers(-(2**31), 2**31 - 1)
I16 = st.integers(-(2**15), 2**15 - 1)
U16 = st.integers(0, 2**16 - 1)
T_US = st.integers(0, 2**32 * 1000 - 1)  # time_boot_ms = t_us // 1000 must fit uint32
# float32 values (NaN and inf included) and doubles that round to a finite float32
F32 = st.one_of(st.floats(width=32), st.floats(-3.4e38, 3.4e38))


def f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def same(a: Any, b: Any) -> bool:
    """Field equality, NaN equal to NaN, arrays elementwise."""
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b) and type(a) is type(b)


def assert_same_message(ours: Decoded, theirs: Any) -> None:
    assert ours.get_type() == theirs.get_type()
    assert ours.msgid == theirs.get_msgId()
    assert (ours.sysid, ours.compid, ours.seq) == (
        theirs.get_srcSystem(),
        theirs.get_srcComponent(),
        theirs.get_seq(),
    )
    for name in theirs.get_fieldnames():
        assert same(getattr(ours, name), getattr(theirs, name)), name


def pm_parse(data: bytes) -> list[Any]:
    mav = m2.MAVLink(None)
    mav.robust_parsing = True
    return [m for m in (mav.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]


def pm_pack(msgs: Sequence[Any], sysid: int, compid: int, seq0: int) -> bytes:
    mav = m2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    out = b""
    for k, m in enumerate(msgs):
        mav.seq = (seq0 + k) & 0xFF
        out += m.pack(mav)
    return out


state_args = st.tuples(
    T_US,
    st.tuples(*[F32] * 6),  # roll, pitch, yaw, p, q, r
    st.tuples(*[F32] * 4),  # w, x, y, z
    I32,
    I32,
    I32,
    st.tuples(I16, I16, I16),
    st.tuples(F32, F32, F32),
    st.tuples(F32, F32, F32),
)


def state_reference(args: tuple[Any, ...]) -> list[Any]:
    t_us, att, quat, lat, lon, alt, vcm, pos, vel = args
    t_ms = t_us // 1000
    return [
        m2.MAVLink_hil_state_quaternion_message(
            t_us, quat, att[3], att[4], att[5], lat, lon, alt, *vcm, 0, 0, 0, 0, 0
        ),
        m2.MAVLink_attitude_message(t_ms, *att),
        m2.MAVLink_local_position_ned_message(t_ms, *pos, *vel),
    ]


# -- (1) + (3): our bytes are pymavlink's bytes and parse to the values given ------------
@given(state_args, U8, U8, U8)
def test_encode_state_matches_pymavlink(args: tuple[Any, ...], sysid: int, compid: int, seq: int) -> None:
    codec = SimCodec(sysid, compid)
    codec.seq = seq
    data = codec.encode_state(*args)
    assert codec.seq == (seq + 3) & 0xFF
    assert data == pm_pack(state_reference(args), sysid, compid, seq)
    parsed = pm_parse(data)
    assert [m.get_type() for m in parsed] == ["HIL_STATE_QUATERNION", "ATTITUDE", "LOCAL_POSITION_NED"]
    t_us, att, quat, lat, lon, alt, vcm, pos, vel = args
    hil, a, lpn = parsed
    assert hil.time_usec == t_us and a.time_boot_ms == lpn.time_boot_ms == t_us // 1000
    assert same(hil.attitude_quaternion, [f32(v) for v in quat])
    assert same([hil.rollspeed, hil.pitchspeed, hil.yawspeed], [f32(v) for v in att[3:]])
    assert (hil.lat, hil.lon, hil.alt, hil.vx, hil.vy, hil.vz) == (lat, lon, alt, *vcm)
    assert (hil.ind_airspeed, hil.true_airspeed, hil.xacc, hil.yacc, hil.zacc) == (0, 0, 0, 0, 0)
    assert same([a.roll, a.pitch, a.yaw, a.rollspeed, a.pitchspeed, a.yawspeed], [f32(v) for v in att])
    assert same([lpn.x, lpn.y, lpn.z, lpn.vx, lpn.vy, lpn.vz], [f32(v) for v in (*pos, *vel)])
    for k, m in enumerate(parsed):
        assert (m.get_srcSystem(), m.get_srcComponent(), m.get_seq()) == (sysid, compid, (seq + k) & 0xFF)


@given(U64, st.lists(F32, min_size=16, max_size=16), U8, U64, U8, U8, U8)
def test_encode_actuators_matches_pymavlink(
    t_us: int, controls: list[float], mode: int, flags: int, sysid: int, compid: int, seq: int
) -> None:
    codec = SimCodec(sysid, compid)
    codec.seq = seq
    data = codec.encode_actuators(t_us, controls, mode, flags)
    ref = m2.MAVLink_hil_actuator_controls_message(t_us, controls, mode, flags)
    assert data == pm_pack([ref], sysid, compid, seq)
    (m,) = pm_parse(data)
    assert (m.time_usec, m.mode, m.flags, m.get_seq()) == (t_us, mode, flags, seq)
    assert same(m.controls, [f32(v) for v in controls])
    (ours,) = codec.decode(data)
    assert_same_message(ours, m)


def test_sequence_wraps_per_instance() -> None:
    a, b = SimCodec(), SimCodec()
    a.seq = 254
    a.encode_state(1000, (0.0,) * 6, (1.0, 0.0, 0.0, 0.0), 0, 0, 0, (0, 0, 0), (0.0,) * 3, (0.0,) * 3)
    assert a.seq == 1 and b.seq == 0
    data = a.encode_actuators(5, [0.0] * 16, 0, 0)
    assert a.decode(data)[0].seq == 1 and a.seq == 2


# -- (2): pymavlink's bytes decode to pymavlink's values ---------------------------------
any_message = st.one_of(
    st.builds(
        m2.MAVLink_hil_state_quaternion_message,
        U64,
        st.lists(F32, min_size=4, max_size=4),
        F32,
        F32,
        F32,
        I32,
        I32,
        I32,
        I16,
        I16,
        I16,
        U16,
        U16,
        I16,
        I16,
        I16,
    ),
    st.builds(m2.MAVLink_attitude_message, st.integers(0, 2**32 - 1), F32, F32, F32, F32, F32, F32),
    st.builds(m2.MAVLink_local_position_ned_message, st.integers(0, 2**32 - 1), F32, F32, F32, F32, F32, F32),
    st.builds(
        m2.MAVLink_hil_actuator_controls_message, U64, st.lists(F32, min_size=16, max_size=16), U8, U64
    ),
)


@given(st.lists(any_message, min_size=1, max_size=5), U8, U8, U8)
def test_decode_pymavlink_packed(msgs: list[Any], sysid: int, compid: int, seq: int) -> None:
    data = pm_pack(msgs, sysid, compid, seq)
    codec = SimCodec()
    ours = codec.decode(data)
    theirs = pm_parse(data)
    assert len(ours) == len(theirs) == len(msgs)
    for o, t in zip(ours, theirs, strict=True):
        assert_same_message(o, t)
    assert codec.counters() == dict.fromkeys(codec.counters(), 0) | {"decoded": len(msgs)}
    # and re-encoding what we decoded gives the same bytes back
    again = b""
    enc = SimCodec(sysid, compid)
    enc.seq = seq
    for o in ours:
        if isinstance(o, HilActuatorControls):
            again += enc.encode_actuators(o.time_usec, o.controls, o.mode, o.flags)
        else:
            again += pm_pack([_to_pymavlink(o)], sysid, compid, enc.seq)
            enc.seq = (enc.seq + 1) & 0xFF
    assert again == data


def _to_pymavlink(o: Decoded) -> Any:
    if isinstance(o, HilStateQuaternion):
        return m2.MAVLink_hil_state_quaternion_message(*o[4:])
    if isinstance(o, Attitude):
        return m2.MAVLink_attitude_message(*o[4:])
    assert isinstance(o, LocalPositionNed)
    return m2.MAVLink_local_position_ned_message(*o[4:])


def test_result_types_and_field_order() -> None:
    codec = SimCodec(7, 9)
    data = codec.encode_state(
        2_500_123, (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), (1.0, 0.0, 0.0, 0.0), 1, 2, 3, (4, 5, 6), (7.0, 8.0, 9.0),
        (10.0, 11.0, 12.0),
    )  # fmt: skip
    hil, att, lpn = codec.decode(data)
    assert isinstance(hil, HilStateQuaternion) and hil.msgid == 115 and hil.sysid == 7 and hil.compid == 9
    assert hil.time_usec == 2_500_123 and hil.attitude_quaternion == (1.0, 0.0, 0.0, 0.0)
    assert (hil.lat, hil.lon, hil.alt, hil.vx, hil.vy, hil.vz) == (1, 2, 3, 4, 5, 6)
    assert isinstance(att, Attitude) and att.msgid == 30 and att.time_boot_ms == 2500
    assert att.yawspeed == f32(0.6)
    assert isinstance(lpn, LocalPositionNed) and lpn.msgid == 32 and (lpn.x, lpn.vz) == (7.0, 12.0)
    (act,) = codec.decode(codec.encode_actuators(3, [float(k) for k in range(16)], 129, 1))
    assert isinstance(act, HilActuatorControls) and act.msgid == 93
    assert act.controls == tuple(float(k) for k in range(16)) and (act.mode, act.flags) == (129, 1)


# -- the semantics of sim_protocol.state_messages ----------------------------------------
@given(
    st.integers(0, 10**12),
    st.lists(st.floats(-50.0, 50.0), min_size=N_STATE, max_size=N_STATE),
)
def test_same_bytes_as_state_messages(t_us: int, xs: list[float]) -> None:
    x = np.array(xs)
    pos_ned, _, euler_frd, omega_frd = frames.state_nwu_to_ned(x)
    rt = rot_body_to_earth(x[EULER][0], x[EULER][1], x[EULER][2])
    vel_ned = frames.nwu_to_ned(rt @ x[VEL])
    quat = frames.euler_to_quaternion(*euler_frd)
    alt_mm, vel_cm = hil_alt_vel(pos_ned, vel_ned)
    codec = SimCodec(1, 1)
    data = codec.encode_state(t_us, euler_frd + omega_frd, quat, 0, 0, alt_mm, vel_cm, pos_ned, vel_ned)
    assert data == pm_pack(sim_protocol.state_messages(t_us, x), 1, 1, 0)

    # and the StateAssembler, written for pymavlink messages, takes our results as they are
    ours, theirs = sim_protocol.StateAssembler(), sim_protocol.StateAssembler()
    a = b = None
    for o, t in zip(codec.decode(data), pm_parse(data), strict=True):
        a, b = ours.feed(o), theirs.feed(t)
    assert a is not None and b is not None
    assert a.t_us == b.t_us == t_us and np.array_equal(a.x, b.x)


def test_hil_alt_vel_clamps_like_state_messages() -> None:
    assert hil_alt_vel((0.0, 0.0, -1.2346), (400.0, -400.0, 0.004)) == (1235, (32767, -32768, 0))


# -- (4): corrupted, truncated and random datagrams --------------------------------------
def _three(seq: int = 0) -> tuple[bytes, list[bytes]]:
    codec = SimCodec(1, 1)
    codec.seq = seq
    frames_ = [
        codec.encode_state(
            1_234_567, (0.1, -0.2, 0.3, 0.01, 0.02, 0.03), (0.9, 0.1, 0.2, 0.3), 0, 0, 5000, (10, -20, 30),
            (1.0, 2.0, -5.0), (0.1, 0.2, 0.3),
        ),
        codec.encode_actuators(1_234_567, [0.5, -0.5, 0.25, -0.25] + [0.0] * 12, 128, 0),
    ]  # fmt: skip
    data = b"".join(frames_)
    # split the datagram into its four frames (each starts with 0xFD, length at byte 1)
    out, i = [], 0
    while i < len(data):
        n = 12 + data[i + 1]
        out.append(data[i : i + n])
        i += n
    return data, out


DATA, FRAMES = _three()
REFERENCE = SimCodec().decode(DATA)
FAILURES = ("bad_crc", "truncated", "unknown", "unsupported", "garbage")


def failures(codec: SimCodec) -> int:
    return sum(getattr(codec, k) for k in FAILURES)


def test_reference_datagram() -> None:
    assert len(FRAMES) == 4 and b"".join(FRAMES) == DATA
    assert [type(m) for m in REFERENCE] == [
        HilStateQuaternion,
        Attitude,
        LocalPositionNed,
        HilActuatorControls,
    ]


@given(st.binary(max_size=400))
def test_random_bytes_never_raise(data: bytes) -> None:
    codec = SimCodec()
    out = codec.decode(data)
    assert codec.decoded == len(out)
    if data and not out:
        assert failures(codec) >= 1


@given(st.binary(max_size=200), st.integers(0, len(DATA)), st.binary(max_size=200))
def test_random_bytes_around_and_inside(pre: bytes, cut: int, post: bytes) -> None:
    SimCodec().decode(pre + DATA[:cut] + post)  # never raises
    SimCodec().decode(bytearray(DATA[cut:] + pre))


@given(st.integers(0, len(DATA) - 1), st.integers(1, 255))
def test_one_corrupted_byte_loses_one_frame(pos: int, xor: int) -> None:
    bad = bytearray(DATA)
    bad[pos] ^= xor
    codec = SimCodec()
    out = codec.decode(bytes(bad))
    k = next(j for j in range(4) if pos < sum(len(f) for f in FRAMES[: j + 1]))
    assert out == REFERENCE[:k] + REFERENCE[k + 1 :]
    assert failures(codec) >= 1


@given(st.integers(0, len(DATA) - 1))
def test_split_across_datagram_end(cut: int) -> None:
    codec = SimCodec()
    out = codec.decode(DATA[:cut])
    whole = 0
    while whole < 4 and sum(len(f) for f in FRAMES[: whole + 1]) <= cut:
        whole += 1
    assert out == REFERENCE[:whole]
    at_boundary = cut == sum(len(f) for f in FRAMES[:whole])
    # the partial frame counts once, whatever 0xFD bytes its payload holds
    assert codec.counters() == dict.fromkeys(codec.counters(), 0) | {
        "decoded": whole,
        "truncated": 0 if at_boundary else 1,
    }


@given(st.binary(min_size=1, max_size=64), st.binary(min_size=1, max_size=64))
def test_garbage_before_and_after(pre: bytes, post: bytes) -> None:
    # garbage that holds no magic byte is one run on each side
    pre = pre.replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00")
    post = post.replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00")
    codec = SimCodec()
    assert codec.decode(pre + DATA + post) == REFERENCE
    assert (codec.garbage, failures(codec)) == (2, 2)


@given(st.binary(min_size=1, max_size=64))
def test_any_garbage_before_is_counted(pre: bytes) -> None:
    codec = SimCodec()
    out = codec.decode(pre + DATA)
    assume(out[-4:] == REFERENCE)  # a random prefix may (1 in 65536) hide a frame behind a good CRC
    assert failures(codec) >= 1


def test_wrong_crc() -> None:
    for k in range(4):
        bad = bytearray(DATA)
        end = sum(len(f) for f in FRAMES[: k + 1])
        bad[end - 1] ^= 0x40
        codec = SimCodec()
        assert codec.decode(bytes(bad)) == REFERENCE[:k] + REFERENCE[k + 1 :]
        assert codec.bad_crc == 1 and failures(codec) == 1


@pytest.mark.parametrize("delta", [-3, -1, 1, 2, 40])
def test_wrong_length(delta: int) -> None:
    for k in range(4):
        frames_ = [bytearray(f) for f in FRAMES]
        frames_[k][1] = (frames_[k][1] + delta) & 0xFF
        codec = SimCodec()
        out = codec.decode(b"".join(frames_))
        assert out == REFERENCE[:k] + REFERENCE[k + 1 :]
        assert codec.bad_crc + codec.truncated == 1


def test_unknown_message_is_skipped() -> None:
    hb = m2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(m2.MAVLink(None, 1, 1))
    codec = SimCodec()
    assert codec.decode(FRAMES[0] + hb + b"".join(FRAMES[1:])) == REFERENCE
    assert codec.unknown == 1 and failures(codec) == 1


def test_signed_frame_is_skipped_as_unsupported() -> None:
    mav = m2.MAVLink(None, 1, 1)
    mav.signing.secret_key = bytes(range(32))
    mav.signing.sign_outgoing = True
    mav.signing.link_id = 0
    mav.signing.timestamp = 1
    signed = m2.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(mav)
    assert signed[2] == 0x01
    codec = SimCodec()
    assert codec.decode(signed + DATA + signed) == REFERENCE
    assert codec.unsupported == 2 and failures(codec) == 2


def test_mavlink1_frame_is_skipped() -> None:
    v1 = m2.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6).pack(
        m2.MAVLink(None, 1, 1), force_mavlink1=True
    )
    assert v1[0] == 0xFE
    codec = SimCodec()
    assert codec.decode(v1 + DATA + v1) == REFERENCE
    assert codec.unsupported == 2 and failures(codec) == 2


def _frame(msgid: int, payload: bytes, extra: int, seq: int = 0) -> bytes:
    body = bytes((len(payload), 0, 0, seq, 1, 1, msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16)) + payload
    crc = mavlink_fast._crc16_py(body + bytes((extra,)))
    return b"\xfd" + body + struct.pack("<H", crc)


def test_longer_payload_and_empty_payload() -> None:
    # a newer dialect's extension fields after the known ones are ignored, as pymavlink does
    payload = struct.pack("<Iffffff", 7, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0) + b"\x01\x02\x03"
    longer = _frame(30, payload, 39)
    # an empty payload is a message of zeros (pymavlink sends at least one byte)
    empty = _frame(32, b"", 185, seq=1)
    codec = SimCodec()
    out = codec.decode(longer + empty)
    for o, t in zip(out, pm_parse(longer + empty), strict=True):
        assert_same_message(o, t)
    assert out[0] == Attitude(30, 1, 1, 0, 7, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert out[1] == LocalPositionNed(32, 1, 1, 1, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert failures(codec) == 0


def test_all_zero_message_keeps_one_payload_byte() -> None:
    data = SimCodec().encode_actuators(0, [0.0] * 16, 0, 0)
    assert data[1] == 1 and len(data) == 13
    assert data == pm_pack([m2.MAVLink_hil_actuator_controls_message(0, [0.0] * 16, 0, 0)], 1, 1, 0)
    (act,) = SimCodec().decode(data)
    assert isinstance(act, HilActuatorControls) and act.controls == (0.0,) * 16


# -- (5): NaN and inf pass through (the caller rejects them) ----------------------------
def test_nan_and_inf_decode_as_such() -> None:
    nan, inf = math.nan, math.inf
    codec = SimCodec()
    data = codec.encode_state(
        1000, (nan, inf, -inf, nan, 0.0, -0.0), (nan, 1.0, inf, -inf), 0, 0, 0, (0, 0, 0), (nan, inf, -inf),
        (-0.0, nan, inf),
    )  # fmt: skip
    hil, att, lpn = codec.decode(data)
    assert isinstance(hil, HilStateQuaternion) and isinstance(att, Attitude)
    assert isinstance(lpn, LocalPositionNed)
    assert math.isnan(att.roll) and att.pitch == inf and att.yaw == -inf and math.isnan(att.rollspeed)
    assert math.copysign(1.0, att.yawspeed) == -1.0
    assert math.isnan(hil.attitude_quaternion[0]) and hil.attitude_quaternion[2:] == (inf, -inf)
    assert math.isnan(lpn.x) and (lpn.y, lpn.z, lpn.vz) == (inf, -inf, inf) and math.isnan(lpn.vy)
    for o, t in zip(codec.decode(data), pm_parse(data), strict=True):
        assert_same_message(o, t)
    act = codec.encode_actuators(1, [nan, inf, -inf] + [0.0] * 13, 0, 0)
    (m,) = codec.decode(act)
    assert isinstance(m, HilActuatorControls)
    controls = m.controls
    assert math.isnan(controls[0]) and controls[1:3] == (inf, -inf)


def test_out_of_range_values_raise_like_pymavlink() -> None:
    codec = SimCodec()
    with pytest.raises(struct.error):
        codec.encode_actuators(-1, [0.0] * 16, 0, 0)
    with pytest.raises(struct.error):
        codec.encode_actuators(0, [0.0] * 15, 0, 0)
    with pytest.raises(OverflowError):
        codec.encode_actuators(0, [1e39] + [0.0] * 15, 0, 0)
    assert codec.seq == 0  # a failed encode uses no sequence number, as with pymavlink
    with pytest.raises(ValueError):
        SimCodec(256, 1)


# -- the CRC -----------------------------------------------------------------------------
@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_python_crc_matches_fastcrc(data: bytes, initial: int) -> None:
    fast = crc16.mcrf4xx
    assert mavlink_fast._crc16_py(data) == fast(data) == m2.x25crc(data).crc
    assert mavlink_fast._crc16_py(data, initial) == fast(data, initial)


def test_codec_with_python_crc(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mavlink_fast, "crc16_mcrf4xx", mavlink_fast._crc16_py)
    data, _ = _three()
    assert data == DATA
    assert SimCodec().decode(DATA) == REFERENCE


@given(
    st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ_0123456789", min_size=1, max_size=16),
    st.floats(width=32, allow_nan=False),
    st.integers(0, 255),
    st.integers(0, 255),
)
def test_param_set_decodes_as_pymavlink_packs_it(name: str, value: float, target: int, comp: int) -> None:
    """The world's live knobs travel as PARAM_SET on the sim link: pymavlink packs, the fast
    codec reads the same name, value and address (names of 16 characters have no NUL)."""
    mav = m2.MAVLink(None, srcSystem=1, srcComponent=1)
    data = m2.MAVLink_param_set_message(target, comp, name.encode(), value, 9).pack(mav)
    (got,) = SimCodec().decode(data)
    assert isinstance(got, mavlink_fast.ParamSet)
    assert (got.param_id, got.param_value, got.target_system, got.target_component, got.param_type) == (
        name, value, target, comp, 9)  # fmt: skip
