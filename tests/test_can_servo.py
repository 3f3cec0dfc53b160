"""The DroneCAN servo link on real python-can buses: encoding, checked reassembly, the
servo endpoint's gate and timeout, the sender's NodeStatus and fault handling, and two
processes over udp_multicast inside a private network namespace.

Faulty traffic is made by encoding with dronecan directly and sending the frames (cut,
corrupted, duplicated) on a python-can ``virtual`` bus; the only fake is a bus that raises.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import can
import dronecan
import numpy as np
import pytest
from dronecan import transport
from netns import unshare_reason

from autopilot.links.can_servo import CanServoSender
from heli_common.vehicle.airframe import PitchLimits
from heli_common.wire.can.bus import (
    CanBus,
    CanBusConfig,
    CanBusError,
    CanSendError,
    open_bus,
    parse_bus_spec,
)
from heli_common.wire.can.dronecan_codec import (
    ACTUATOR_COMMAND,
    ARRAY_COMMAND,
    ARRAY_COMMAND_DTID,
    COMMAND_TYPE_POSITION,
    ArrayCommandEncoder,
    CanFrame,
    DronecanDriver,
    DropReason,
    Reassembler,
    array_command_entries,
    float16_round,
    float16_tolerance,
    parse_can_id,
)
from heli_plant.can_endpoint import CanServoEndpoint

# wide test limits [rad] (the X-Cell 60 file has tighter ones): theta_m, theta_t, eps, eta
LIMITS = PitchLimits((-0.6, 0.6), (-0.8, 0.8), (-0.5, 0.5), (-0.5, 0.5))
U1 = (0.1, -0.2, 0.3, -0.05)
U2 = (0.2, 0.1, -0.1, 0.05)
AUTOPILOT_NODE = 10

_ids = itertools.count()


@pytest.fixture
def channel() -> str:
    """A virtual CAN channel no other test shares."""
    return f"test-can-servo-{os.getpid()}-{next(_ids)}"


@pytest.fixture
def raw(channel: str) -> Iterator[CanBus]:
    """A plain bus on the channel, to inject hand-made frames."""
    with CanBus(CanBusConfig("virtual", channel)) as bus:
        yield bus


@pytest.fixture
def endpoint(channel: str) -> Iterator[CanServoEndpoint]:
    with CanServoEndpoint(CanBusConfig("virtual", channel), limits=LIMITS, timeout_s=0.1) as ep:
        yield ep


def transfer_frames(payload: Any, node_id: int = AUTOPILOT_NODE, tid: int = 0) -> list[CanFrame]:
    tr = transport.Transfer(transfer_id=tid, source_node_id=node_id, payload=payload)
    return [CanFrame(int(f.message_id), bytes(f.bytes)) for f in tr.to_frames()]


def array_command(entries: Sequence[tuple[int, int, float]]) -> Any:
    return ARRAY_COMMAND(
        commands=[
            ACTUATOR_COMMAND(actuator_id=a, command_type=ct, command_value=v)
            for a, ct, v in entries
        ]
    )


def pitch_frames(
    values: Sequence[float], tid: int = 0, ids: Sequence[int] = (1, 2, 3, 4)
) -> list[CanFrame]:
    cmds = [(a, COMMAND_TYPE_POSITION, v) for a, v in zip(ids, values, strict=True)]
    return transfer_frames(array_command(cmds), tid=tid)


def put(bus: CanBus, frames: Sequence[CanFrame]) -> None:
    for f in frames:
        bus.send(f.can_id, f.data)


def f16(values: Sequence[float]) -> list[float]:
    return [float16_round(v) for v in values]


def assert_f16_equal(got: Sequence[float], sent: Sequence[float]) -> None:
    for g, s in zip(got, sent, strict=True):
        assert abs(g - s) <= float16_tolerance(s), (got, sent)


# ------------------------------------------------------------------------------ codec


def test_array_command_wire_format() -> None:
    enc = ArrayCommandEncoder(AUTOPILOT_NODE)
    frames = enc.encode(U1)
    # 4 commands x (uint8 id, uint8 type, float16) = 16 bytes + 2 CRC = 18 -> 7 + 7 + 4
    assert [len(f.data) for f in frames] == [8, 8, 5]
    f = parse_can_id(frames[0].can_id)
    assert (f.data_type_id, f.source_node_id, f.service, f.priority) == (1010, 10, False, 8)
    tails = [fr.data[-1] for fr in frames]
    assert [t & 0x80 != 0 for t in tails] == [True, False, False]  # start of transfer
    assert [t & 0x40 != 0 for t in tails] == [False, False, True]  # end of transfer
    assert [(t >> 5) & 1 for t in tails] == [0, 1, 0]  # toggle
    assert {t & 0x1F for t in tails} == {0}  # transfer id
    # transfer id advances per transfer and wraps at 32
    tids = [enc.encode(U1)[0].data[-1] & 0x1F for _ in range(40)]
    assert tids[:3] == [1, 2, 3] and tids[30:33] == [31, 0, 1]
    # decoded by dronecan's own Transfer.from_frames (not our reassembler)
    tr = transport.Transfer()
    tr.from_frames([transport.Frame(fr.can_id, fr.data) for fr in frames])
    entries = array_command_entries(tr.payload)
    assert [(a, c) for a, c, _ in entries] == [(1, 1), (2, 1), (3, 1), (4, 1)]
    assert_f16_equal([v for _, _, v in entries], U1)


def test_float16_quantisation_bound() -> None:
    rng = np.random.default_rng(1)
    for v in [0.0, 1e-6, -3e-5, 0.6, -0.8, 0.5, *rng.uniform(-0.8, 0.8, 500)]:
        q = float16_round(float(v))
        assert abs(q - v) <= float16_tolerance(float(v))
    assert abs(float16_round(0.3) - 0.3) > 1e-6  # it is a real quantisation
    assert float16_round(0.6) > 0.6  # a command saturated at the limit lands past it
    assert math.isnan(float16_round(math.nan))
    assert float16_round(1e9) == 65504.0  # dronecan saturates to the float16 range


def test_reassembler_counts_each_fault_once() -> None:
    drops: list[tuple[DropReason, str]] = []
    r = Reassembler((ARRAY_COMMAND_DTID,), lambda reason, detail: drops.append((reason, detail)))
    good = pitch_frames(U1, tid=5)
    assert [r.feed(f.can_id, f.data) for f in good[:2]] == [None, None]
    out = r.feed(good[2].can_id, good[2].data)
    assert out is not None and out.transfer_id == 5 and out.source_node_id == AUTOPILOT_NODE
    # lost end frame: noticed when the next transfer starts, which still decodes
    a, b = pitch_frames(U1, tid=6), pitch_frames(U2, tid=7)
    for f in [*a[:2], *b[:2]]:
        r.feed(f.can_id, f.data)
    out = r.feed(b[2].can_id, b[2].data)
    assert out is not None and out.transfer_id == 7
    assert r.drops[DropReason.MISSING_FRAME] == 1
    # lost start frame: two headless frames, one lost transfer
    c = pitch_frames(U1, tid=8)
    assert r.feed(c[1].can_id, c[1].data) is None and r.feed(c[2].can_id, c[2].data) is None
    assert r.drops[DropReason.MISSING_FRAME] == 2
    assert "transfer 8" in drops[-1][1]


# ---------------------------------------------------------------------- endpoint: good path


def test_sender_to_endpoint_applies_float16_pitches(
    channel: str, endpoint: CanServoEndpoint
) -> None:
    assert endpoint.poll(0.0) is None  # nothing yet: the plant keeps its own initial pitches
    with CanServoSender(CanBusConfig("virtual", channel), node_id=AUTOPILOT_NODE) as tx:
        assert tx.send(U1, 0.0)
        held = endpoint.poll(0.0)
        assert held is not None
        assert held.tolist() == f16(U1)
        assert tx.send(U2, 0.01)
        held = endpoint.poll(0.01)
        assert held is not None and held.tolist() == f16(U2)
    s = endpoint.stats
    assert s["commands_applied"] == 2 and s["frames_rx"] == 3 + 1 + 3  # + one NodeStatus
    assert s["node_status_rx"] == 1
    assert endpoint.autopilot_status is not None
    assert endpoint.autopilot_status.source_node_id == AUTOPILOT_NODE
    bad = {
        k: v
        for k, v in s.items()
        if k not in {"frames_rx", "transfers_rx", "commands_applied", "node_status_rx"}
    }
    assert not any(bad.values()), bad


def test_a_repeated_answer_is_the_same_transfer_and_is_not_the_next_ticks_command(
    channel: str, endpoint: CanServoEndpoint
) -> None:
    """The lockstep race: the plant re-sends state t (no answer within resend_s), the slow
    autopilot answers t, then the re-sent t again. The second answer is the same transfer
    (same transfer id): dropped, so the plant, now at t + dt, waits for the answer to
    t + dt instead of holding a repeat of t's. A new command of the same values is new."""
    from autopilot.links.can_servo import CanServoOutput

    with CanServoSender(CanBusConfig("virtual", channel), node_id=AUTOPILOT_NODE) as tx:
        out = CanServoOutput(tx)
        out.send_pitches(10_000, np.array(U1), True)  # the answer to t
        out.send_pitches(10_000, np.array(U1), True)  # the answer to the re-sent t
        assert tx.stats["commands_repeated"] == 1 and tx.stats["commands_sent"] == 1
        before = endpoint.stats["commands_applied"]
        held = endpoint.poll(1.0)
        assert held is not None and held.tolist() == f16(U1)
        assert endpoint.stats["commands_applied"] == before + 1
        assert endpoint.stats["repeated_transfer"] == 1
        out.send_pitches(20_000, np.array(U1), True)  # t + dt, the same values: a new command
        endpoint.poll(1.01)
        assert endpoint.stats["commands_applied"] == before + 2
        assert tx.stats["commands_repeated"] == 1
        out.send_pitches(20_000, np.array(U2), True)  # the same time, other values: new
        endpoint.poll(1.02)
        assert endpoint.stats["commands_applied"] == before + 3
    # a transfer id seen again after the transfer-id timeout is a new transfer (32 later)
    enc = ArrayCommandEncoder(AUTOPILOT_NODE)
    frames = enc.encode(list(U2))
    with CanBus(CanBusConfig("virtual", channel)) as bus:
        put(bus, frames)
        endpoint.poll(2.0)
        applied = endpoint.stats["commands_applied"]
        put(bus, frames)
        endpoint.poll(2.5)  # within 2 s: a repeat
        assert endpoint.stats["commands_applied"] == applied
        put(bus, frames)
        endpoint.poll(4.6)  # 2.6 s after the transfer: a new one
        assert endpoint.stats["commands_applied"] == applied + 1


