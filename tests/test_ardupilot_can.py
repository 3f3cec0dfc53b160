"""ArduPilot's helicopter firmware drives the plant's servos over DroneCAN only
(`heli-sitl up --firmware ardupilot --servo-link can`): the CAN-enabled `arducopter-heli-can`
SITL binary from ../shared/ardupilot (skipped with a message where it is not) sends its servo
outputs as uavcan.equipment.actuator.ArrayCommand on SITL's multicast CAN (`mcast:0`), the
plant flies them through the swashplate and only cross-checks the JSON frame's PWMs. The
flight is tests/ardupilot_flight.py's, run by this file's ``__main__`` inside a private
network namespace made by the test (`unshare --net`, `lo` up, 224.0.0.0/4 routed on it): the
firmware opens TCP 5760-5763 and UDP 9002, and the bus is multicast.

``python tests/test_ardupilot_can.py OUT PLANT [--hover-only] [--servo-link json]`` (inside
a namespace) is also the by-hand run; ``--servo-link json`` flies the same flight over the
JSON frame's PWMs (the plain firmware), the comparison."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent


def _result(out: Path) -> tuple[dict[str, Any], dict[str, np.ndarray], dict[str, Any]]:
    from ground.plots import read_csv_columns

    res = json.loads((out / "result.json").read_text())
    stats = json.loads((out / "plant-stats.json").read_text())
    return res, read_csv_columns(out / "plant.csv"), stats


def _ardupilot_command(pulses: dict[int, int], tid: int, command_type: int = 0) -> list[Any]:
    """The frames of an ArrayCommand as AP_DroneCAN::SRV_send_actuator builds it (node 10,
    one command per channel, ``(pulse - 1000) / 500 - 1`` as float16)."""
    import struct

    from heli_common.wire.can.dronecan_codec import (
        ARRAY_COMMAND,
        ARRAY_COMMAND_DTID,
        float16_bits,
        frames_of_transfer,
        message_can_id,
    )

    payload = b"".join(
        struct.pack("<BBH", ch, command_type, float16_bits(min(max((p - 1000) / 500 - 1, -1.0), 1.0)))
        for ch, p in pulses.items()
    )
    base_crc = int(ARRAY_COMMAND()._type.base_crc)
    return frames_of_transfer(message_can_id(8, ARRAY_COMMAND_DTID, 10), payload, tid, base_crc)


def test_every_pulse_comes_back_from_the_firmwares_unitless_value() -> None:
    """The firmware sends ``constrain((pulse - 1000) / 500 - 1, -1, 1)`` as a float16: every
    whole microsecond of 1000-2000 comes back exactly (float16 resolves 0.25 us there)."""
    from heli_common.wire.can.dronecan_codec import float16_round
    from heli_plant.ardupilot_can import pwm_from_unitless, servo_ranges
    from heli_sitl.launch.ardupilot import can_parm_files

    for pulse in range(1000, 2001):
        assert round(pwm_from_unitless(float16_round((pulse - 1000) / 500 - 1))) == pulse
    # the bench's SERVO1-4 and 8: 1000 / 1500 / 2000, where -1, 0, +1 are also MIN, TRIM, MAX
    ranges = servo_ranges(can_parm_files("gavrilets"))
    assert all(r.matches_unitless() for r in ranges.values()), ranges


def test_the_servo_node_takes_ardupilots_commands_and_reports_healthy() -> None:
    """On a virtual bus: ArduPilot's ArrayCommand (type 0, ids 1-4 and 8) held as PWMs; a
    command of another type refused whole, one without channel 8 refused; the node's
    NodeStatus is HEALTH_OK / operational (the firmware arms only then) and it answers
    GetNodeInfo; other types are counted by data type id."""
    import uuid

    from heli_common.wire.can.bus import open_bus
    from heli_common.wire.can.dronecan_codec import NodeStatusEncoder, parse_can_id
    from heli_plant.ardupilot_can import ArduPilotCanServos, ServoRange

    chan = f"virtual:apcan-{uuid.uuid4().hex}"
    ranges = dict.fromkeys((1, 2, 3, 4, 8), ServoRange(1000, 1500, 2000))
    with open_bus(chan) as firmware, ArduPilotCanServos(chan, ranges) as servos:
        assert servos.poll(0.0) is None
        pulses = {1: 1459, 2: 1460, 3: 1459, 4: 1500, 8: 1000}
        for f in _ardupilot_command(pulses, 0):
            firmware.send(f.can_id, f.data)
        for f in NodeStatusEncoder(10).encode(3):
            firmware.send(f.can_id, f.data)
        assert servos.poll(0.01) == pulses
        for f in _ardupilot_command({**pulses, 1: 1700}, 1, command_type=1):  # not unitless
            firmware.send(f.can_id, f.data)
        for f in _ardupilot_command({1: 1700, 2: 1500, 3: 1500, 4: 1500}, 2):  # no channel 8
            firmware.send(f.can_id, f.data)
        assert servos.poll(0.02) == pulses
        c = servos.stats.counts
        assert (c["commands_applied"], c["wrong_command_type"], c["missing_channel"]) == (1, 1, 1)
        assert servos.stats.types[1010] == 3 and servos.stats.types[341] == 1
        # GetNodeInfo for node 20, from node 10 (a single frame: the request is empty)
        firmware.send((30 << 24) | (1 << 16) | 0x8000 | (20 << 8) | 0x80 | 10, bytes((0xC0 | 5,)))
        servos.poll(1.5)
        heard = []
        for _ in range(200):
            msg = firmware.recv(0.05)
            if msg is None:
                break
            heard.append(msg)
        statuses = [m for m in heard if parse_can_id(m.arbitration_id).data_type_id == 341
                    and not parse_can_id(m.arbitration_id).service]  # fmt: skip
        # health OK (0), mode OPERATIONAL (0): the health/mode byte after the uptime
        assert statuses and all(m.data[4] >> 6 == 0 and (m.data[4] >> 3) & 7 == 0 for m in statuses)
        assert servos.stats.node_info_answered == 1
        assert any(parse_can_id(m.arbitration_id).service for m in heard)


def test_servo_link_can_without_the_can_firmware_says_so(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`up --firmware ardupilot --servo-link can` where the DroneCAN build is missing: exit 2
    and a message naming what to give; the JSON firmware alone does not stand in for it."""
    from heli_sitl import cli
    from heli_sitl.launch import ardupilot

    monkeypatch.delenv(ardupilot.ENV_CAN_BIN, raising=False)
    monkeypatch.setattr(ardupilot, "SHARED_CAN_BIN", Path("/nonexistent/arducopter-heli-can"))
    assert cli.main(["up", "--firmware", "ardupilot", "--servo-link", "can"]) == 2
    err = capsys.readouterr().err
    assert "--servo-link can needs arducopter-heli built with DroneCAN" in err
    assert "ARDUPILOT_HELI_CAN_BIN" in err
    assert cli.main(["up", "--servo-link", "can"]) == 2  # the bench's own firmware: not here
    assert "for --firmware ardupilot" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.netns
