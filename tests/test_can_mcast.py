"""DroneCAN's UDP multicast CAN (``mcast:N``): the datagram format against the C layout,
the python-can bus on real sockets, the nodes' NodeStatus / GetNodeInfo / actuator Status,
and ``heli-sitl can monitor``.

Multicast only inside a private network namespace each test makes (``unshare --net``, lo
up, 224.0.0.0/4 routed on lo): the roles run as ``python tests/test_can_mcast.py ROLE OUT
PARENT_NETNS`` in that namespace, and refuse to run in the test's own. The format and node
tests that need no multicast use python-can's ``virtual`` bus in this process.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import dronecan
import pytest
from dronecan import transport
from dronecan.dsdl.common import crc16_from_bytes
from netns import NETNS_SETUP, unshare_reason

from autopilot.links.can_servo import AUTOPILOT_NODE_NAME, CanServoSender
from heli_common.vehicle.airframe import PitchLimits
from heli_common.wire.can.bus import CanBus, CanBusConfig, parse_bus_spec
from heli_common.wire.can.dronecan_codec import DronecanDriver, float16_round
from heli_common.wire.can.mcast import (
    MCAST_MAGIC,
    MCAST_PORT,
    McastFrame,
    crc16_ccitt,
    decode_datagram,
    encode_datagram,
    group_of,
    parse_channel,
)
from heli_common.wire.can.monitor import TransferMonitor, transfer_line
from heli_common.wire.can.node import (
    ACTUATOR_STATUS,
    GET_NODE_INFO,
    ActuatorStatusEncoder,
    NodeIdentity,
    NodeInfoResponder,
    ServiceRequest,
    get_node_info_request,
    node_status_bytes,
)
from heli_plant.can_endpoint import DEFAULT_PLANT_NODE_ID, SERVOS_NODE_NAME, CanServoEndpoint

LIMITS = PitchLimits((-0.6, 0.6), (-0.8, 0.8), (-0.5, 0.5), (-0.5, 0.5))
U1 = (0.1, -0.2, 0.3, -0.05)
ME = str(Path(__file__).resolve())
_ids = itertools.count()


def _crc_bitwise(data: bytes) -> int:
    """CRC-16-CCITT written out as libcanard's drivers/mcast/mcast.c loops it."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


# ------------------------------------------------------------------ the format, no sockets


def test_crc_is_ccitt_false() -> None:
    assert crc16_ccitt(b"123456789") == 0x29B1 == _crc_bitwise(b"123456789")
    blob = bytes(range(256)) * 3
    assert crc16_ccitt(blob) == _crc_bitwise(blob) == crc16_from_bytes(blob)


def test_header_matches_the_c_struct_built_by_hand() -> None:
    """struct PACKED mcast_pkt {uint16 magic; uint16 crc; uint16 flags; uint32 message_id;
    uint8 data[]} little-endian, crc over flags..data, message_id with bit 31 = extended."""
    can_id, data = 0x1003F20A, bytes((1, 2, 3, 4, 5, 6, 7, 0xC5))
    body = bytes((0x00, 0x00)) + bytes((0x0A, 0xF2, 0x03, 0x10 | 0x80)) + data  # flags, id | EFF
    crc = _crc_bitwise(body)
    by_hand = bytes((0x34, 0x29, crc & 0xFF, crc >> 8)) + body
    assert encode_datagram(McastFrame(can_id, data)) == by_hand
    assert len(by_hand) == 10 + 8
    assert decode_datagram(by_hand) == McastFrame(can_id, data, True, False, False, False)
    # pydronecan's driver packs it so: struct.pack("<HI", flags, id | 1 << 31) + data, its CRC
    py = struct.pack("<HI", 0, can_id | 1 << 31) + data
    assert struct.pack("<HH", MCAST_MAGIC, crc16_from_bytes(py)) + py == by_hand