def test_configured_actuator_ids_and_node_id(channel: str) -> None:
    ids = (11, 12, 13, 14)
    with (
        CanServoEndpoint(
            CanBusConfig("virtual", channel), limits=LIMITS, actuator_ids=ids, source_node_id=42
        ) as ep,
        CanServoSender(CanBusConfig("virtual", channel), node_id=42, actuator_ids=ids) as tx,
    ):
        tx.send(U1, 0.0)
        held = ep.poll(0.0)
        assert held is not None and held.tolist() == f16(U1)
    with (
        CanServoEndpoint(CanBusConfig("virtual", channel), limits=LIMITS, source_node_id=42) as ep,
        CanServoSender(CanBusConfig("virtual", channel), node_id=43) as tx,
    ):
        tx.send(U1, 0.0)
        assert ep.poll(0.0) is None
        assert ep.stats["foreign_source"] == 1


def test_node_status_at_1hz_of_given_time(channel: str, endpoint: CanServoEndpoint) -> None:
    with CanServoSender(CanBusConfig("virtual", channel), node_id=AUTOPILOT_NODE) as tx:
        for k in range(251):  # 0 .. 2.5 s at 100 Hz
            tx.send(U1, 100.0 + k * 0.01)  # any time origin: uptime counts from the first
            endpoint.poll(100.0 + k * 0.01)
        assert tx.stats["node_status_sent"] == 3  # at 100, 101, 102 s
    st = endpoint.autopilot_status
    assert st is not None and (st.uptime_s, st.health, st.mode) == (2, 0, 0)
    assert endpoint.stats["node_status_rx"] == 3