def test_ardupilot_flies_the_rotor_plant_with_its_servos_on_dronecan(tmp_path: Path) -> None:
    """`up --firmware ardupilot --servo-link can` on the rotor plant, in a private network
    namespace: ArduPilot arms with the plant's servo node on its bus (HEALTH_OK, operational),
    runs the rotor up, takes off to 5 m, hovers and flies the paper's spiral in GUIDED with
    the plant's swashplate, tail and rotor taken from its DroneCAN ArrayCommand, then lands
    and disarms; the bounds are tests/test_ardupilot_sitl.py's. The plant's stats show the
    bus drove every frame after the first command, the firmware's command type (0) and
    actuator ids (1, 2, 3, 4, 8), and the cross-check against the JSON frame."""
    from netns import skip_without_firmware_netns

    from ground.guided import truth_tracking
    from heli_sitl.launch.ardupilot import FirmwareNotFoundError, find_firmware

    skip_without_firmware_netns()
    try:
        find_firmware(None, can=True)
    except FirmwareNotFoundError as exc:
        pytest.skip(f"ArduPilot's SITL binary with DroneCAN is not here: {exc}")
    out = tmp_path / "gavrilets"
    env = {**os.environ, "PARENT_NETNS": os.readlink("/proc/self/ns/net")}
    t0 = time.monotonic()
    proc = subprocess.Popen(
        ["unshare", "--net", "--map-root-user", sys.executable, str(Path(__file__).resolve()), str(out),
         "gavrilets"],
        env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        rc = proc.wait(timeout=480)
    except subprocess.TimeoutExpired:
        # SIGINT to the flight (unshare runs it in place): its finally stops `up` and the firmware
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
        pytest.fail("the flight over DroneCAN took more than 480 s of wall time")
    assert rc == 0
    res, truth, stats = _result(out)
    print(f"flight: {time.monotonic() - t0:.0f} s of wall time")
    print({k: v for k, v in res.items() if k not in ("texts", "params", "estimate_ned", "mavproxy")})
    print("plant stats:", json.dumps({k: stats[k] for k in ("frames", "crosscheck", "can")}))
    assert "error" not in res, (res.get("error"), res.get("texts"))
    assert res["heartbeat"] == [4, 3]
    modes = res["modes"]
    assert 4 in modes and modes[-1] == 9  # GUIDED, then LAND

    # the servos came from the bus: every frame after the first command, none refused
    can, cc = stats["can"], stats["crosscheck"]
    assert can["command_types"] == [0] and can["actuator_ids"] == [1, 2, 3, 4, 8], can
    assert can["commands_applied"] > 1000 and can["wrong_command_type"] == can["out_of_range"] == 0, can
    assert can["missing_channel"] == can["crc"] == 0, can
    # a transfer with a frame missing now and then (5 % measured), never a corrupt one
    assert can["missing_frame"] < 0.1 * can["types"]["1010"], can
    assert can["node_status_sent"] > 10, can  # the servos' node (HEALTH_OK): the firmware armed with it
    assert cc["frames"] + cc["frames_before_command"] == stats["frames"]
    assert cc["frames_before_command"] < 1200 * 20, cc  # the first command 6.8-8.1 s into the physics
    # in flight the plant paces the lockstep to the bus (heli_plant/ardupilot_backend.py: a frame
    # waits up to 2 ms of wall for a command while the newest is over 20 ms of physics old), so
    # the firmware's commands come at 50 Hz of physics or more: 66-101 Hz on an idle machine,
    # 49.0 in two loaded runs (its CAN thread starved, the pacing's floor), and none is held
    # long (0.038 and 0.051 s measured there)
    rate = cc["rotor_on_commands"] / cc["rotor_on_s"]
    print(f"in flight: {rate:.0f} commands/s of physics, held at most {cc['rotor_on_max_stale_s']:.3f} s")
    assert rate > 45.0 and cc["rotor_on_max_stale_s"] < 0.15, cc
    # the JSON frame, cross-checked: in flight the bus lags it (a few us); large disagreements rare
    assert cc["disagree_large_frames"] < 0.05 * cc["frames"], cc  # 0.1-1.1 % measured

    t = truth["t_s"]
    pos = np.column_stack([truth["x_m"], truth["y_m"], truth["z_m"]])
    t_takeoff, t_hover_end = float(res["t_takeoff"]), float(res["t_hover_end"])
    k0 = int(np.searchsorted(t, t_takeoff))
    target = np.array([pos[k0, 0], pos[k0, 1], 5.0])
    hover = (t > t_hover_end - 15.0) & (t <= t_hover_end)
    err = np.linalg.norm(pos[hover] - target, axis=1)
    rms = float(np.sqrt(np.mean(err**2)))
    print(f"hover over 15 s: RMS {rms:.3f} m, max {err.max():.3f} m")
    assert err.max() < 0.1 and rms < 0.06  # tests/test_ardupilot_sitl.py's bounds
    rotor, on = truth["rotor_rad_s"], truth["interlock"] > 0.5
    assert rotor[0] == 0.0 and np.abs(rotor[hover] - 167.0).max() < 1.0  # run up by channel 8 on the bus
    assert not on[-1] and res["disarmed_after_landing"] and pos[-1, 2] < 0.05

    assert res["guided_exit"] == 0, res["guided_output"]
    track = truth_tracking(out / "track.csv", out / "plant.csv", (45.0, 120.0))
    print(f"the paper's trajectory in GUIDED over DroneCAN, truth: {track.line()}")
    assert track.samples > 7000
    assert track.rms_m < 0.28 and track.max_m < 0.5, res["guided_output"]  # tests/test_ardupilot_sitl.py's


def _flight_in_namespace(argv: list[str]) -> int:
    """Inside the namespace: route multicast on loopback, then tests/ardupilot_flight.py's
    flight with ``--servo-link can`` (or ``json``) added to its `up` command."""
    if os.readlink("/proc/self/ns/net") == os.environ.get("PARENT_NETNS"):
        print("refusing: not inside a private network namespace", file=sys.stderr)
        return 3
    link = "can"
    if "--servo-link" in argv:
        i = argv.index("--servo-link")
        link = argv[i + 1]
        del argv[i : i + 2]
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    subprocess.run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
    sys.path.insert(0, str(TESTS))
    import ardupilot_flight as flight

    class _Popen(subprocess.Popen):  # type: ignore[type-arg]
        def __init__(self, args: Any, *a: Any, **kw: Any) -> None:
            if isinstance(args, list) and "up" in args and "--firmware" in args:
                args = [*args, "--servo-link", link]
            super().__init__(args, *a, **kw)

    # only the flight script's own subprocess calls see the shim (subprocess.run keeps its own)
    flight.subprocess = types.SimpleNamespace(**{**vars(subprocess), "Popen": _Popen})  # type: ignore[assignment]

    # the CAN build starts later (its DroneCAN start-up): its RC input, which sets the motor
    # interlock from RC8's mid-stick default, can appear after the flight's one interlock-low
    # command, and every arming attempt then fails ("Motor Interlock Enabled"; 1 flight in 4
    # measured). So each arming attempt is preceded by the interlock-low switch again.
    connect = flight.mavutil.mavlink_connection

    def _connection(*a: Any, **kw: Any) -> Any:
        conn = connect(*a, **kw)
        send = conn.mav.command_long_send

        def command_long_send(target_sys: int, target_comp: int, command: int, *rest: Any) -> Any:
            if command == 400 and rest[1:2] == (1,):  # MAV_CMD_COMPONENT_ARM_DISARM, arm
                send(target_sys, target_comp, 218, 0, 32, 0, 0, 0, 0, 0, 0)  # DO_AUX_FUNCTION interlock low
            return send(target_sys, target_comp, command, *rest)

        conn.mav.command_long_send = command_long_send
        return conn

    flight.mavutil = types.SimpleNamespace(**{**vars(flight.mavutil), "mavlink_connection": _connection})
    out = Path(argv[0])
    plant = argv[1] if len(argv) > 1 else "paper"
    return int(flight.main(out, plant, "--hover-only" not in argv))


if __name__ == "__main__":
    raise SystemExit(_flight_in_namespace(sys.argv[1:]))