def test_fd_standard_remote_and_error_frames_round_trip() -> None:
    fd = McastFrame(0x155, bytes(range(64)), extended=True, fd=True)
    pkt = encode_datagram(fd)
    assert len(pkt) == 74 and struct.unpack_from("<H", pkt, 4)[0] == 1  # flags bit 0
    assert decode_datagram(pkt) == fd
    std = McastFrame(0x7FF, b"\x01", extended=False)
    assert struct.unpack_from("<I", encode_datagram(std), 6)[0] == 0x7FF  # no flag bits
    assert decode_datagram(encode_datagram(std)) == std
    rtr = McastFrame(0x123, b"", remote=True)
    assert struct.unpack_from("<I", encode_datagram(rtr), 6)[0] == 0x123 | 1 << 31 | 1 << 30
    assert decode_datagram(encode_datagram(rtr)) == rtr
    err = McastFrame(0x4, b"", error=True)
    assert decode_datagram(encode_datagram(err)) == err
    for bad in (McastFrame(1, bytes(9)), McastFrame(1, bytes(9), fd=True),
                McastFrame(0x800, b"", extended=False), McastFrame(1 << 29, b"")):  # fmt: skip
        with pytest.raises(ValueError):
            encode_datagram(bad)


def _bad_datagrams() -> dict[str, bytes]:
    good = encode_datagram(McastFrame(0x1234, b"\x01\x02\x03"))
    no_fd_9 = struct.pack("<HI", 0, 1 << 31) + bytes(9)
    std_big = struct.pack("<HI", 0, 0x800) + b""
    return {
        "bad_short": good[:9],
        "bad_magic": b"\x35\x29" + good[2:],
        "bad_crc": good[:2] + bytes((good[2] ^ 1,)) + good[3:],
        "bad_oversized": struct.pack("<HH", MCAST_MAGIC, crc16_ccitt(bytes(71))) + bytes(71),
        "bad_frame": struct.pack("<HH", MCAST_MAGIC, crc16_ccitt(no_fd_9)) + no_fd_9,
        "bad_frame ": struct.pack("<HH", MCAST_MAGIC, crc16_ccitt(std_big)) + std_big,
    }


def test_bad_datagrams_are_named() -> None:
    for reason, pkt in _bad_datagrams().items():
        assert decode_datagram(pkt) == reason.strip(), reason


def test_bus_spec_and_channels() -> None:
    m = parse_bus_spec("mcast")
    assert (m.interface, m.channel, m.port, m.describe()) == ("mcast", "0", MCAST_PORT, "mcast:0")
    assert parse_bus_spec("mcast:3").describe() == "mcast:3" and group_of(3) == "239.65.82.3"
    assert parse_bus_spec("mcast:1:50000").port == 50000
    assert CanBusConfig("mcast").port == MCAST_PORT
    assert CanBusConfig("udp_multicast").port == 43113  # unchanged
    assert [parse_channel(c) for c in (0, "7", "mcast:2", "mcast", None)] == [0, 7, 2, 0, 0]
    for bad in ("mcast:10", "mcast:x", "mcast:-1"):
        with pytest.raises(ValueError):
            parse_bus_spec(bad)
    with pytest.raises(ValueError, match="mcast"):
        parse_bus_spec("candy:0")
    assert "dronecan_mcast" in can.interfaces.VALID_INTERFACES  # the entry point


# ------------------------------------------------------------------ nodes, on a virtual bus


def test_actuator_status_bytes_are_dronecans() -> None:
    enc = ActuatorStatusEncoder(20)
    for aid, pos in ((1, 0.25), (4, -0.123), (2, math.nan)):
        ours = enc.encode(aid, pos)
        ref = transport.Transfer(
            transfer_id=ours and enc.transfer_id - 1, source_node_id=20, transfer_priority=enc.priority,
            payload=ACTUATOR_STATUS(actuator_id=aid, position=pos, force=math.nan, speed=math.nan,
                                    power_rating_pct=127),
        )  # fmt: skip
        theirs = [(int(f.message_id), bytes(f.bytes)) for f in ref.to_frames()]
        assert [(f.can_id, f.data) for f in ours] == theirs