# --------------------------------------------------------------------- endpoint: faults


def test_missing_frames_are_dropped_and_held(
    raw: CanBus, endpoint: CanServoEndpoint, caplog: pytest.LogCaptureFixture
) -> None:
    put(raw, pitch_frames(U1, tid=0))
    assert endpoint.poll(0.0) is not None
    for tid, lost in [(1, 1), (2, 0), (3, 2)]:  # middle, first, last frame lost
        frames = pitch_frames(U2, tid=tid)
        put(raw, [f for i, f in enumerate(frames) if i != lost])
        held = endpoint.poll(0.01 * tid)
        assert held is not None and held.tolist() == f16(U1)  # the old command is held
    put(raw, pitch_frames(U2, tid=4))  # the next start frame reveals the lost end
    held = endpoint.poll(0.05)
    assert held is not None and held.tolist() == f16(U2)
    assert endpoint.stats["missing_frame"] == 3
    assert endpoint.stats["commands_applied"] == 2
    assert "dropped (missing_frame)" in caplog.text


def test_duplicated_frame_is_a_toggle_error(raw: CanBus, endpoint: CanServoEndpoint) -> None:
    frames = pitch_frames(U1)
    put(raw, [frames[0], frames[1], frames[1], frames[2]])
    assert endpoint.poll(0.0) is None
    assert endpoint.stats["missing_frame"] == 1


