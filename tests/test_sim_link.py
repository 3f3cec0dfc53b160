"""The sim link's messages, the UDP link's robustness, and the runner's tick semantics."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from autopilot.flight.commands import Arm, FlyTrajectory
from autopilot.flight.manager import FlightConfig, FlightManager
from autopilot.links.mavlink_sim import SimLink
from autopilot.runner import Runner, RunnerConfig
from autopilot.scenario import Scenario
from autopilot.tlc.controller import S_I1, S_I4, TLController
from autopilot.trajectory.analytic import StraightLine
from heli_common.geo import GeoPoint
from heli_common.vehicle.airframe import Airframe
from heli_common.wire import servo_map
from heli_common.wire.mavlink.sim_protocol import (
    StateAssembler,
    StateSample,
    command_message,
    decode_command,
    state_messages,
)
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp, PortBusyError, mavlink2

LIMITS = servo_map.limits_array(Airframe.load().limits.as_tuple())
angles = st.floats(-1.2, 1.2)
small = st.floats(-20.0, 20.0)


def _roundtrip_state(t_us: int, x: np.ndarray) -> np.ndarray:
    tx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=51)
    rx = mavlink2.MAVLink(None)
    data = b"".join(bytes(m.pack(tx)) for m in state_messages(t_us, x))
    asm = StateAssembler()
    out = None
    for m in rx.parse_buffer(data) or []:
        s = asm.feed(m)
        if s is not None:
            out = s
    assert out is not None and out.t_us == t_us
    return out.x


@settings(max_examples=60)
@given(
    pos=st.tuples(small, small, st.floats(0.0, 50.0)),
    vel=st.tuples(small, small, small),
    eul=st.tuples(angles, angles, st.floats(-3.1, 3.1)),
    om=st.tuples(small, small, small),
)
def test_state_survives_the_sim_link(pos, vel, eul, om) -> None:  # type: ignore[no-untyped-def]
    x = np.array([*pos, *vel, *eul, *om])
    y = _roundtrip_state(123_456_789, x)
    # float32 on the wire; body velocity goes through the earth frame and back
    assert_allclose(y[0:3], x[0:3], atol=1e-5 * (1 + np.abs(x[0:3]).max()))
    assert_allclose(y[3:6], x[3:6], atol=2e-5 * (1 + np.abs(x[3:6]).max()))
    assert_allclose(y[6:12], x[6:12], atol=2e-6 * (1 + np.abs(x[9:12]).max()))


@settings(max_examples=100)
@given(st.tuples(*(st.floats(lo, hi) for lo, hi in LIMITS)))
def test_pitches_survive_normalisation(pitches) -> None:  # type: ignore[no-untyped-def]
    u = np.array(pitches)
    n = servo_map.to_normalized(u, LIMITS)
    assert np.all(np.abs(n) <= 1 + 1e-12)
    msg = command_message(42, u, LIMITS, armed=True)
    rx = mavlink2.MAVLink(None)
    [parsed] = rx.parse_buffer(bytes(msg.pack(mavlink2.MAVLink(None, 1, 1))))
    decoded = decode_command(parsed, LIMITS)
    assert decoded is not None and decoded[0] == 42
    assert_allclose(decoded[1], u, atol=1e-6)
    assert parsed.mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED


def test_normalisation_maps_the_limits_to_plus_minus_one() -> None:
    lo, hi = LIMITS[:, 0], LIMITS[:, 1]
    assert_allclose(servo_map.to_normalized(lo, LIMITS), -1.0)
    assert_allclose(servo_map.to_normalized(hi, LIMITS), 1.0)
    assert_allclose(servo_map.to_pwm_us(hi, LIMITS), 2000.0)
    assert_allclose(servo_map.to_pwm_us(lo, LIMITS), 1000.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf, 1.5, -1.01])
def test_bad_command_values_are_refused(bad: float) -> None:
    msg = command_message(1, np.zeros(4), LIMITS, armed=True)
    msg.controls = list(msg.controls)
    msg.controls[2] = bad
    assert decode_command(msg, LIMITS) is None


def test_out_of_order_state_is_dropped_and_a_repeat_is_answered() -> None:
    asm = StateAssembler()
    x = np.zeros(12)
    for t_us in (20_000, 20_000, 10_000):
        for m in state_messages(t_us, x):
            s = asm.feed(m)
    assert asm.out_of_order == 1 and asm.last_t_us == 20_000
    assert s is None


def _feed(asm: StateAssembler, t_us: int, x: np.ndarray) -> StateSample | None:
    out = None
    for m in state_messages(t_us, x):
        out = asm.feed(m)
    return out


def test_one_far_future_state_cannot_capture_the_timeline() -> None:
    """A single valid-CRC state stamped 2**62 us (and one holding 1e30 m) is refused and
    counted; the plant's real states go on being accepted."""
    asm = StateAssembler()
    x = np.zeros(12)
    assert _feed(asm, 10_000, x) is not None
    assert _feed(asm, 2**62, x) is None
    huge = x.copy()
    huge[0] = 1e30
    assert _feed(asm, 20_000, huge) is None
    for t_us in range(20_000, 100_000, 10_000):
        s = _feed(asm, t_us, x)
        assert s is not None and s.t_us == t_us and s.session == 0
    assert (asm.time_jumps, asm.implausible, asm.session) == (1, 1, 0)