def test_get_node_info_answer_and_status_bytes_are_dronecans() -> None:
    """The answer (dronecan's serialisation done once, the status put in front per request)
    equals dronecan's own serialisation of the whole response, frame for frame."""
    ident = NodeIdentity("org.heli-tlc-sitl.servos", (0, 1))
    responder = NodeInfoResponder(20, ident)
    for uptime, health, mode in ((0, 0, 0), (12345, 1, 0), (2**32 - 1, 3, 7)):
        ours = responder.respond(ServiceRequest(100, 7, 30), uptime, health=health, mode=mode)
        r = GET_NODE_INFO.Response()
        r.status.uptime_sec, r.status.health, r.status.mode = uptime, health, mode
        r.software_version.major, r.software_version.minor = 0, 1
        r.hardware_version.unique_id = list(ident.unique_id_for(20))
        r.name = ident.name
        ref = transport.Transfer(transfer_id=7, source_node_id=20, dest_node_id=100, payload=r,
                                 transfer_priority=30, service_not_message=True)  # fmt: skip
        theirs = [(int(f.message_id), bytes(f.bytes)) for f in ref.to_frames()]
        assert [(f.can_id, f.data) for f in ours] == theirs
        st = dronecan.uavcan.protocol.NodeStatus(uptime_sec=uptime, health=health, mode=mode, sub_mode=5,
                                                 vendor_specific_status_code=0xABCD)  # fmt: skip
        assert node_status_bytes(uptime, health, mode, 5, 0xABCD) == transport.Transfer(payload=st).payload


def _spin_until(node: Any, done: Callable[[], bool], tick: Callable[[], None], limit_s: float = 3.0) -> None:
    t0 = time.monotonic()
    while not done() and time.monotonic() - t0 < limit_s:
        tick()
        node.spin(0)


def test_both_nodes_answer_get_node_info_and_publish_status() -> None:
    """A dronecan Node (its own transfer manager) asks both bench nodes for their info and
    hears the servos' Status, on one virtual bus."""
    ch = f"test-can-mcast-nodes-{os.getpid()}-{next(_ids)}"
    infos: dict[int, Any] = {}
    statuses: dict[int, float] = {}
    node = dronecan.node.Node(DronecanDriver(CanBus(CanBusConfig("virtual", ch))), node_id=100)
    node.add_handler(ACTUATOR_STATUS,
                     lambda e: statuses.__setitem__(e.message.actuator_id, e.message.position))
    with (
        CanServoSender(CanBusConfig("virtual", ch), node_id=10) as tx,
        CanServoEndpoint(CanBusConfig("virtual", ch), limits=LIMITS, actuator_status_period_s=0.05) as ep,
    ):
        t = [0.0]

        def tick() -> None:
            t[0] += 0.01
            tx.send(U1, t[0])
            ep.poll(t[0])

        for nid in (10, DEFAULT_PLANT_NODE_ID):
            node.request(dronecan.uavcan.protocol.GetNodeInfo.Request(), nid,
                         lambda e, nid=nid: infos.__setitem__(nid, e and e.response))  # fmt: skip
        _spin_until(node, lambda: len(infos) == 2 and len(statuses) == 4, tick)
        assert tx.stats["node_info_answered"] == 1 and ep.node_stats["node_info_answered"] == 1
        assert ep.node_stats["node_status_sent"] >= 1 and ep.node_stats["actuator_status_sent"] >= 1
        # the other node's request and answer are foreign traffic to the servos; their own is not
        assert ep.stats["foreign_type"] == 1 + 10 and ep.stats["commands_applied"] > 0
    node.close()
    assert infos[10] is not None and infos[DEFAULT_PLANT_NODE_ID] is not None
    assert infos[10].name.decode() == AUTOPILOT_NODE_NAME
    assert infos[DEFAULT_PLANT_NODE_ID].name.decode() == SERVOS_NODE_NAME
    assert infos[10].software_version.minor == 1  # heli-tlc-sitl 0.1
    ids = {bytes(i.hardware_version.unique_id.to_bytes()) for i in infos.values()}
    assert len(ids) == 2 and all(any(u) for u in ids)  # distinct, non-zero
    assert statuses == {i + 1: pytest.approx(float16_round(u), abs=0) for i, u in enumerate(U1)}