def test_wrong_crc_is_dropped(
    raw: CanBus, endpoint: CanServoEndpoint, caplog: pytest.LogCaptureFixture
) -> None:
    frames = pitch_frames(U1)
    data = bytearray(frames[1].data)
    data[3] ^= 0x10  # a value bit flips; the tail byte is intact
    put(raw, [frames[0], CanFrame(frames[1].can_id, bytes(data)), frames[2]])
    assert endpoint.poll(0.0) is None
    assert endpoint.stats["crc"] == 1
    assert "dropped (crc)" in caplog.text


def test_foreign_types_and_malformed_frames(raw: CanBus, endpoint: CanServoEndpoint) -> None:
    esc = dronecan.uavcan.equipment.esc.RawCommand(cmd=list(range(100, 900, 100)))
    put(raw, transfer_frames(esc))  # data type 1030, 8 x 14 bits: 3 frames
    raw.bus.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\xc0"))
    raw.bus.send(can.Message(arbitration_id=0x0803F20A, is_extended_id=True, data=b""))
    raw.bus.send(can.Message(arbitration_id=0x0803F20A, is_extended_id=True, is_remote_frame=True))
    assert endpoint.poll(0.0) is None
    assert endpoint.stats["foreign_type"] == 3  # counted per frame: they are never reassembled
    assert endpoint.stats["malformed_frame"] == 3
    put(raw, pitch_frames(U1))  # and the link still works
    held = endpoint.poll(0.01)
    assert held is not None and held.tolist() == f16(U1)


