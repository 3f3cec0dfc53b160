"""The struct-packed DroneCAN codec against dronecan's own serialisation, byte for byte.

The per-tick messages (ArrayCommand, ArmingStatus) are packed and unpacked without DSDL
objects; these properties say that nothing on the wire changed by it: the same frames as
dronecan's ``Transfer.to_frames`` for any value and transfer id, the same decoded values as
dronecan's ``Transfer.from_frames``, and the same float16 bits as libuavcan's conversion.
"""

from __future__ import annotations

import math
import struct

from dronecan import transport
from dronecan.dsdl import common as dsdl_common
from hypothesis import given, settings
from hypothesis import strategies as st

from heli_common.wire.can.dronecan_codec import (
    ACTUATOR_COMMAND,
    ARMING_STATUS,
    ARMING_STATUS_DTID,
    ARRAY_COMMAND,
    ARRAY_COMMAND_DTID,
    COMMAND_TYPE_POSITION,
    ArmingStatusEncoder,
    ArrayCommandEncoder,
    Reassembler,
    array_command_entries,
    float16_bits,
    float16_round,
    transfer_crc,
)

NODE = 10
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True, width=64)
PITCH = st.floats(-0.8, 0.8)


def dronecan_f16_bits(value: float) -> int:
    """libuavcan's conversion as dronecan runs it, after the DSDL saturated cast."""
    v = max(-65504.0, min(65504.0, value)) if not math.isnan(value) else value
    return int(transport.f16_from_f32(v))


def dronecan_frames(values: list[float], ids: tuple[int, ...], tid: int) -> list[tuple[int, bytes]]:
    msg = ARRAY_COMMAND(commands=[
        ACTUATOR_COMMAND(actuator_id=a, command_type=COMMAND_TYPE_POSITION, command_value=v)
        for a, v in zip(ids, values, strict=True)
    ])  # fmt: skip
    tr = transport.Transfer(transfer_id=tid, source_node_id=NODE, payload=msg, transfer_priority=8)
    return [(int(f.message_id), bytes(f.bytes)) for f in tr.to_frames()]


@settings(max_examples=2000, deadline=None)
@given(ANY_FLOAT)
def test_float16_bits_are_libuavcans(value: float) -> None:
    # the struct round trip below raises for |v| beyond float32; the saturation comes first
    assert float16_bits(value) == dronecan_f16_bits(value)


def test_float16_ties_round_away_from_zero() -> None:
    # 1 + 2**-11 lies exactly between two float16 values: libuavcan rounds it up,
    # IEEE round-to-nearest-even (numpy, struct 'e') would round down
    tie = 1.0 + 2.0**-11
    assert float16_round(tie) == 1.0 + 2.0**-10
    assert struct.unpack("<e", struct.pack("<e", tie))[0] == 1.0


@settings(max_examples=300, deadline=None)
@given(
    st.integers(1, 15).flatmap(
        lambda n: st.tuples(
            st.lists(ANY_FLOAT, min_size=n, max_size=n),
            st.lists(st.integers(0, 255), min_size=n, max_size=n, unique=True),
        )
    ),
    st.integers(0, 31),
)
def test_array_command_frames_are_dronecans(case: tuple[list[float], list[int]], tid: int) -> None:
    values, ids = case
    enc = ArrayCommandEncoder(NODE, ids)
    enc.transfer_id = tid
    got = [(f.can_id, f.data) for f in enc.encode(values)]
    assert got == dronecan_frames(values, tuple(ids), tid)


@settings(max_examples=300, deadline=None)
@given(st.lists(PITCH, min_size=4, max_size=4), st.integers(0, 31))
def test_array_command_decodes_as_dronecan_does(values: list[float], tid: int) -> None:
    frames = dronecan_frames(values, (1, 2, 3, 4), tid)
    r = Reassembler((ARRAY_COMMAND_DTID,))
    got = [r.feed(can_id, data) for can_id, data in frames]
    assert got[:-1] == [None] * (len(frames) - 1)
    ours = got[-1]
    assert ours is not None and ours.transfer_id == tid and ours.source_node_id == NODE
    tr = transport.Transfer()
    tr.from_frames([transport.Frame(c, d) for c, d in frames])
    assert array_command_entries(ours.payload) == array_command_entries(tr.payload)


@given(st.booleans(), st.integers(0, 31))
def test_arming_status_frames_are_dronecans(armed: bool, tid: int) -> None:
    enc = ArmingStatusEncoder(NODE)
    enc.transfer_id = tid
    got = [(f.can_id, f.data) for f in enc.encode(armed)]
    msg = ARMING_STATUS(status=255 if armed else 0)
    tr = transport.Transfer(transfer_id=tid, source_node_id=NODE, payload=msg, transfer_priority=16)
    assert got == [(int(f.message_id), bytes(f.bytes)) for f in tr.to_frames()]
    decoded = Reassembler((ARMING_STATUS_DTID,)).feed(*got[0])
    assert decoded is not None and decoded.payload.status == (255 if armed else 0)


@given(st.binary(max_size=64))
def test_transfer_crc_is_dronecans(payload: bytes) -> None:
    base = int(ARRAY_COMMAND.base_crc)
    assert transfer_crc(payload, base) == dsdl_common.crc16_from_bytes(payload, initial=base)


def test_array_command_of_odd_length_is_a_decode_drop() -> None:
    r = Reassembler((ARRAY_COMMAND_DTID,))
    can_id = dronecan_frames([0.1], (1,), 0)[0][0]
    # a single-frame transfer of three bytes: not a whole command
    assert r.feed(can_id, b"\x01\x01\x00" + bytes((0xC0,))) is None
    assert [d.value for d in r.drops] == ["decode"]