def test_a_restarted_plant_is_recognised_after_three_states() -> None:
    asm = StateAssembler()
    x = np.zeros(12)
    for t_us in range(0, 5_000_000, 10_000):
        _feed(asm, t_us, x)
    assert _feed(asm, 0, x) is None  # the new plant's first state: not believed yet
    assert _feed(asm, 10_000, x) is None
    s = _feed(asm, 20_000, x)  # three states that continue each other: a new session
    assert s is not None and s.session == 1 and s.t_us == 20_000
    assert _feed(asm, 30_000, x) is not None
    assert asm.out_of_order == 2


def test_a_long_gap_forward_is_believed_when_the_states_continue_it() -> None:
    """A stalled autopilot reads on at the plant's current time: a resync, not a refusal."""
    asm = StateAssembler()
    x = np.zeros(12)
    _feed(asm, 0, x)
    later = [20_000_000 + k * 10_000 for k in range(4)]
    got = [_feed(asm, t, x) for t in later]
    assert got[0] is None and got[1] is None and got[2] is not None and got[3] is not None
    assert asm.resyncs == 1 and asm.session == 0


def test_udp_link_survives_garbage_and_counts_it() -> None:
    with MavlinkUdp((LOOPBACK, 0)) as rx, MavlinkUdp((LOOPBACK, 0), rx.local, system_id=1) as tx:
        good = tx.pack(mavlink2.MAVLink_heartbeat_message(4, 0, 0, 0, 3, 3))
        flipped = bytearray(good)
        flipped[12] ^= 0xFF  # payload byte: CRC no longer matches
        datagrams = [b"\xfd\x09", bytes(flipped), b"\x00" * 300, good[:-3], good]
        for d in datagrams:
            tx.send_bytes(d)
        got = rx.recv(timeout_s=1.0)
        for _ in range(20):
            if rx.stats.rx_datagrams >= len(datagrams):
                break
            got += rx.recv(timeout_s=0.1)
        assert [m.get_type() for m, _ in got] == ["HEARTBEAT"]
        assert rx.stats.rx_bad >= 2


def test_wrong_system_is_dropped() -> None:
    with MavlinkUdp((LOOPBACK, 0), accept_system=1) as rx, MavlinkUdp(
        (LOOPBACK, 0), rx.local, system_id=7
    ) as tx:
        tx.send(mavlink2.MAVLink_heartbeat_message(4, 0, 0, 0, 3, 3))
        assert rx.recv(timeout_s=1.0) == []
        assert rx.stats.rx_foreign == 1


def test_only_loopback_and_busy_ports_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="loopback"):
        MavlinkUdp((LOOPBACK, 0), ("10.0.0.1", 14550))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        with pytest.raises(PortBusyError, match="busy"):
            MavlinkUdp((LOOPBACK, s.getsockname()[1]))


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


def _runner(paper: Scenario) -> tuple[Runner, TLController, FlightManager]:
    ctrl = TLController(paper.airframe, paper.gains, 100.0)
    manager = FlightManager(FlightConfig(home=GeoPoint(47.4, 8.5, 488.0)))
    sim = SimLink((LOOPBACK, 0), (LOOPBACK, 9), LIMITS)
    return Runner(ctrl, manager, sim, sim, RunnerConfig()), ctrl, manager


def test_disarmed_gives_zero_pitch_and_no_integration(paper: Scenario) -> None:
    runner, ctrl, _ = _runner(paper)
    x = np.zeros(12)
    for k in range(200):
        u = runner.tick(k * 0.01, x)
        assert np.all(u == 0.0)
    assert np.all(ctrl.state == 0.0)
    runner.state_in.close()


def test_landed_with_ground_command_does_not_wind_up(paper: Scenario) -> None:
    runner, ctrl, manager = _runner(paper)
    line = StraightLine(start_nwu_m=(1.0, -1.0, 0.0), duration_s=10.0)
    for cmd in (FlyTrajectory(line), Arm()):
        assert manager.execute(cmd, 0.0, np.zeros(12)).accepted
    x = np.zeros(12)  # on the ground, 1.4 m from a command that is also on the ground
    for k in range(500):
        runner.tick(k * 0.01, x)
    assert np.all(ctrl.state[S_I1 : S_I4 + 3] == 0.0)
    runner.state_in.close()


def test_disarmed_on_the_ground_does_not_yaw() -> None:
    """Zero pitch still leaves the main rotor's profile torque; skid friction holds the yaw."""
    from heli_plant.model import Plant

    plant = Plant(Airframe.load(), np.zeros(12))
    plant.set_pitches(np.zeros(4))
    for _ in range(500):
        plant.step(0.01)
    assert plant.on_ground and plant.x[8] == 0.0 and np.all(plant.x[0:3] == 0.0)


def test_ftp_requests_get_a_nak() -> None:
    from autopilot.links.mavlink_gcs import FTP_OPCODE_NAK, ftp_nak

    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    req_payload = [0] * 251
    req_payload[0:2] = [41, 0]  # seq 41
    req_payload[2], req_payload[3] = 3, 4  # session 3, OpenFileRO
    req = mavlink2.MAVLink_file_transfer_protocol_message(0, 1, 1, req_payload)
    [parsed_req] = mavlink2.MAVLink(None).parse_buffer(bytes(req.pack(mav)))
    nak = ftp_nak(parsed_req)
    [parsed] = mavlink2.MAVLink(None).parse_buffer(bytes(nak.pack(mavlink2.MAVLink(None, 1, 1))))
    p = bytes(parsed.payload)
    assert (parsed.target_system, parsed.target_component) == (255, 190)
    assert int.from_bytes(p[0:2], "little") == 42 and p[2] == 3
    assert p[3] == FTP_OPCODE_NAK and p[4] == 1 and p[5] == 4 and p[12] == 7