def test_unknown_actuator_ids_are_ignored_missing_ones_refuse(
    raw: CanBus, endpoint: CanServoEndpoint
) -> None:
    P = COMMAND_TYPE_POSITION
    put(
        raw,
        transfer_frames(array_command([(7, P, 0.4), *[(i + 1, P, v) for i, v in enumerate(U1)]])),
    )
    held = endpoint.poll(0.0)
    assert held is not None and held.tolist() == f16(U1)  # ours applied, id 7 ignored
    assert endpoint.stats["unknown_actuator"] == 1
    put(
        raw,
        transfer_frames(array_command([(5, P, 0.1), (6, P, 0.1), (7, P, 0.1), (8, P, 0.1)]), tid=1),
    )
    put(raw, transfer_frames(array_command([(1, P, 0.1), (2, P, 0.1), (3, P, 0.1)]), tid=2))
    put(
        raw,
        transfer_frames(array_command([(1, P, 0.1), (1, P, 0.2), (3, P, 0.1), (4, P, 0.1)]), tid=3),
    )
    put(
        raw,
        transfer_frames(array_command([(1, 0, 0.1), (2, P, 0.1), (3, P, 0.1), (4, P, 0.1)]), tid=4),
    )
    held = endpoint.poll(0.01)
    assert held is not None and held.tolist() == f16(U1)
    s = endpoint.stats
    assert (s["missing_actuator"], s["duplicate_actuator"], s["wrong_command_type"]) == (2, 1, 1)
    assert s["unknown_actuator"] == 5 and s["commands_applied"] == 1


def test_nan_and_out_of_limits_never_reach_a_servo(
    raw: CanBus, endpoint: CanServoEndpoint, caplog: pytest.LogCaptureFixture
) -> None:
    put(raw, pitch_frames(U1, tid=0))
    endpoint.poll(0.0)
    bad = [
        (math.nan, 0.0, 0.0, 0.0),
        (0.0, math.inf, 0.0, 0.0),  # float16 saturates it to 65504: out of limits
        (0.7, 0.0, 0.0, 0.0),  # theta_m limit 0.6
        (0.0, 0.0, 0.0, -0.51),  # eta limit -0.5
    ]
    for k, u in enumerate(bad, start=1):
        put(raw, pitch_frames(u, tid=k))
        held = endpoint.poll(0.01 * k)
        assert held is not None and held.tolist() == f16(U1)
    assert endpoint.stats["nonfinite"] == 1 and endpoint.stats["out_of_limits"] == 3
    # logged once a second per kind: the first of the three is in the log
    assert "command refused (out_of_limits)" in caplog.text and "theta_t=65504" in caplog.text
    # a command saturated at a limit comes back 1e-4 past it: clipped, not refused
    at_limits = (0.6, -0.8, 0.5, -0.5)
    put(raw, pitch_frames(at_limits, tid=9))
    held = endpoint.poll(0.1)
    assert float16_round(0.6) > 0.6
    assert (
        held is not None
        and held.tolist() == np.clip(f16(at_limits), endpoint.lo, endpoint.hi).tolist()
    )
    assert held[0] == 0.6
    assert endpoint.stats["clipped"] == 1 and endpoint.stats["commands_applied"] == 2


def test_timeout_engages_on_silence_and_on_bad_commands(
    raw: CanBus, endpoint: CanServoEndpoint, caplog: pytest.LogCaptureFixture
) -> None:
    assert not endpoint.silent(0.0)  # nothing polled yet
    endpoint.poll(0.0)
    assert not endpoint.silent(0.1) and endpoint.silent(0.11)  # none since the first poll
    put(raw, pitch_frames(U1, tid=0))
    endpoint.poll(0.5)
    assert not endpoint.silent(0.55)
    assert endpoint.poll(0.61) is not None and endpoint.silent(0.61)  # still holding
    assert endpoint.stats["timeouts"] == 1  # entries into silence are seen by polls
    assert "no valid command for" in caplog.text and "ended its flight, or the bus is down" in caplog.text
    put(raw, pitch_frames(U2, tid=1))
    endpoint.poll(1.0)
    assert not endpoint.silent(1.0)
    # a stream of refused commands does not keep the link alive
    for k in range(30):
        put(raw, pitch_frames((math.nan, 0.0, 0.0, 0.0), tid=(2 + k) & 31))
        held = endpoint.poll(1.0 + 0.01 * (k + 1))
        assert held is not None and held.tolist() == f16(U2)
    assert endpoint.silent(1.3) and endpoint.stats["timeouts"] == 2
    assert endpoint.stats["nonfinite"] == 30
    # so does a stream of transfers that each lose a frame
    put(raw, pitch_frames(U1, tid=0))
    endpoint.poll(2.0)
    for k in range(1, 31):
        put(raw, pitch_frames(U2, tid=k)[:2])
        held = endpoint.poll(2.0 + 0.01 * k)
        assert held is not None and held.tolist() == f16(U1)
    assert endpoint.silent(2.3) and endpoint.stats["timeouts"] == 3
    assert endpoint.stats["missing_frame"] == 29  # the 30th is noticed at the next start