def test_servos_report_silence_and_unknown_positions() -> None:
    """Before any command: Status positions NaN (unknown); NodeStatus health WARNING once
    the command stream is silent (timeout), OK while commands flow."""
    ch = f"test-can-mcast-silent-{os.getpid()}-{next(_ids)}"
    mon = TransferMonitor()
    seen: list[Any] = []
    with (
        CanBus(CanBusConfig("virtual", ch)) as spy,
        CanServoEndpoint(CanBusConfig("virtual", ch), limits=LIMITS, timeout_s=0.1) as ep,
        CanServoSender(CanBusConfig("virtual", ch), node_id=10) as tx,
    ):
        ep.poll(0.0)  # first poll: not silent yet
        ep.poll(1.5)  # 1.5 s without a command: silent
        tx.send(U1, 0.0)
        ep.poll(3.0)  # a command just applied
        for _ in range(100):
            msg = spy.recv(0.0)
            if msg is None:
                break
            tr = mon.feed(msg)
            if tr is not None and tr.source_node_id == DEFAULT_PLANT_NODE_ID:
                seen.append(tr)
        assert ep.node_stats["node_status_sent"] == 3 and ep.node_stats["own_frames"] == 0
    health = [int(t.payload.health) for t in seen if t.type_name == "uavcan.protocol.NodeStatus"]
    assert health == [0, 1, 0]
    positions = [float(t.payload.position) for t in seen if t.type_name.endswith("actuator.Status")]
    assert len(positions) == 12 and all(math.isnan(p) for p in positions[:8])
    assert positions[8:] == [float16_round(u) for u in U1]


def test_get_node_info_request_test_is_exact() -> None:
    req = transport.Transfer(transfer_id=7, source_node_id=100, dest_node_id=20, transfer_priority=30,
                             payload=dronecan.uavcan.protocol.GetNodeInfo.Request(),
                             service_not_message=True, request_not_response=True)  # fmt: skip
    (f,) = req.to_frames()
    got = get_node_info_request(int(f.message_id), bytes(f.bytes), 20)
    assert got is not None and tuple(got) == (100, 7, 30)
    assert get_node_info_request(int(f.message_id), bytes(f.bytes), 21) is None  # not for us
    assert get_node_info_request(int(f.message_id) & ~0x8000, bytes(f.bytes), 20) is None  # response


