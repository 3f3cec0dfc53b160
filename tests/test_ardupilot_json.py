"""ArduPilot's JSON SITL backend: the wire format, the UDP endpoint, and the real firmware.

The firmware test runs ``arducopter-heli`` (../shared/ardupilot, see its README) and a
minimal physics peer inside a private network namespace that the test makes (the firmware
opens TCP 5760-5763 and sends to UDP 9002: never on the host's network).
"""

from __future__ import annotations

import json
import math
import os
import random
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from heli_common.frames import NF_POS, NF_QUAT, NF_RATES, NF_VEL, flu_to_frd, state_to_ned_fields
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import N_STATE, PHI, PSI, THETA, U_F, V_L, W_U, X_N, Y_W, Z_U
from heli_common.wire.ardupilot_json import (
    MAGIC_16,
    MAGIC_32,
    PACKET_BYTES,
    QUAT_NORM_TOL,
    Refusal,
    RefusalReason,
    ServoFrame,
    encode_servo_packet,
    json_state_from_plant,
    parse_servo_packet,
    state_json,
)
from heli_plant.ardupilot_link import ArduPilotJsonLink, port_for_instance

G = 9.80665
T = np.diag([1.0, -1.0, -1.0])  # NWU <-> NED, FLU <-> FRD
FIRMWARE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "ardupilot"
FIRMWARE = FIRMWARE_DIR / "arducopter-heli"
HOME = (-35.363261, 149.165230, 584.0, 90.0)  # lat, lon, alt [m], heading [deg]: facing east


def _pwm(n: int, base: int = 1000) -> list[int]:
    return [base + 17 * i for i in range(n)]


# =========================================================== servo frames (firmware -> us)
@pytest.mark.parametrize(("channels", "magic"), [(16, MAGIC_16), (32, MAGIC_32)])
def test_servo_packet_round_trip(channels: int, magic: int) -> None:
    data = encode_servo_packet(1200, 123456, _pwm(channels))
    assert len(data) == PACKET_BYTES[magic] == 8 + 2 * channels
    # the C struct's layout, byte for byte
    assert data == struct.pack(f"<HHI{channels}H", magic, 1200, 123456, *_pwm(channels))
    frame = parse_servo_packet(data)
    assert isinstance(frame, ServoFrame)
    assert (frame.magic, frame.frame_rate_hz, frame.frame_count) == (magic, 1200, 123456)
    assert frame.pwm_us == tuple(_pwm(channels)) and isinstance(frame.pwm_us, tuple)
    assert frame.channel(1) == 1000 and frame.channel(channels) == _pwm(channels)[-1]
    assert frame.dt_s == pytest.approx(1 / 1200)
    with pytest.raises(IndexError):
        frame.channel(channels + 1)
    with pytest.raises(AttributeError):
        frame.frame_count = 0  # type: ignore[misc]


def test_servo_packet_extremes_are_frames() -> None:
    """Every uint16/uint32 bit pattern is a number (no NaN exists here): the largest frame
    rate, frame count and PWMs are frames; only a 0 Hz frame rate is refused."""
    frame = parse_servo_packet(encode_servo_packet(65535, 2**32 - 1, [65535] * 16))
    assert isinstance(frame, ServoFrame)
    assert frame.frame_rate_hz == 65535 and frame.frame_count == 2**32 - 1
    assert parse_servo_packet(encode_servo_packet(1, 0, [0] * 32)) == ServoFrame(MAGIC_32, 1, 0, (0,) * 32)


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", RefusalReason.SHORT),
        (struct.pack("<HHI", MAGIC_16, 1200, 1)[:7], RefusalReason.SHORT),
        (encode_servo_packet(1200, 1, _pwm(16))[:-1], RefusalReason.SHORT),
        (encode_servo_packet(1200, 1, _pwm(32))[:40], RefusalReason.SHORT),  # 32-ch magic, 16 PWMs
        (encode_servo_packet(1200, 1, _pwm(16)) + b"\0", RefusalReason.OVERSIZED),
        (encode_servo_packet(1200, 1, _pwm(16)) + bytes(32), RefusalReason.OVERSIZED),  # 72 B, magic 16
        (encode_servo_packet(1200, 1, _pwm(32)) + b"\0\0", RefusalReason.OVERSIZED),
        (struct.pack("<HHI16H", 18459, 1200, 1, *_pwm(16)), RefusalReason.MAGIC),
        (struct.pack("<HHI16H", 0, 1200, 1, *_pwm(16)), RefusalReason.MAGIC),
        (struct.pack(">HHI16H", MAGIC_16, 1200, 1, *_pwm(16)), RefusalReason.MAGIC),  # big-endian
        (encode_servo_packet(0, 1, _pwm(16)), RefusalReason.FRAME_RATE),
        (encode_servo_packet(0, 1, _pwm(32)), RefusalReason.FRAME_RATE),
    ],
)
def test_servo_packet_refusals(data: bytes, reason: RefusalReason) -> None:
    out = parse_servo_packet(data)
    assert isinstance(out, Refusal), out
    assert out.reason is reason and out.detail


def test_encode_servo_packet_rejects_what_its_fields_cannot_hold() -> None:
    with pytest.raises(ValueError, match="16 or 32"):
        encode_servo_packet(1200, 0, _pwm(8))
    with pytest.raises(ValueError, match="out of range"):
        encode_servo_packet(1200, 2**32, _pwm(16))
    with pytest.raises(ValueError, match="out of range"):
        encode_servo_packet(1200, 0, [70000] * 16)