def test_random_garbage_never_crashes_nor_reaches_a_servo(
    raw: CanBus, endpoint: CanServoEndpoint
) -> None:
    """Valid transfers mixed with cut, bit-flipped, shuffled and random frames."""
    rng = np.random.default_rng(2024)
    lim = np.array(LIMITS.as_tuple())
    applied_ok = 0
    for k in range(400):
        u = rng.uniform(lim[:, 0] * 1.3, lim[:, 1] * 1.3)  # some beyond the limits
        frames = pitch_frames(u.tolist(), tid=k & 31)
        kind = k % 5
        if kind == 1:  # flip a random bit anywhere, tail byte included
            i = int(rng.integers(len(frames)))
            data = bytearray(frames[i].data)
            data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
            frames[i] = CanFrame(frames[i].can_id, bytes(data))
        elif kind == 2:  # random frames with DroneCAN-looking ids
            frames = [
                CanFrame(
                    int(rng.integers(0, 1 << 29)) if j % 2 else frames[0].can_id,
                    rng.integers(0, 256, int(rng.integers(1, 9))).astype(np.uint8).tobytes(),
                )
                for j in range(4)
            ]
        elif kind == 3:  # frames out of order
            frames = [frames[i] for i in rng.permutation(len(frames))]
        put(raw, frames)
        held = endpoint.poll(0.01 * k)
        if held is not None:
            assert np.all(np.isfinite(held))
            assert np.all(held >= lim[:, 0]) and np.all(held <= lim[:, 1])
        applied_ok = endpoint.stats["commands_applied"]
    assert applied_ok > 50  # the clean transfers within limits still got through
    s = endpoint.stats
    assert s["out_of_limits"] > 0 and s["missing_frame"] + s["crc"] + s["foreign_type"] > 0


class RaisingBus(can.BusABC):
    """A bus whose driver fails on every send and receive."""

    def __init__(self) -> None:
        super().__init__(channel="raising")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("transmit failed: bus off")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise can.CanOperationError("receive failed: interface down")


def test_bus_that_raises_is_counted_not_fatal(caplog: pytest.LogCaptureFixture) -> None:
    with CanBus(bus=RaisingBus()) as bus:
        with pytest.raises(CanSendError):
            bus.send(0x1, b"\x00")
        tx = CanServoSender(bus, node_id=AUTOPILOT_NODE)
        for k in range(300):
            assert tx.send(U1, 0.01 * k) is False
        assert tx.stats["send_errors"] == 300 and tx.stats["commands_sent"] == 0
        assert tx.stats["node_status_errors"] == 3 and tx.stats["rx_errors"] == 300
        # logged, but at most once per second of the given time
        assert caplog.text.count("ArrayCommand send failed") == 3
        assert "bus off" in caplog.text
        ep = CanServoEndpoint(bus, limits=LIMITS, timeout_s=0.1)
        assert ep.poll(0.0) is None and ep.poll(0.2) is None
        assert ep.stats["bus_errors"] == 2 and ep.silent(0.2)
        # the servos' node: NodeStatus and Status at 0 s, Status at 0.2 s, refused and counted
        assert ep.node_stats["send_errors"] == 3 and ep.node_stats["node_status_sent"] == 0
        assert "CAN servo: receive failed" in caplog.text
        tx.close()
        ep.close()
        assert not bus.closed  # an injected bus is left to its owner
    assert bus.closed


