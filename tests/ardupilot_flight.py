"""A flight of ArduPilot's helicopter firmware on this bench's plant, run INSIDE a private
network namespace (tests/test_ardupilot_sitl.py starts it with ``unshare --net``): ArduPilot
SITL opens TCP 5760-5763 and UDP 9002, which must never reach the host's network.

``python tests/ardupilot_flight.py OUT PLANT [--hover-only]`` starts ``heli-sitl up --firmware ardupilot``,
connects a ground station (pymavlink, TCP 5760), reads parameters, the mode and the EKF status
(and so does MAVProxy on TCP 5763 while it flies),
arms in GUIDED, runs the rotor up (the motor interlock, switched with MAV_CMD_DO_AUX_FUNCTION),
takes off to 5 m and hovers; then ``heli-ground fly --guided`` (UDP 14550, the firmware's
SERIAL1) flies the paper's trajectory in GUIDED, lands and disarms (with ``--hover-only``:
it lands from the hover). What it saw goes to
OUT/result.json, the streamed targets to OUT/track.csv; the plant's truth is OUT/plant.csv.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from pymavlink import mavutil

TAKEOFF_M = 5.0
SPEEDUP = 10
MAV_CMD_DO_AUX_FUNCTION, MOTOR_INTERLOCK = 218, 32  # (ardupilotmega.xml; RC_Channel aux function)
TRAJECTORY = Path(__file__).resolve().parent.parent / "configs" / "scenario_paper.toml"
GUIDED, LAND = 4, 9  # ArduCopter custom modes


def sim_time(out: Path) -> float:
    """The plant's physics time: the last complete row of plant.csv (0 before the first)."""
    try:
        with (out / "plant.csv").open("rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            lines = f.read().split(b"\n")
    except OSError:
        return 0.0
    for line in reversed(lines[:-1]):  # the last one may be half written
        head = line.split(b",", 1)[0]
        if head and head != b"t":
            return float(head)
    return 0.0


def main(out: Path, plant: str, trajectory: bool) -> int:
    if os.readlink("/proc/self/ns/net") == os.environ.get("PARENT_NETNS"):
        print("refusing: not inside a private network namespace", file=sys.stderr)
        return 3
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    out.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = {"texts": [], "modes": [], "estimate_ned": []}
    up = subprocess.Popen(
        # niced: the lockstep simulation does not mind being slowed, while a ground station
        # streaming setpoints on the vehicle's clock must never wait for a CPU behind it
        ["nice", "-n", "10", sys.executable, "-m", "heli_sitl.cli", "up", "--firmware", "ardupilot",
         "--speedup", str(SPEEDUP),
         "--plant", plant, "--out", str(out)],
        stdout=(out / "up.log").open("w"), stderr=subprocess.STDOUT, start_new_session=True,
    )  # fmt: skip
    conn = None
    try:
        end = time.monotonic() + 30.0
        while conn is None and time.monotonic() < end:
            try:
                conn = mavutil.mavlink_connection("tcp:127.0.0.1:5760", autoreconnect=False)
            except OSError:
                time.sleep(0.3)
        if conn is None:
            res["error"] = "no ground-station connection on TCP 5760"
            return 0
        hb = conn.wait_heartbeat(timeout=30)
        res["heartbeat"] = [hb.type, hb.autopilot]
        # only what is checked (a flood at --speedup 10 would cost the ground stations' CPU)
        mav = mavutil.mavlink
        for stream, hz in ((mav.MAV_DATA_STREAM_POSITION, 5), (mav.MAV_DATA_STREAM_EXTRA3, 2)):
            conn.mav.request_data_stream_send(1, 1, stream, hz, 1)

        def pump(wall_s: float) -> None:
            stop = time.monotonic() + wall_s
            while time.monotonic() < stop:
                m = conn.recv_match(blocking=True, timeout=0.1)
                if m is None:
                    continue
                kind = m.get_type()
                if kind == "STATUSTEXT":
                    res["texts"].append(m.text)
                elif kind == "LOCAL_POSITION_NED":  # the firmware's estimate, for the record
                    res["estimate_ned"].append((m.time_boot_ms / 1e3, m.x, m.y, m.z))
                elif kind == "EKF_STATUS_REPORT":
                    res["ekf_flags"] = m.flags
                elif kind == "HEARTBEAT" and m.get_srcComponent() == 1:
                    res["armed"] = bool(m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
                    if not res["modes"] or res["modes"][-1] != m.custom_mode:
                        res["modes"].append(m.custom_mode)
                elif kind == "PARAM_VALUE":
                    res.setdefault("params", {})[m.param_id] = m.param_value

        def wait_sim(seconds: float, wall_limit_s: float = 60.0) -> None:
            """Pump until the physics has advanced ``seconds`` (the firmware may run slower
            than its speed-up on a loaded machine)."""
            t_end = sim_time(out) + seconds
            give_up = time.monotonic() + wall_limit_s
            while sim_time(out) < t_end and time.monotonic() < give_up:
                pump(0.25)

        def interlock(on: bool) -> None:
            """The ground station's motor-interlock switch (an RC override would lapse in 3 s)."""
            conn.mav.command_long_send(1, 1, MAV_CMD_DO_AUX_FUNCTION, 0, MOTOR_INTERLOCK, 2 if on else 0,
                                       0, 0, 0, 0, 0)  # fmt: skip

        for name in ("H_SW_TYPE", "H_COL_MAX", "FRAME_CLASS"):
            conn.mav.param_request_read_send(1, 1, name.encode(), -1)
        wait_sim(1.0)
        conn.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
        pump(0.5)
        interlock(False)  # it must be low to arm
        for _ in range(120):  # arming waits for the EKF to align and take the GPS: retry
            if res["modes"][-1:] != [GUIDED]:  # the firmware's mode switch, read when RC input
                # first appears, can undo a GUIDED set before: then it would arm in STABILIZE
                conn.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)
            conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, *[0] * 6)
            pump(0.5)
            if res.get("armed"):
                break
        if not res.get("armed"):
            res["error"] = "did not arm"
            return 0
        interlock(True)
        # MAVProxy, a second ground station on SERIAL2 (TCP 5763), while the vehicle flies
        mavproxy = subprocess.Popen(
            [sys.executable, "-m", "MAVProxy.mavproxy", "--master=tcp:127.0.0.1:5763", "--no-state",
             f"--state-basedir={out}", "--source-system=254"],
            stdin=subprocess.PIPE, stdout=(out / "mavproxy.log").open("w"), stderr=subprocess.STDOUT,
            text=True, start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        wait_sim(15.0)  # rotor run-up (H_RSC_RUNUP_TIME)
        t_takeoff = sim_time(out)
        conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, TAKEOFF_M)
        wait_sim(15.0)  # climb
        assert mavproxy.stdin is not None  # it has found the vehicle and fetched its parameters by now
        # MAVProxy 1.8 asks for the vehicle's streams at its start to the vehicles it has found
        # after waiting 0.1 s for a heartbeat, which it has not yet processed: to nobody. It asks
        # again 15 s of wall clock later, when a flight at speed-up 10 may be over (its status
        # then listed no EKF_STATUS_REPORT: a failure of CI). A user sets the rate, as here.
        mavproxy.stdin.write("set streamrate 5\nparam show H_SW_TYPE\nparam show FRAME_CLASS\n")
        mavproxy.stdin.flush()
        wait_sim(15.0)  # hover
        t_hover_end = sim_time(out)
        log = out / "mavproxy.log"
        for _ in range(10):  # its status lists only the messages it has received
            mavproxy.stdin.write("status EKF_STATUS_REPORT\n")
            mavproxy.stdin.flush()
            wait_sim(1.0)
            if "EKF_STATUS_REPORT {" in log.read_text(errors="replace"):
                break
        mavproxy.stdin.close()  # EOF: MAVProxy ends
        with contextlib.suppress(subprocess.TimeoutExpired):
            mavproxy.wait(10)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(mavproxy.pid, signal.SIGKILL)  # with the process it forks for its console
        mavproxy.wait()
        res["mavproxy"] = (out / "mavproxy.log").read_text(errors="replace")
        res["t_takeoff"], res["t_hover_end"] = t_takeoff, t_hover_end
        if not trajectory:  # straight down from the hover: LAND, until it disarms itself
            conn.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LAND)
            t_land = sim_time(out)
            while res.get("armed") and sim_time(out) < t_land + 60.0:
                wait_sim(1.0)
            pump(1.0)
            res["disarmed_after_landing"] = not res.get("armed")
            return 0
        # the paper's trajectory, streamed by heli-ground over the firmware's SERIAL1; our
        # link keeps pumping in a thread, so the modes and the arming state are still seen
        stop = threading.Event()
        pumper = threading.Thread(target=lambda: [pump(0.25) for _ in iter(stop.is_set, True)], daemon=True)
        pumper.start()
        guided = subprocess.run(
            [sys.executable, "-m", "ground.cli", "fly", "--guided", str(TRAJECTORY), "--quiet",
             "--track-csv", str(out / "track.csv"), "--pace-port", "9008"],  # the plant waits for it
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        stop.set()
        pumper.join()
        res["guided_exit"], res["guided_output"] = guided.returncode, guided.stdout + guided.stderr
        pump(1.0)
        res["disarmed_after_landing"] = not res.get("armed")
    finally:
        if conn is not None:
            conn.close()
        os.killpg(up.pid, signal.SIGINT)  # up, the plant and the firmware: one process group
        with contextlib.suppress(subprocess.TimeoutExpired):
            up.wait(20)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(up.pid, signal.SIGKILL)  # the firmware ignores SIGTERM while it waits
        up.wait(10)
        (out / "result.json").write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    args = sys.argv[1:]
    raise SystemExit(main(Path(args[0]), args[1] if len(args) > 1 else "paper", "--hover-only" not in args))