# ================================================================ state answers (us -> firmware)
def _firmware_scan(datagram: bytes) -> dict[str, Any]:
    """What ``JSON::recv_fdm`` + ``parse_sensors`` of the binary (sscanf build) take from one
    answer datagram: '\\n' -> NUL, the text between the last two NULs, then for each key
    ``strstr(section)``, ``strstr(key)``, step over ``key":`` and ``sscanf("[%f, %f, %f]")``
    (which needs '[' right there). Raises AssertionError where the firmware would fail."""
    buf = b"\0" + datagram.replace(b"\n", b"\0")  # the NUL recv_fdm keeps from the last line
    p2 = buf.rindex(b"\0")
    p1 = buf.rindex(b"\0", 0, p2)
    text = buf[p1 + 1 : p2].decode()
    keys = [("", "timestamp", 1, True), ("imu", "gyro", 3, True), ("imu", "accel_body", 3, True),
            ("", "position", 3, True), ("", "attitude", 3, False), ("", "quaternion", 4, False),
            ("", "velocity", 3, True), ("", "airspeed", 1, False),
            ("", "no_time_sync", 1, False)]  # fmt: skip
    out: dict[str, Any] = {}
    for section, key, n, required in keys:
        s = text.find(section)
        k = text.find(key, s + len(section) + 1) if s >= 0 else -1
        if k < 0:
            assert not required, f"Failed to find key {section}/{key}"
            continue
        p = text[k + len(key) + 2 :]
        if n == 1:
            m = re.match(r"\s*([-+0-9.eE]+|nan|inf)", p, re.I)  # atof
            assert m, f"atof finds no number for {key}"
            out[key] = float(m.group(1))
            continue
        assert p.startswith("["), f"Failed to parse Vector3f for {section}/{key}: {p[:12]!r}"
        # sscanf's ", " matches a comma followed by any (or no) white space
        m = re.match(r"\[" + r",\s*".join([r"([-+0-9.eEnaifNAIF]+)"] * n) + r"\]", p)
        assert m, f"Failed to parse Vector3f for {section}/{key}: {p[:40]!r}"
        out[key] = [float(v) for v in m.groups()]
    assert "attitude" in out or "quaternion" in out, "Did not receive attitude or quaternion"
    return out


def _level_state(z_u: float = 0.0, psi: float = 0.0) -> np.ndarray:
    x = np.zeros(N_STATE)
    x[Z_U], x[PSI] = z_u, psi
    return x


def test_state_json_is_compact_and_newline_framed() -> None:
    data = state_json(12.5, [0.1, -0.2, 0.3], [0.0, 0.0, -G], [1.0, 2.0, -3.0], [0.5, 0, 0], [1, 0, 0, 0])
    assert data.startswith(b"\n{") and data.endswith(b"}\n") and data.count(b"\n") == 2
    assert b" " not in data and b": " not in data and b", " not in data
    doc = json.loads(data)
    assert list(doc) == ["timestamp", "imu", "position", "velocity", "quaternion"]
    assert list(doc["imu"]) == ["gyro", "accel_body"]
    assert "no_time_sync" not in doc and "attitude" not in doc
    scanned = _firmware_scan(data)
    assert scanned["timestamp"] == 12.5
    assert scanned["position"] == [1.0, 2.0, -3.0]
    assert scanned["quaternion"] == [1.0, 0.0, 0.0, 0.0]
    assert np.float32(scanned["gyro"][0]) == np.float32(0.1)


def test_firmware_scan_rejects_a_space_after_a_colon() -> None:
    """The check above is meaningful: the default json.dumps (': ') fails the firmware."""
    doc = json.loads(state_json(1.0, [0, 0, 0], [0, 0, -G], [0, 0, 0], [0, 0, 0], [1, 0, 0, 0]))
    with pytest.raises(AssertionError, match="Failed to parse Vector3f"):
        _firmware_scan(b"\n" + json.dumps(doc).encode() + b"\n")


