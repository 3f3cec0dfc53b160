"""No request can freeze the vehicle: every command is answered, and no child's output blocks it.

A ground station may ask for any message id (QGroundControl asks for several the vehicle
does not build while it connects). Each COMMAND_LONG addressed to the vehicle gets exactly
one COMMAND_ACK whatever its parameters, heartbeats keep flowing, and the vehicle still
flies afterwards. The launcher drains its children's stderr, so a child that writes a lot
never blocks on a full pipe.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import pytest
from ports import new_port
from test_ground_client import client, gwp, running_vehicle

from autopilot.params_table import SPECS
from ground.client import GroundClient
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink import modes as wm
from heli_common.wire.mavlink.udp import Message, mavlink2
from heli_sitl.launch.children import spawn

m2 = mavlink2
UNKNOWN_IDS = (299, 300, 397, 435, 436, 437, 12_900, 65_535, 16_777_215)  # not built / not defined
REPEATS = 3
BATCH = 16  # in flight at once: well inside the vehicle's socket buffer


def _requests() -> list[tuple[int, float, float]]:
    """(command, param1, param2) for every message id of the common dialect and a few more."""
    ids = sorted(set(m2.mavlink_map) | set(UNKNOWN_IDS))
    out: list[tuple[int, float, float]] = []
    for _ in range(REPEATS):
        for msg_id in ids:
            out.append((m2.MAV_CMD_REQUEST_MESSAGE, float(msg_id), 0.0))
            out.append((m2.MAV_CMD_SET_MESSAGE_INTERVAL, float(msg_id), 200_000.0))
            out.append((m2.MAV_CMD_SET_MESSAGE_INTERVAL, float(msg_id), 0.0))  # back to the default
    return out


def _send_and_count_acks(gc: GroundClient, reqs: list[tuple[int, float, float]]) -> dict[int, int]:
    """Send in batches and count the ACKs of each batch by result (an ACK does not echo
    the message id, so the count per batch is what is checked)."""
    acks: dict[int, int] = {}
    for start in range(0, len(reqs), BATCH):
        batch = reqs[start : start + BATCH]
        for cmd, p1, p2 in batch:
            gc.send(m2.MAVLink_command_long_message(1, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0))
        got = 0
        deadline = time.monotonic() + 5.0
        while got < len(batch) and time.monotonic() < deadline:
            m = gc.recv_match(lambda m: m.get_type() == "COMMAND_ACK" and gc.from_vehicle(m), 0.5)
            if m is not None:
                acks[int(m.result)] = acks.get(int(m.result), 0) + 1
                got += 1
        assert got == len(batch), f"batch at {start}: {got} of {len(batch)} acknowledged"
    return acks


@pytest.mark.slow
def test_every_message_request_is_answered_and_the_vehicle_still_flies(tmp_path: Path) -> None:
    reqs = _requests()
    with running_vehicle("--out", str(tmp_path)) as v, client(v.gcs_port) as gc:
        acks = _send_and_count_acks(gc, reqs)
        assert sum(acks.values()) == len(reqs)
        assert acks.get(m2.MAV_RESULT_FAILED, 0) == 0, acks  # no handler error
        assert acks.get(m2.MAV_RESULT_ACCEPTED, 0) > 0 and acks.get(m2.MAV_RESULT_DENIED, 0) > 0
        # heartbeats still flow, at about 1 Hz
        t0 = time.monotonic()
        beats = 0
        while time.monotonic() - t0 < 3.0:
            if gc.recv_match(lambda m: m.get_type() == "HEARTBEAT" and gc.from_vehicle(m), 0.5):
                beats += 1
        assert beats >= 2
        # and the vehicle still flies: a take-off to 2.5 m and a landing
        gc.upload_mission([gwp(0, 0.0, 0.0, 2.5, ms.CMD_TAKEOFF),
                           ms.MissionItem(1, ms.FRAME_GLOBAL_REL_INT, ms.CMD_LAND, z=0.0)])  # fmt: skip
        gc.arm()
        gc.start_mission()
        top = 0.0
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and top < 2.3:
            m: Message | None = gc.recv_match(
                lambda m: m.get_type() == "LOCAL_POSITION_NED" and gc.from_vehicle(m), 1.0
            )
            if m is not None:
                top = max(top, -float(m.z))
        assert top >= 2.3, f"climbed to {top:.2f} m only"
        assert v.proc.poll() is None
    # the launcher wrote each child's output to the run's directory
    assert (tmp_path / "logs" / "autopilot.log").is_file()
    assert (tmp_path / "logs" / "plant.log").is_file()


def test_a_child_writing_megabytes_to_stderr_is_not_blocked(tmp_path: Path) -> None:
    """8 MB to stderr, far beyond a pipe's 64 KiB: the child finishes, its last line is kept."""
    code = (
        "import sys\n"
        "line = 'x' * 1023 + '\\n'\n"
        "for _ in range(8192):\n"
        "    sys.stderr.write(line)\n"
        "sys.stderr.write('the last line\\n')\n"
    )
    child = spawn([sys.executable, "-c", code], "chatty", tmp_path / "chatty.log")
    assert child.wait(timeout=60) == 0
    child.join_output()
    assert child.last_error_line() == "the last line"
    assert child.lines == 8193
    log_lines = (tmp_path / "chatty.log").read_text().splitlines(keepends=True)
    # the launcher's header (2 lines: the command, what follows) and footer (the exit status)
    assert log_lines[0].startswith("# chatty: ")
    assert log_lines[-1].startswith("# chatty ended with exit status 0")
    assert sum(len(x) for x in log_lines[2:-1]) == 8192 * 1024 + len("the last line\n")