def test_full_queue_drops_a_command_and_recovers(channel: str) -> None:
    # the servo's receive queue holds 4 frames: one command (3) and one NodeStatus (1)
    cfg_rx = CanBusConfig("virtual", channel, rx_queue_size=4)
    with (
        CanServoEndpoint(cfg_rx, limits=LIMITS) as ep,
        CanServoSender(CanBusConfig("virtual", channel), node_id=AUTOPILOT_NODE) as tx,
    ):
        assert tx.send(U1, 0.0)
        assert not tx.send(U2, 0.01)  # the servo did not read: queue full, not blocking
        assert tx.stats["send_errors"] == 1
        held = ep.poll(0.01)
        assert held is not None and held.tolist() == f16(U1)
        assert tx.send(U2, 0.02)
        held = ep.poll(0.02)
        assert held is not None and held.tolist() == f16(U2)
        assert ep.stats["missing_frame"] == 0  # the cut transfer never started on the bus


# ------------------------------------------------------------------- independent dronecan node


def test_dronecan_node_broadcast_is_applied(channel: str, endpoint: CanServoEndpoint) -> None:
    """The other direction of interoperability: dronecan's own Node sends, we apply."""
    node = dronecan.node.Node(
        DronecanDriver(open_bus(CanBusConfig("virtual", channel))), node_id=33
    )
    try:
        cmds = [(i + 1, COMMAND_TYPE_POSITION, v) for i, v in enumerate(U2)]
        node.broadcast(array_command(cmds))
        node.broadcast(dronecan.uavcan.protocol.NodeStatus(uptime_sec=7))
        held = endpoint.poll(0.0)
        assert held is not None and held.tolist() == f16(U2)
        assert endpoint.autopilot_status is not None and endpoint.autopilot_status.uptime_s == 7
    finally:
        node.close()


# ----------------------------------------------------------------------- buses and configs


def test_bus_specs() -> None:
    assert parse_bus_spec("virtual") == CanBusConfig("virtual", "heli-sitl-servo")
    assert parse_bus_spec("virtual:x").channel == "x"
    u = parse_bus_spec("udp_multicast")
    assert (u.channel, u.port) == ("239.74.163.2", 43113)  # the IPv4 group
    assert parse_bus_spec("udp_multicast:239.1.2.3:5000").port == 5000
    assert parse_bus_spec("socketcan").channel == "vcan0"
    with pytest.raises(ValueError):
        parse_bus_spec("pcan:1")
    with pytest.raises(ValueError):
        CanServoSender("virtual:x", node_id=0)
    with pytest.raises(ValueError):
        CanServoEndpoint("virtual:x", limits=LIMITS, actuator_ids=(1, 1, 2, 3))


def test_socketcan_vcan0() -> None:
    if not sys.platform.startswith("linux") or not Path("/sys/class/net/vcan0").exists():
        pytest.skip(
            "no vcan0 here (needs the vcan kernel module: modprobe vcan; "
            "ip link add dev vcan0 type vcan; ip link set up vcan0)"
        )
    with (
        CanServoEndpoint("socketcan:vcan0", limits=LIMITS) as ep,
        CanServoSender("socketcan:vcan0", node_id=AUTOPILOT_NODE) as tx,
    ):
        assert tx.send(U1, 0.0)
        held = ep.poll(0.0, wait_s=1.0)
        assert held is not None and held.tolist() == f16(U1)


def test_unopenable_bus_is_a_clear_error() -> None:
    with pytest.raises(CanBusError, match="socketcan:no-such-can9"):
        open_bus("socketcan:no-such-can9")


# -------------------------------------------------- two processes over udp_multicast (netns)

N_UDP = 300


def _udp_pattern(k: int) -> list[float]:
    return [0.3 * math.sin(0.05 * k), 0.4 * math.cos(0.03 * k), 0.2 * math.sin(0.07 * k), -0.1]