def test_monitor_decodes_every_kind_of_transfer() -> None:
    ch = f"test-can-mcast-mon-{os.getpid()}-{next(_ids)}"
    lines: list[str] = []
    mon = TransferMonitor()
    with (
        CanBus(CanBusConfig("virtual", ch)) as spy,
        CanServoSender(CanBusConfig("virtual", ch), node_id=10) as tx,
        CanServoEndpoint(CanBusConfig("virtual", ch), limits=LIMITS) as ep,
        CanBus(CanBusConfig("virtual", ch)) as asker,
    ):
        tx.send(U1, 0.0, armed=True)
        ep.poll(0.0)
        req = transport.Transfer(transfer_id=3, source_node_id=100, dest_node_id=10, transfer_priority=30,
                                 payload=dronecan.uavcan.protocol.GetNodeInfo.Request(),
                                 service_not_message=True, request_not_response=True)  # fmt: skip
        for f in req.to_frames():
            asker.send(int(f.message_id), bytes(f.bytes))
        tx.send(U1, 0.01)
        for _ in range(200):
            msg = spy.recv(0.0)
            if msg is None:
                break
            tr = mon.feed(msg)
            if tr is not None:
                lines.append(transfer_line(tr))
    text = "\n".join(lines)
    print(text)
    assert mon.errors == 0 and mon.skipped == 0
    for want in ("10 -> *    uavcan.equipment.actuator.ArrayCommand", "uavcan.protocol.NodeStatus",
                 "uavcan.equipment.safety.ArmingStatus", "20 -> *    uavcan.equipment.actuator.Status",
                 "100 -> 10   uavcan.protocol.GetNodeInfo request",
                 "10 -> 100  uavcan.protocol.GetNodeInfo response",
                 f"name='{AUTOPILOT_NODE_NAME}'", "actuator_id=1, command_type=1, command_value=0.0999756",
                 "unique_id=0x"):  # fmt: skip
        assert want in text, want


# ------------------------------------------------------------------ real sockets, in a netns