def test_a_dead_child_is_reported_by_name_of_its_signal() -> None:
    child = spawn([sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"], "victim")
    child.wait(timeout=30)
    assert child.last_error_line() == "killed by SIGKILL"


def _request(gc: GroundClient, msg_id: int, param2: float = 0.0) -> tuple[int, list[Message]]:
    """MAV_CMD_REQUEST_MESSAGE -> (MAV_RESULT, the messages of that id that came with it)."""
    got: list[Message] = []

    def keep(m: Message) -> None:
        if m.get_msgId() == msg_id and gc.from_vehicle(m):
            got.append(m)

    gc.listeners.append(keep)
    try:
        result = gc.command(m2.MAV_CMD_REQUEST_MESSAGE, [float(msg_id), param2], timeout_s=1.0, retries=0)
        gc.spin(0.2)
    finally:
        gc.listeners.remove(keep)
    return result, got


@pytest.mark.slow
def test_qgroundcontrol_connect_sequence_is_answered_at_every_step() -> None:
    """What QGroundControl asks on connect (InitialConnectStateMachine, StandardModes,
    ComponentInformationManager, ParameterManager, PlanManager), in its order; every step is
    answered at once, so QGC never waits for a retry."""
    with running_vehicle() as v, client(v.gcs_port) as gc:
        t0 = time.monotonic()
        result, (ver,) = _request(gc, m2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert result == m2.MAV_RESULT_ACCEPTED
        caps, cap = ver.capabilities, m2
        assert caps & cap.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
        assert caps & cap.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        assert not caps & cap.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # one encoding, alone
        # no fence or rally: QGC then does not ask for them
        fence_or_rally = cap.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE | cap.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
        assert not caps & fence_or_rally
        # standard modes, one index at a time as QGC asks
        result, (first_mode,) = _request(gc, wm.MSG_ID_AVAILABLE_MODES, 1.0)
        n = first_mode.number_modes
        names = [first_mode.mode_name]
        for i in range(2, n + 1):
            result, (mode,) = _request(gc, wm.MSG_ID_AVAILABLE_MODES, float(i))
            assert result == m2.MAV_RESULT_ACCEPTED and mode.mode_index == i
            names.append(mode.mode_name)
        assert names == [m.name for m in wm.MODES]
        assert _request(gc, wm.MSG_ID_AVAILABLE_MODES, float(n + 1))[0] == m2.MAV_RESULT_DENIED
        # component metadata and protocol version: refused at once (QGC moves on)
        for msg_id in (397, 395, 300):
            assert _request(gc, msg_id)[0] in (m2.MAV_RESULT_DENIED, m2.MAV_RESULT_UNSUPPORTED)
        # parameters, then mission, fence and rally downloads
        assert len(gc.param_list()) == len(SPECS)
        for mtype in (m2.MAV_MISSION_TYPE_MISSION, m2.MAV_MISSION_TYPE_FENCE, m2.MAV_MISSION_TYPE_RALLY):
            gc.send(m2.MAVLink_mission_request_list_message(1, 1, mtype))
            count = gc.recv_match(
                lambda m, t=mtype: m.get_type() == "MISSION_COUNT" and m.mission_type == t, 1.0
            )
            assert count is not None, mtype
            if count.count == 0:
                continue
            gc.send(m2.MAVLink_mission_ack_message(1, 1, m2.MAV_MISSION_ACCEPTED, mtype))
        result, (home,) = _request(gc, m2.MAVLINK_MSG_ID_HOME_POSITION)
        assert result == m2.MAV_RESULT_ACCEPTED and home.latitude == 473977420
        # every step answered within its own request's wait (QGC never retries); the total, a
        # speed on the wall clock, printed only
        print(f"QGC connect sequence answered in {time.monotonic() - t0:.2f} s")
        # modes set the three ways: whole custom mode, standard mode, SET_MODE message
        assert gc.command(m2.MAV_CMD_DO_SET_MODE, [1.0, float(wm.HOLD.custom_mode)]) == m2.MAV_RESULT_ACCEPTED
        assert gc.command(wm.CMD_DO_SET_STANDARD_MODE, [1.0]) == m2.MAV_RESULT_ACCEPTED  # POSITION_HOLD
        assert gc.command(wm.CMD_DO_SET_STANDARD_MODE, [3.0]) == m2.MAV_RESULT_FAILED  # CRUISE: none here
        gc.send(m2.MAVLink_set_mode_message(1, m2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, wm.HOLD.custom_mode))
        text = gc.recv_match(lambda m: m.get_type() == "STATUSTEXT", 2.0)
        assert text is not None and text.text == "Hold"
        cur = gc.recv_match(lambda m: m.get_msgId() == wm.MSG_ID_CURRENT_MODE, 3.0)
        assert cur is not None and cur.custom_mode == wm.HOLD.custom_mode and cur.standard_mode == 1


@pytest.mark.slow
def test_two_instances_fly_side_by_side_and_a_client_sees_both() -> None:
    """``heli-sitl up --instance 7`` and ``--instance 8`` on one host: every default port + 70
    or + 80, system ids 8 and 9; both send to one ground-station port, as QGroundControl
    listens on one. Each takes the commands addressed to it and ignores the other's."""
    gcs = new_port()
    ups = [spawn([sys.executable, "-m", "heli_sitl.cli", "up", "--instance", str(n), "--gcs-port", str(gcs)],
                 f"up{n}") for n in (7, 8)]  # fmt: skip
    try:
        with GroundClient(gcs, target_system=8) as gc:
            seen: set[int] = set()
            deadline = time.monotonic() + 120.0
            while seen != {8, 9} and time.monotonic() < deadline:
                for m in gc.poll(0.5):
                    if m.get_type() == "HEARTBEAT" and m.type == m2.MAV_TYPE_HELICOPTER:
                        seen.add(m.get_srcSystem())
            assert seen == {8, 9}
            for sysid, alt in ((8, 2.0), (9, 4.0)):
                gc.target_system = sysid
                gc.arm()
                gc.command_ok(m2.MAV_CMD_NAV_TAKEOFF, [math.nan] * 6 + [alt])
            top = {8: 0.0, 9: 0.0}
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and (top[8] < 1.8 or top[9] < 3.6):
                for m in gc.poll(0.2):
                    if m.get_type() == "LOCAL_POSITION_NED" and m.get_srcSystem() in top:
                        top[m.get_srcSystem()] = max(top[m.get_srcSystem()], -float(m.z))
            assert top[8] >= 1.8 and top[9] >= 3.6, top
            assert top[8] < 3.0  # instance 7 took its own take-off, not the other's
            assert all(u.poll() is None for u in ups)
    finally:
        for u in ups:
            u.stop()


def test_the_shipped_pymavlink_mode_map_is_the_vehicles() -> None:
    """configs/pymavlink_custom_mode_map.json (for MAVProxy) names exactly the vehicle's modes."""
    import json

    from heli_common.config import CONFIG_DIR

    shipped = json.loads((CONFIG_DIR / "pymavlink_custom_mode_map.json").read_text())
    assert shipped == {str(m2.MAV_TYPE_HELICOPTER): {str(m.custom_mode): m.name for m in wm.MODES}}