def test_state_json_is_exact_at_the_firmwares_precision() -> None:
    """Vector3f fields arrive as exactly np.float32(value) (strtof of the written text);
    the timestamp (atof) and the position (Vector3d, %lf) as exactly the double."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        v = rng.normal(0.0, 10.0, 3) * 10.0 ** rng.integers(-8, 6)
        t = float(rng.uniform(0, 1e5))
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        s = _firmware_scan(state_json(t, v, v, v, v, q))
        assert s["timestamp"] == t and s["position"] == list(v)
        for key in ("gyro", "accel_body", "velocity"):
            assert [np.float32(c) for c in s[key]] == list(v.astype(np.float32))
        assert np.float32(s["quaternion"]) == pytest.approx(q.astype(np.float32), abs=1e-7)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("field", ["timestamp", "gyro", "accel", "pos", "vel", "quat"])
def test_state_json_refuses_non_finite(field: str, bad: float) -> None:
    args: dict[str, Any] = {"timestamp_s": 1.0, "gyro": [0.0] * 3, "accel": [0, 0, -G], "pos": [0.0] * 3,
                            "vel": [0.0] * 3, "quat": [1.0, 0, 0, 0]}  # fmt: skip
    if field == "timestamp":
        args["timestamp_s"] = bad
    else:
        args[field] = list(args[field])
        args[field][1] = bad
    with pytest.raises(ValueError, match="not finite"):
        state_json(args["timestamp_s"], args["gyro"], args["accel"], args["pos"], args["vel"], args["quat"])


def test_state_json_refuses_what_the_firmware_cannot_take() -> None:
    ok = ([0.0] * 3, [0, 0, -G], [0.0] * 3, [0.0] * 3)
    with pytest.raises(ValueError, match="overflows a float32"):
        state_json(1.0, [1e39, 0, 0], *ok[1:], [1, 0, 0, 0])
    with pytest.raises(ValueError, match="norm"):
        state_json(1.0, *ok, [1, 1, 0, 0])
    with pytest.raises(ValueError, match="norm"):
        state_json(1.0, *ok, [0, 0, 0, 0])
    with pytest.raises(ValueError, match="3 components"):
        state_json(1.0, [0, 0], *ok[1:], [1, 0, 0, 0])
    with pytest.raises(ValueError, match="negative"):
        state_json(-1.0, *ok, [1, 0, 0, 0])
    q = json.loads(state_json(1.0, *ok, [1.0005, 0, 0, 0]))["quaternion"]  # rounding: renormalised
    assert q == [1.0, 0.0, 0.0, 0.0]
    x = _level_state()
    x[THETA] = math.nan
    with pytest.raises(ValueError, match="not finite"):
        json_state_from_plant(0.0, x, [0, 0, G])
    with pytest.raises(ValueError, match="not finite"):
        json_state_from_plant(0.0, _level_state(), [0, math.inf, G])
    with pytest.raises(ValueError, match="shape"):
        json_state_from_plant(0.0, np.zeros(11), [0, 0, G])


_F32 = struct.Struct("<f")


def _reference_state_json(t: float, *fields: Any) -> bytes:
    """The answer as state_json wrote it before its compiled rounding: plain floats, the
    quaternion normalised, the float32 fields rounded by struct (round-to-nearest-even),
    each number written as its repr. Raises OverflowError where a float32 cannot hold one."""
    gyro, accel, pos, vel, quat = ([float(c) for c in f] for f in fields)
    norm = math.sqrt(sum(c * c for c in quat))
    quat = [c / norm for c in quat]

    def f32(values: list[float]) -> list[float]:
        return [_F32.unpack(_F32.pack(c))[0] for c in values]

    gyro, accel, vel, quat = f32(gyro), f32(accel), f32(vel), f32(quat)
    return (
        f'\n{{"timestamp":{t!r},"imu":{{"gyro":[{",".join(map(repr, gyro))}],'
        f'"accel_body":[{",".join(map(repr, accel))}]}},"position":[{",".join(map(repr, pos))}],'
        f'"velocity":[{",".join(map(repr, vel))}],"quaternion":[{",".join(map(repr, quat))}]}}\n'
    ).encode("ascii")


def _random_vector(rng: np.random.Generator, n: int) -> np.ndarray:
    """Components over many decades (past both ends of float32's range), some exact zeros of
    either sign, some exactly halfway between two float32s (where round-to-nearest-even decides)."""
    v = rng.normal(size=n) * 10.0 ** rng.integers(-48, 40, n)  # float32: 1e-45 .. 3.4e38
    k = rng.integers(0, 8)
    if k == 0:
        v[rng.integers(0, n)] = rng.choice([0.0, -0.0])
    elif k == 1:  # a float32 plus half its ulp: a tie
        f = np.float32(rng.normal() * 100.0)
        v[rng.integers(0, n)] = float(f) + 0.5 * float(np.spacing(f))
    return v


def test_state_json_is_byte_identical_to_the_struct_rounding() -> None:
    rng = np.random.default_rng(23)
    for _ in range(3000):
        t = float(rng.uniform(0.0, 1e5))
        q = rng.normal(size=4)
        q *= (1.0 + rng.uniform(-0.9, 0.9) * QUAT_NORM_TOL) / np.linalg.norm(q)
        fields = [_random_vector(rng, 3) for _ in range(4)] + [q]
        try:
            want = _reference_state_json(t, *fields)
        except OverflowError:
            with pytest.raises(ValueError, match="overflows a float32"):
                state_json(t, *fields)
            continue
        assert state_json(t, *fields) == want
        assert state_json(t, *(f.tolist() for f in fields)) == want  # lists as arrays
    # the largest float32 is sent as itself; twice it is refused
    big = float(np.finfo(np.float32).max)
    edge = ([big, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0, 0])
    assert state_json(1.0, *edge) == _reference_state_json(1.0, *edge)
    with pytest.raises(ValueError, match="overflows a float32"):
        state_json(1.0, [0, 0, 0], [0, 0, 0], [0, 0, 0], [2.0 * big, 0, 0], [1, 0, 0, 0])


def test_plant_answer_equals_state_json_of_the_same_values() -> None:
    """json_state_from_plant's compiled path writes what state_json writes for the
    converted state, byte for byte."""
    rng = np.random.default_rng(29)
    for n in range(3000):
        x = _random_vector(rng, N_STATE)
        x[PHI : PSI + 1] = rng.uniform(-7.0, 7.0, 3)  # any angle: yaw wraps
        f_flu = _random_vector(rng, 3) if n % 2 else rng.normal(0.0, 20.0, 3)
        t = float(rng.uniform(0.0, 1e5))
        f = state_to_ned_fields(x)
        args = (f[NF_RATES : NF_RATES + 3], flu_to_frd(f_flu), f[NF_POS : NF_POS + 3], f[NF_VEL : NF_VEL + 3],
                f[NF_QUAT : NF_QUAT + 4])  # fmt: skip
        try:
            want = state_json(t, *args)
        except ValueError as exc:  # the same refusal, with the same message
            with pytest.raises(ValueError, match=re.escape(str(exc))):
                json_state_from_plant(t, x, f_flu)
            continue
        assert json_state_from_plant(t, x, f_flu) == want
        assert json_state_from_plant(t, x, tuple(f_flu)) == want


def test_plant_answer_refusals_say_why() -> None:
    x = _level_state()
    x[U_F] = 1e39  # a finite double no float32 holds
    with pytest.raises(ValueError, match="overflows a float32"):
        json_state_from_plant(1.0, x, [0, 0, G])
    with pytest.raises(ValueError, match="negative"):
        json_state_from_plant(-1.0, _level_state(), [0, 0, G])
    with pytest.raises(ValueError, match="plant state is not finite"):
        json_state_from_plant(1.0, np.full(N_STATE, math.inf), [0, 0, G])
    with pytest.raises(ValueError, match="specific force is not finite"):
        json_state_from_plant(1.0, _level_state(), [math.nan, 0, G])
    with pytest.raises(ValueError, match="3 components"):
        json_state_from_plant(1.0, _level_state(), [0, 0, G, 0])
    with pytest.raises(ValueError, match="not numbers"):
        json_state_from_plant("soon", _level_state(), [0, 0, G])  # type: ignore[arg-type]


def test_level_hover_gives_gravity_up_specific_force() -> None:
    """Level, at rest, 50 m up and heading 0.3 rad west of north: the accelerometer reads
    +g up in FLU, i.e. (0, 0, -g) in FRD; no rates; altitude 50 m is NED down -50 m."""
    doc = json.loads(json_state_from_plant(3.25, _level_state(50.0, 0.3), [0.0, 0.0, G]))
    assert doc["timestamp"] == 3.25
    assert doc["imu"]["accel_body"] == pytest.approx([0.0, 0.0, -G], abs=1e-6)
    assert doc["imu"]["gyro"] == [0.0, 0.0, 0.0]
    assert doc["position"] == pytest.approx([0.0, 0.0, -50.0])
    assert doc["velocity"] == [0.0, 0.0, 0.0]
    # heading 0.3 rad west of north = NED yaw -0.3: q = (cos 0.15, 0, 0, -sin 0.15)
    assert doc["quaternion"] == pytest.approx([math.cos(0.15), 0, 0, -math.sin(0.15)], abs=1e-7)


def test_ned_position_and_velocity_signs() -> None:
    x = _level_state()
    x[X_N], x[Y_W], x[Z_U] = 1.0, 2.0, 3.0  # 1 m north, 2 m west, 3 m up
    x[U_F], x[V_L], x[W_U] = 4.0, 5.0, 6.0  # heading north: forward = north, left = west
    doc = json.loads(json_state_from_plant(0.0, x, [0, 0, G]))
    assert doc["position"] == pytest.approx([1.0, -2.0, -3.0])
    assert doc["velocity"] == pytest.approx([4.0, -5.0, -6.0])
    x[PSI] = math.pi / 2  # nose to the west (NWU yaw is counter-clockwise seen from above)
    x[U_F], x[V_L], x[W_U] = 1.0, 0.0, 0.0
    doc = json.loads(json_state_from_plant(0.0, x, [0, 0, G]))
    assert doc["velocity"] == pytest.approx([0.0, -1.0, 0.0], abs=1e-7)  # moving west: east -1


@pytest.mark.parametrize(
    ("euler_nwu", "quat_ned"),
    [
        ((0.0, 0.0, -math.pi / 2), (math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4))),  # facing east
        ((0.3, 0.0, 0.0), (math.cos(0.15), math.sin(0.15), 0, 0)),  # right side down: roll +0.3
        ((0.0, 0.2, 0.0), (math.cos(0.1), 0, -math.sin(0.1), 0)),  # FLU pitch +0.2 = nose down
    ],
)
def test_quaternion_of_known_attitudes(
    euler_nwu: tuple[float, float, float], quat_ned: tuple[float, ...]
) -> None:
    x = _level_state()
    x[PHI], x[THETA], x[PSI] = euler_nwu
    doc = json.loads(json_state_from_plant(0.0, x, [0, 0, G]))
    assert doc["quaternion"] == pytest.approx(quat_ned, abs=1e-7)


def _dcm(q: list[float]) -> np.ndarray:
    """ArduPilot's Quaternion::rotation_matrix (q1..q4 = w, x, y, z): body -> earth."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def test_frames_agree_with_the_plants_rotation() -> None:
    """For random states: the quaternion's DCM is T R T (R the plant's FLU -> NWU), the NED
    velocity is T R v_FLU, and a static vehicle's specific force is R^T g_up, flipped."""
    rng = np.random.default_rng(11)
    for _ in range(50):
        x = rng.normal(size=N_STATE)
        x[THETA] = rng.uniform(-1.4, 1.4)
        r = rot_body_to_earth(x[PHI], x[THETA], x[PSI])
        f_flu = r.T @ np.array([0.0, 0.0, G])
        doc = json.loads(json_state_from_plant(1.0, x, f_flu))
        np.testing.assert_allclose(_dcm(doc["quaternion"]), T @ r @ T, atol=1e-6)
        np.testing.assert_allclose(doc["velocity"], T @ r @ x[U_F : W_U + 1], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(doc["position"], T @ x[X_N : Z_U + 1])
        np.testing.assert_allclose(doc["imu"]["gyro"], T @ x[9:12], rtol=1e-6)
        # specific force in FRD seen in NED is gravity-up: (0, 0, -g)
        np.testing.assert_allclose(_dcm(doc["quaternion"]) @ doc["imu"]["accel_body"], [0, 0, -G], atol=1e-5)


# ============================================================ the endpoint, with a fake firmware
class FakeFirmware:
    """A socket standing in for the firmware: sends servo frames, receives answers."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(1.0)
        self.target = ("127.0.0.1", port)

    @property
    def addr(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()
        return (host, port)

    def send(self, frame_count: int, data: bytes | None = None) -> None:
        if data is None:
            data = encode_servo_packet(1200, frame_count, _pwm(16))
        self.sock.sendto(data, self.target)

    def recv(self, timeout_s: float = 1.0) -> bytes | None:
        self.sock.settimeout(timeout_s)
        try:
            return self.sock.recv(65535)
        except TimeoutError:
            return None

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def link_and_fw() -> Any:
    with ArduPilotJsonLink(0) as link:  # port 0: the OS picks a free one
        fw = FakeFirmware(link.port)
        try:
            yield link, fw
        finally:
            fw.close()


def _answer(t: float) -> bytes:
    return json_state_from_plant(t, _level_state(), [0, 0, G])


def test_link_ports_and_loopback() -> None:
    assert port_for_instance(0) == 9002 and port_for_instance(3) == 9032
    with pytest.raises(ValueError):
        port_for_instance(-1)
    with ArduPilotJsonLink(0) as link:
        assert link.local[0] == "127.0.0.1" and link.port > 0 and link.peer is None
        with pytest.raises(RuntimeError, match="no servo frame"):
            link.answer(_answer(0.0))
        assert link.poll(0.0) is None


def test_link_new_frames_and_answers(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    for k in range(5):
        fw.send(k)
        frame = link.poll(1.0)
        assert frame is not None and frame.frame_count == k and not link.last_frame_was_reset
        assert link.peer == fw.addr
        link.answer(_answer(k / 1200))
        assert fw.recv() == _answer(k / 1200)
    c = link.counters
    assert (c.frames, c.answers, c.datagrams, c.resets, c.skipped, c.superseded) == (5, 5, 5, 0, 0, 0)
    with pytest.raises(ValueError, match="newline"):
        link.answer(b'{"timestamp":1}')


def test_link_answers_a_resend_with_the_last_answer_without_a_new_frame(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    fw.send(7)
    assert link.poll(1.0) is not None
    link.answer(_answer(1.0))
    assert fw.recv() == _answer(1.0)
    for n in range(1, 3):  # the firmware heard nothing: it re-sends frame 7
        fw.send(7)
        assert link.poll(1.0) is None
        assert fw.recv() == _answer(1.0)  # the same answer again, nothing stepped
        assert link.counters.resends_answered == n
    assert link.counters.frames == 1 and link.counters.answers == 3


def test_link_resend_before_the_answer_sends_nothing(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    fw.send(0)
    assert link.poll(1.0) is not None
    link.answer(_answer(0.0))
    assert fw.recv() is not None
    fw.send(1)
    assert link.poll(1.0) is not None  # the caller is still computing frame 1's answer...
    fw.send(1)
    assert link.poll(1.0) is None  # ...when the re-send arrives: frame 0's answer must not go
    assert fw.recv(0.2) is None
    assert link.counters.resends_unanswered == 1
    link.answer(_answer(1 / 1200))
    assert fw.recv() == _answer(1 / 1200)


def test_link_flags_a_reset(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    for k in range(3):
        fw.send(k)
        assert link.poll(1.0) is not None
        link.answer(_answer(k))
        fw.recv()
    fw.send(0)  # frame_count went back: the firmware restarted (same address here)
    frame = link.poll(1.0)
    assert frame is not None and frame.frame_count == 0 and link.last_frame_was_reset
    assert link.counters.resets == 1
    fw.send(0)  # a re-send in the new session: nothing answered yet, nothing re-sent
    assert link.poll(1.0) is None and fw.recv(0.2) is None
    link.answer(_answer(0.0))
    assert fw.recv() == _answer(0.0)
    fw.send(1)
    assert link.poll(1.0) is not None and not link.last_frame_was_reset
    # a new firmware process: a new socket, so a new address, even with a larger count
    fw2 = FakeFirmware(link.port)
    try:
        fw2.send(5)
        frame = link.poll(1.0)
        assert frame is not None and link.last_frame_was_reset and link.peer == fw2.addr
        link.answer(_answer(0.0))
        assert fw2.recv() == _answer(0.0) and fw.recv(0.1) is None
    finally:
        fw2.close()
    assert link.counters.resets == 2


def test_link_keeps_the_newest_of_queued_frames_and_counts_gaps(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    fw.send(10)
    assert link.poll(1.0) is not None
    fw.send(11)
    fw.send(11)  # a duplicate of a frame not returned yet: merged
    fw.send(12)
    time.sleep(0.05)  # all three queued
    frame = link.poll(1.0)
    assert frame is not None and frame.frame_count == 12
    assert link.counters.superseded == 1 and link.counters.skipped == 0
    fw.send(15)
    frame = link.poll(1.0)
    assert frame is not None and frame.frame_count == 15 and link.counters.skipped == 2
    fw.send(2**32 - 2)  # 17 back modulo 2^32: backwards, a reset
    assert link.poll(1.0) is not None and link.last_frame_was_reset and link.counters.resets == 1
    for k in (2**32 - 1, 0, 1):  # the uint32 wraps: forward, no reset, no gap
        fw.send(k)
        frame = link.poll(1.0)
        assert frame is not None and frame.frame_count == k and not link.last_frame_was_reset
    assert link.counters.resets == 1 and link.counters.skipped == 2


def _fuzz(rng: random.Random) -> bytes:
    kind = rng.randrange(6)
    good = encode_servo_packet(rng.randrange(1, 65536), rng.randrange(2**32),
                               [rng.randrange(65536) for _ in range(rng.choice((16, 32)))])  # fmt: skip
    if kind == 0:
        return rng.randbytes(rng.randrange(0, 120))
    if kind == 1:
        return good[: rng.randrange(len(good))]
    if kind == 2:
        return struct.pack("<H", rng.choice([0, 1, 18457, 18459, 29568, 29570, 65535])) + good[2:]
    if kind == 3:
        return good + rng.randbytes(rng.choice([1, 2, 32, 500, 9000]))
    if kind == 4:
        return good[:2] + b"\0\0" + good[4:]  # frame rate 0
    return rng.randbytes(len(good))  # the right size, random content


def test_link_survives_1000_fuzzed_datagrams(link_and_fw: Any) -> None:
    link, fw = link_and_fw
    rng = random.Random(2024)
    sent = [_fuzz(rng) for _ in range(1000)]
    expected: dict[str, int] = {r.value: 0 for r in RefusalReason}
    valid = 0
    for d in sent:
        out = parse_servo_packet(d)
        if isinstance(out, Refusal):
            expected[out.reason.value] += 1
        else:
            valid += 1
    assert all(expected.values()), expected  # every reason exercised
    deadline = time.monotonic() + 20.0
    for i in range(0, len(sent), 50):  # in batches: never more than the socket buffer holds
        for d in sent[i : i + 50]:
            fw.send(0, d)
        while link.counters.datagrams < i + 50 and time.monotonic() < deadline:
            link.poll(0.2)  # never raises
    c = link.counters
    assert c.datagrams == 1000
    r = c.refused
    assert (r.short, r.oversized, r.magic, r.frame_rate) == (
        expected["short"], expected["oversized"], expected["magic"], expected["frame_rate"])  # fmt: skip
    assert r.total == 1000 - valid
    # the link still works after it
    fw2 = FakeFirmware(link.port)
    try:
        fw2.send(1)
        frame = link.poll(1.0)
        assert frame is not None and frame.frame_count == 1 and link.peer == fw2.addr
    finally:
        fw2.close()


# ========================================================================== the real firmware
def _unshare_cmd() -> list[str] | str:
    """The unshare command that makes a private network namespace here, or why none can."""
    if not sys.platform.startswith("linux"):
        return "network namespaces are Linux-only"
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs unshare (util-linux) and ip (iproute2)"
    errors = []
    for cmd in (["unshare", "--net"], ["unshare", "--net", "--map-root-user"]):
        probe = subprocess.run([*cmd, "ip", "link", "set", "lo", "up"], capture_output=True, timeout=10)
        if probe.returncode == 0:
            return cmd
        errors.append(f"{' '.join(cmd)}: {probe.stderr.decode().strip()}")
    return "cannot make a network namespace (" + "; ".join(errors) + ")"


def _start_firmware(work: Path, speedup: int) -> subprocess.Popen[bytes]:
    lat, lon, alt, hdg = HOME
    return subprocess.Popen(
        [str(FIRMWARE), "-w", "--model", "JSON", "--speedup", str(speedup),
         "--defaults", str(FIRMWARE_DIR / "copter-heli.parm"), "-I0",
         "--home", f"{lat},{lon},{alt},{hdg}",
         # SERIAL0's default is tcp:0:wait: no servo frame before a MAVLink client connects.
         # Without :wait the physics runs whether or not the MAVLink check below connects.
         "--serial0", "tcp:0"],
        cwd=work, stdout=(work / "firmware.log").open("ab"), stderr=subprocess.STDOUT,
    )  # fmt: skip


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL: the firmware blocked in recv_fdm does not act on SIGTERM."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5.0)


def _mavlink_watch(out: dict[str, Any], stop: threading.Event, clock: list[float]) -> None:
    """HEARTBEAT and the firmware's truth (SIMSTATE) and clock (SYSTEM_TIME) from TCP 5760."""
    from pymavlink import mavutil

    conn = None
    end = time.monotonic() + 10.0
    while conn is None and time.monotonic() < end and not stop.is_set():
        try:
            conn = mavutil.mavlink_connection("tcp:127.0.0.1:5760", autoreconnect=False)
        except OSError:
            time.sleep(0.2)
    if conn is None:
        out["mavlink_error"] = "no connection to TCP 5760"
        return
    try:
        while not stop.is_set():
            msg = conn.recv_match(blocking=True, timeout=0.5)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "HEARTBEAT" and "heartbeat" not in out:
                out["heartbeat"] = [msg.type, msg.autopilot]
                conn.mav.request_data_stream_send(msg.get_srcSystem(), msg.get_srcComponent(), 0, 10, 1)
            elif kind == "SIMSTATE":
                out["simstate"] = [msg.roll, msg.pitch, msg.yaw, msg.xacc, msg.yacc, msg.zacc,
                                   msg.lat, msg.lng]  # fmt: skip
            elif kind == "SYSTEM_TIME":
                out["clock"] = [msg.time_boot_ms / 1000.0, clock[0]]  # firmware's, ours when read
            elif kind == "SERVO_OUTPUT_RAW":
                out["servo_raw"] = [msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw,
                                    msg.servo8_raw]  # fmt: skip
    finally:
        conn.close()


def _peer(link: ArduPilotJsonLink, x: np.ndarray, f_flu: np.ndarray, until: float,
          t_prev: float | None, n_frames: int, clock: list[float], log: dict[str, Any]) -> float:  # fmt: skip
    """Answer frames as a vehicle at rest (x, specific force f_flu) until ``n_frames`` are
    answered or the wall clock passes ``until``. Physics time is ``t_prev`` (the last answer's)
    plus one step a frame, and 0 at the first frame of a session. Returns the last time sent."""
    t = 0.0 if t_prev is None else t_prev
    counts: list[int] = log.setdefault("counts", [])
    while len(counts) < n_frames and time.monotonic() < until:
        frame = link.poll(0.5)
        if frame is None:
            continue
        if link.last_frame_was_reset or t_prev is None:
            t = 0.0
            log.setdefault("first_frame", [frame.frame_count, frame.frame_rate_hz, list(frame.pwm_us)])
            log.setdefault("t_first_wall", time.monotonic())
        else:
            t += frame.dt_s
        t_prev = t
        counts.append(frame.frame_count)
        log.setdefault("rates", set()).add(frame.frame_rate_hz)
        clock[0] = t
        link.answer(json_state_from_plant(t, x, f_flu))
    log["t_last_wall"] = time.monotonic()
    return t


def _firmware_namespace_main(work: Path, parent_netns: str, speedup: int) -> int:
    """Inside the private namespace: firmware + minimal physics peer; results to result.json."""
    if os.readlink("/proc/self/ns/net") == parent_netns:
        print("refusing: not inside a private network namespace", file=sys.stderr)
        return 3
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    res: dict[str, Any] = {}
    # level, at rest at home, facing east (NED yaw +90 deg = NWU psi -90 deg)
    x = _level_state(0.0, -math.radians(HOME[3]))
    f_flu = np.array([0.0, 0.0, G])
    json_state_from_plant(0.0, x, f_flu)  # compile the conversion before the firmware waits on it
    with ArduPilotJsonLink(port_for_instance(0)) as link:
        fw = _start_firmware(work, speedup)
        stop = threading.Event()
        clock = [0.0]
        mav: dict[str, Any] = {}
        watcher = threading.Thread(target=_mavlink_watch, args=(mav, stop, clock), daemon=True)
        try:
            watcher.start()
            run: dict[str, Any] = {}
            # 1. lockstep at rest: 6000 frames (5 s of physics at 1200 Hz)
            t = _peer(link, x, f_flu, time.monotonic() + 30.0, None, 6000, clock, run)
            res["run"] = {k: (sorted(v) if isinstance(v, set) else v) for k, v in run.items()}
            res["run_counters"] = {k: v for k, v in vars(link.counters).items() if k != "refused"}
            # 2. hold one frame unanswered: the firmware re-sends it after ~1 s
            frame = None
            while frame is None and fw.poll() is None:
                frame = link.poll(1.0)
            assert frame is not None
            held = time.monotonic()
            while link.counters.resends_unanswered == 0 and time.monotonic() - held < 5.0:
                assert link.poll(0.5) is None, "a new frame while one was unanswered"
            res["resend_after_s"] = time.monotonic() - held if link.counters.resends_unanswered else None
            res["held_frame"] = frame.frame_count
            link.answer(json_state_from_plant(t + frame.dt_s, x, f_flu))
            after: dict[str, Any] = {}
            _peer(link, x, f_flu, time.monotonic() + 10.0, t + frame.dt_s, 200, clock, after)
            res["after_resend"] = after["counts"][:3]
            time.sleep(1.0)  # the MAVLink streams (10 Hz) report the clock after the run
            stop.set()
            watcher.join(5.0)
            res["mavlink"] = mav
            # 3. a new firmware process: frame_count from 0, from a new socket: a reset
            _stop(fw)
            while link.poll(0.1) is not None:  # the old process's last frames, never answered
                pass
            resets_before = link.counters.resets
            fw = _start_firmware(work, speedup)
            again: dict[str, Any] = {}
            _peer(link, x, f_flu, time.monotonic() + 30.0, t, 1200, clock, again)
            res["restart"] = {"counts": again["counts"][:3] + again["counts"][-1:],
                              "resets": link.counters.resets - resets_before}  # fmt: skip
        finally:
            stop.set()
            _stop(fw)
            res["counters"] = {k: v for k, v in vars(link.counters).items() if k != "refused"}
            res["refused"] = vars(link.counters.refused)
            (work / "result.json").write_text(json.dumps(res))
    return 0


@pytest.mark.netns
@pytest.mark.slow
def test_real_arducopter_heli_steps_in_lockstep(tmp_path: Path) -> None:
    """ArduPilot's own helicopter firmware against a minimal peer (a vehicle at rest at
    home): its frames come at the rate it claims, it steps once per answer, its clock is
    our physics time, it re-sends a frame after ~1 s unanswered, a restart is a reset, it
    is a helicopter (HEARTBEAT type 4), and its truth (SIMSTATE) is the state we sent."""
    if not FIRMWARE.exists():
        pytest.skip(f"no ArduPilot SITL binary at {FIRMWARE} (see shared/ardupilot/README.md)")
    cmd = _unshare_cmd()
    if isinstance(cmd, str):
        pytest.skip(cmd)
    speedup = 5
    me = str(Path(__file__).resolve())
    parent_netns = os.readlink("/proc/self/ns/net")
    proc = subprocess.Popen(
        [*cmd, "--", sys.executable, me, "firmware-ns", str(tmp_path), parent_netns, str(speedup)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    try:
        output, _ = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the namespace's processes: peer and firmware
        output, _ = proc.communicate()
        pytest.fail(f"firmware test timed out:\n{output.decode(errors='replace')[-3000:]}")
    fw_log = tmp_path / "firmware.log"
    log = fw_log.read_text(errors="replace") if fw_log.exists() else ""
    assert proc.returncode == 0, output.decode(errors="replace")[-3000:] + "\n" + log[-2000:]
    res = json.loads((tmp_path / "result.json").read_text())
    run = res["run"]

    # frames: 1200 Hz claimed, from 0, one per answer, none skipped or repeated
    assert run["rates"] == [1200]
    assert run["first_frame"][0] == 0
    assert run["counts"] == list(range(6000))
    # (the firmware paces itself to --speedup on the wall clock: its own feature, not ours, and
    # a speed; printed, not asserted: 6000 frames within _peer's 30 s bound is "it runs")
    wall_rate = (len(run["counts"]) - 1) / (run["t_last_wall"] - run["t_first_wall"])
    print(f"\nframes per wall second {wall_rate:.0f} at --speedup {speedup} ({speedup * 1200} nominal)")
    c = res["run_counters"]
    assert c["skipped"] == 0 and c["superseded"] == 0 and c["tx_errors"] == 0
    assert sum(res["refused"].values()) == 0
    # the firmware's parser took every answer: no complaint in its log
    assert "Failed to parse" not in log and "mandatory" not in log and "Detected physics reset" not in log
    assert "JSON received:" in log

    # an unanswered frame is re-sent (ArduPilot's ~1 s wall-clock timer: within the 5 s the peer
    # waits), with the same count and no new frame meanwhile; then it goes on
    assert res["resend_after_s"] is not None, "no re-send within 5 s"
    print(f"re-sent after {res['resend_after_s']:.2f} s")
    assert "No JSON sensor message received, resending servos" in log
    held = res["held_frame"]
    assert res["after_resend"] == [held + 1, held + 2, held + 3]

    # a new firmware process: frames from 0 again, flagged as a reset
    assert res["restart"]["resets"] == 1
    assert res["restart"]["counts"][:3] == [0, 1, 2]

    mav = res["mavlink"]
    if "mavlink_error" in mav:
        pytest.skip(f"physics checked; MAVLink not: {mav['mavlink_error']}")
    assert mav["heartbeat"] == [4, 3]  # MAV_TYPE_HELICOPTER, MAV_AUTOPILOT_ARDUPILOTMEGA
    # the firmware's ground truth is what we sent: level, facing east, at home, 1 g up
    roll, pitch, yaw, ax, ay, az, lat, lng = mav["simstate"]
    assert abs(roll) < 1e-4 and abs(pitch) < 1e-4 and yaw == pytest.approx(math.pi / 2, abs=1e-4)
    assert [ax, ay, az] == pytest.approx([0.0, 0.0, -G], abs=1e-3)
    assert lat == pytest.approx(HOME[0] * 1e7, abs=2) and lng == pytest.approx(HOME[1] * 1e7, abs=2)
    # lockstep: its clock is our physics time (both read within one 10 Hz stream period)
    fw_s, ours_s = mav["clock"]
    assert fw_s == pytest.approx(ours_s, abs=0.25), mav["clock"]
    # at rest, rotor off: swash near mid, tail 1500 us, HeliRSC (SERVO8) at 1000 us
    assert mav["servo_raw"][3] == 1500 and mav["servo_raw"][4] == 1000


if __name__ == "__main__":  # the firmware test's namespace side, run by the test in a child
    role = sys.argv[1]
    if role == "firmware-ns":
        sys.exit(_firmware_namespace_main(Path(sys.argv[2]), sys.argv[3], int(sys.argv[4])))
    sys.exit(f"unknown role {role}")