def _in_netns(role: str, out: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    parent = os.readlink("/proc/self/ns/net")
    script = f"{NETNS_SETUP} && exec {sys.executable} {ME} {role} {out} {parent}"
    return subprocess.run(["unshare", "--net", "--", "bash", "-c", script],
                          capture_output=True, text=True, timeout=timeout_s)  # fmt: skip


@pytest.mark.netns
def test_two_buses_in_a_namespace_exchange_frames(tmp_path: Path) -> None:
    proc = _in_netns("exchange", tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads((tmp_path / "exchange.json").read_text())
    assert r["a_got"] == [[0x10203, "0a0b"], [0x1FFFFFFF, "ff" * 8]]  # what b sent, in order
    assert r["b_got"] == [[0x155, "01"]]
    assert r["a_own"] is None and r["own_seen"] == [0x777]  # own frames only when asked
    assert r["bus1_got"] is None  # bus 1 is another group
    assert r["b_heard_own_bus"] == [0x777, ""]
    assert r["fd"] == [0x155, 64, True]
    assert r["a_stats"]["rx_own"] >= 1 and r["a_stats"]["tx_errors"] == 0


@pytest.mark.netns
def test_bad_datagrams_are_counted_and_dropped(tmp_path: Path) -> None:
    proc = _in_netns("bad", tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads((tmp_path / "bad.json").read_text())
    assert r["delivered"] == [[0x42, "07"]]  # only the good one, sent last
    s = r["stats"]
    bad = (s["bad_short"], s["bad_magic"], s["bad_crc"], s["bad_oversized"], s["bad_frame"])
    assert bad == (1, 1, 1, 1, 2)


def test_monitor_type_filter_takes_a_full_name_or_its_last_parts() -> None:
    from heli_sitl.cli import _is_listed

    name = "uavcan.equipment.actuator.ArrayCommand"
    assert _is_listed(name, ["ArrayCommand"]) and _is_listed(name, ["actuator.ArrayCommand"])
    assert _is_listed(name, [name]) and _is_listed(name, ["NodeStatus", "ArrayCommand"])
    assert not _is_listed(name, ["Command"]) and not _is_listed(name, ["NodeStatus"])


@pytest.mark.netns
def test_can_monitor_lists_a_senders_traffic(tmp_path: Path) -> None:
    proc = _in_netns("monitor", tmp_path, timeout_s=90.0)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = (tmp_path / "monitor.out").read_text().splitlines()
    print("\n".join(out[:12]))
    assert len(out) == 12  # --count 12: 12 transfer lines, then it exits
    assert any("10 -> *    uavcan.equipment.actuator.ArrayCommand" in line for line in out)
    assert any("uavcan.protocol.NodeStatus" in line for line in out)
    assert "transfers" in (tmp_path / "monitor.err").read_text()


# ------------------------------------------------------------------ roles (in the namespace)


def _hexmsg(m: can.Message | None) -> list[Any] | None:
    return None if m is None else [m.arbitration_id, bytes(m.data).hex()]


def _role_exchange(out: Path) -> int:
    a = can.Bus(interface="dronecan_mcast", channel=0)  # through python-can's entry point
    b = can.Bus(interface="dronecan_mcast", channel="mcast:0")
    c = can.Bus(interface="dronecan_mcast", channel=1)
    own = can.Bus(interface="dronecan_mcast", channel=0, receive_own_messages=True)
    try:
        b.send(can.Message(arbitration_id=0x10203, data=b"\x0a\x0b"))
        b.send(can.Message(arbitration_id=0x1FFFFFFF, data=b"\xff" * 8))
        a.send(can.Message(arbitration_id=0x155, data=b"\x01"))
        a_got = [_hexmsg(a.recv(1.0)), _hexmsg(a.recv(1.0))]
        b_got = [_hexmsg(b.recv(1.0))]
        a_own = _hexmsg(a.recv(0.2))
        own.send(can.Message(arbitration_id=0x777, data=b""))
        own_seen = [m.arbitration_id for m in iter(lambda: own.recv(0.3), None) if m.arbitration_id == 0x777]
        b_heard_own_bus = _hexmsg(b.recv(1.0))  # own is another node: b hears its frame
        a.send(can.Message(arbitration_id=0x155, data=bytes(64), is_fd=True))
        m = b.recv(1.0)
        result = {
            "a_got": a_got, "b_got": b_got, "a_own": a_own, "own_seen": own_seen,
            "bus1_got": _hexmsg(c.recv(0.3)),
            "fd": None if m is None else [m.arbitration_id, len(m.data), m.is_fd],
            "a_stats": a.stats, "b_heard_own_bus": b_heard_own_bus,
        }  # fmt: skip
    finally:
        for bus in (a, b, c, own):
            bus.shutdown()
    (out / "exchange.json").write_text(json.dumps(result))
    return 0


def _role_bad(out: Path) -> int:
    with can.Bus(interface="dronecan_mcast", channel=0) as bus:
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        raw.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        for pkt in [*_bad_datagrams().values(), encode_datagram(McastFrame(0x42, b"\x07"))]:
            raw.sendto(pkt, (group_of(0), MCAST_PORT))
        raw.close()
        delivered = [_hexmsg(m) for m in iter(lambda: bus.recv(0.5), None)]
        (out / "bad.json").write_text(json.dumps({"delivered": delivered, "stats": bus.stats}))
    return 0


def _role_monitor(out: Path) -> int:
    cli = [sys.executable, "-m", "heli_sitl.cli", "can", "monitor", "mcast:0", "--count", "12",
           "--duration", "60"]
    with (out / "monitor.out").open("w") as fo, (out / "monitor.err").open("w") as fe:
        mon = subprocess.Popen(cli, stdout=fo, stderr=fe)
        try:
            deadline = time.monotonic() + 60.0
            while "listening" not in (out / "monitor.err").read_text() and time.monotonic() < deadline:
                time.sleep(0.05)
            with CanServoSender("mcast:0", node_id=10) as tx:
                k = 0
                while mon.poll() is None and time.monotonic() < deadline:
                    tx.send(U1, 0.01 * k, armed=True)  # a 100 Hz tick, its status each 1 s of it
                    k += 1
                    time.sleep(0.002)
            return mon.wait(timeout=10)
        finally:
            if mon.poll() is None:
                mon.kill()


if __name__ == "__main__":
    role, out_dir, parent_netns = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
    if os.readlink("/proc/self/ns/net") == parent_netns:
        print("refusing: not inside a private network namespace", file=sys.stderr)
        sys.exit(3)
    roles = {"exchange": _role_exchange, "bad": _role_bad, "monitor": _role_monitor}
    sys.exit(roles[role](out_dir))