def _udp_receiver(out: Path) -> int:
    ep = CanServoEndpoint(
        CanBusConfig("udp_multicast"), limits=LIMITS, timeout_s=0.2, source_node_id=AUTOPILOT_NODE
    )
    (out / "ready").touch()
    history: list[tuple[int, list[float]]] = []
    t0 = time.monotonic()
    while ep.stats["commands_applied"] < N_UDP and time.monotonic() - t0 < 20.0:
        n0 = ep.stats["commands_applied"]
        held = ep.poll(time.monotonic() - t0, wait_s=0.05)
        if held is not None and ep.stats["commands_applied"] != n0:
            history.append((ep.stats["commands_applied"], held.tolist()))
    t_last = time.monotonic() - t0
    while not ep.silent(time.monotonic() - t0) and time.monotonic() - t0 < t_last + 2.0:
        ep.poll(time.monotonic() - t0, wait_s=0.01)
    status = ep.autopilot_status
    result = {
        "history": history,
        "stats": ep.stats,
        "silent": ep.silent(time.monotonic() - t0),
        "status_uptime_s": None if status is None else status.uptime_s,
    }
    ep.close()
    (out / "rx.json").write_text(json.dumps(result))
    return 0


def _udp_sender(out: Path) -> int:
    deadline = time.monotonic() + 10.0
    while not (out / "ready").exists():
        if time.monotonic() > deadline:
            return 4
        time.sleep(0.01)
    with CanServoSender(CanBusConfig("udp_multicast"), node_id=AUTOPILOT_NODE) as tx:
        for k in range(N_UDP):
            tx.send(_udp_pattern(k), 0.01 * k)  # 3 s of 100 Hz ticks, sent 3x faster
            time.sleep(0.003)
        (out / "tx.json").write_text(json.dumps(tx.stats))
    return 0


def _udp_namespace_main(out: Path, parent_netns: str) -> int:
    if os.readlink("/proc/self/ns/net") == parent_netns:
        print("refusing: not inside a private network namespace", file=sys.stderr)
        return 3
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    subprocess.run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
    me = str(Path(__file__).resolve())
    rx = subprocess.Popen([sys.executable, me, "udp-rx", str(out)])
    tx = subprocess.Popen([sys.executable, me, "udp-tx", str(out)])
    try:
        return max(tx.wait(timeout=40), rx.wait(timeout=40))
    finally:
        for p in (tx, rx):
            if p.poll() is None:
                p.kill()


@pytest.mark.netns
@pytest.mark.slow
def test_two_processes_over_udp_multicast_in_private_netns(tmp_path: Path) -> None:
    """Sender and servo endpoint in two processes on one host: udp_multicast on the IPv4
    group over ``lo`` of a network namespace made for this test (never the host's)."""
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    me = str(Path(__file__).resolve())
    parent_netns = os.readlink("/proc/self/ns/net")
    proc = subprocess.run(
        ["unshare", "--net", "--", sys.executable, me, "udp-ns", str(tmp_path), parent_netns],
        capture_output=True, timeout=60, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    rx = json.loads((tmp_path / "rx.json").read_text())
    tx = json.loads((tmp_path / "tx.json").read_text())
    assert tx["commands_sent"] == N_UDP and tx["send_errors"] == 0
    assert tx["node_status_sent"] == 3  # t = 0, 1, 2 s of the given time
    s = rx["stats"]
    assert s["commands_applied"] == N_UDP, s
    faults = ("missing_frame", "crc", "decode", "foreign_type", "out_of_limits", "nonfinite")
    assert all(s[k] == 0 for k in faults), s
    assert s["node_status_rx"] == 3 and rx["status_uptime_s"] == 2
    assert rx["history"], "no command seen"
    for count, held in rx["history"]:  # every held vector is the count-th one sent
        assert_f16_equal(held, _udp_pattern(count - 1))
    assert rx["history"][-1][0] == N_UDP
    assert rx["silent"]  # the sender stopped: the timeout engaged


if __name__ == "__main__":  # roles of the udp_multicast test, run in child processes
    logging.basicConfig(level=logging.WARNING)
    role, out_dir = sys.argv[1], Path(sys.argv[2])
    if role == "udp-ns":
        sys.exit(_udp_namespace_main(out_dir, sys.argv[3]))
    sys.exit(_udp_receiver(out_dir) if role == "udp-rx" else _udp_sender(out_dir))
