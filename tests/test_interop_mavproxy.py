"""MAVProxy (a real third-party ground station) against the vehicle of ``heli-sitl up``.

MAVProxy runs as its own process on the vehicle's ground-station port
(``--master=udpin:127.0.0.1:PORT``) and takes its commands on stdin, as typed at its
console; ``--non-interactive`` would stop it reading stdin, so it is not used. It ends on
EOF (exit code 1, always). What is checked: ``status`` shows the vehicle's telemetry,
``param fetch`` gets every parameter, ``wp load`` uploads a QGC WPL file written by
ground.files that the helicopter then flies (armed and started with MAVProxy's own
``arm throttle`` and ``long MISSION_START``), ``wp list`` downloads it back.

The waypoint file uses MAV_FRAME_GLOBAL_RELATIVE_ALT: MAVProxy converts file items to
MISSION_ITEM_INT by multiplying x/y by 1e7 for every positional command whatever the
frame, so a local-frame file would be scaled wrongly. MAVProxy uploads line 0 (home) as
item 0 too; on this vehicle that is a waypoint at home on the ground, flown first.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from vehicle import free_ports, spawn_up

from autopilot.params_table import SPECS
from ground.client import GroundClient
from ground.files import read_waypoints, write_waypoints
from heli_common.config import CONFIG_DIR as CONFIGS
from heli_common.frames import flip
from heli_common.geo import GeoPoint, nwu_to_geo
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem
from heli_common.wire.mavlink.udp import Message
from heli_sitl.launch.children import die_with_parent

HOME = GeoPoint(47.397742, 8.545594, 488.0)
START_S = 60.0


class MavProxy:
    """A MAVProxy process fed on stdin; its output is collected by a thread."""

    def __init__(self, master_port: int, workdir: Path, env: dict[str, str] | None = None) -> None:
        cmd = [sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpin:127.0.0.1:{master_port}",
               "--no-state", f"--state-basedir={workdir}", "--source-system=255"]  # fmt: skip
        # heli_sitl.launch.demo.spawn gives no stdin pipe; the same parent-death signal is kept.
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, cwd=workdir, env=env,
                                     preexec_fn=die_with_parent)  # fmt: skip
        self._out: list[str] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in iter(self.proc.stdout.readline, b""):
            with self._lock:
                self._out.append(raw.decode(errors="replace"))

    @property
    def text(self) -> str:
        with self._lock:
            return "".join(self._out)

    def mark(self) -> int:
        return len(self.text)

    def send(self, line: str) -> int:
        """Type a command; returns the output position before it (for :meth:`expect`)."""
        pos = self.mark()
        assert self.proc.stdin is not None
        self.proc.stdin.write((line + "\n").encode())
        self.proc.stdin.flush()
        return pos

    def expect(self, pattern: str, timeout_s: float, since: int = 0) -> re.Match[str]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            m = re.search(pattern, self.text[since:], re.MULTILINE)
            if m:
                return m
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        tail = self.text[since:][-1500:]
        raise AssertionError(f"MAVProxy: no {pattern!r} within {timeout_s} s; output tail:\n{tail}")

    def close(self) -> int:
        if self.proc.poll() is None and self.proc.stdin is not None:
            self.proc.stdin.close()  # EOF: MAVProxy's way out when it reads a pipe
        try:
            return self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


@contextmanager
def vehicle_and_mavproxy(
    tmp_path: Path, env: dict[str, str] | None = None, *extra: str
) -> Iterator[tuple[MavProxy, int]]:
    ports = free_ports()
    gcs = ports.gcs
    up = spawn_up(ports, *extra)
    mp = None
    try:
        mp = MavProxy(gcs, tmp_path, env)
        yield mp, ports.api
    finally:
        if mp is not None:
            mp.close()
        if up.poll() is None:
            up.send_signal(signal.SIGTERM)
        try:
            up.wait(timeout=10)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait()


def gwp(seq: int, north_m: float, west_m: float, up_m: float, cmd: int = ms.CMD_WAYPOINT) -> MissionItem:
    g = nwu_to_geo(HOME, (north_m, west_m, 0.0))
    lat, lon = round(g.lat_deg * 1e7), round(g.lon_deg * 1e7)
    return MissionItem(seq, ms.FRAME_GLOBAL_REL, cmd, x=lat, y=lon, z=up_m)


TELEMETRY = (
    "HEARTBEAT", "SYS_STATUS", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
    "GPS_RAW_INT", "HOME_POSITION", "EXTENDED_SYS_STATE", "SERVO_OUTPUT_RAW", "MISSION_CURRENT",
)  # fmt: skip


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavproxy_status_params_and_a_flown_waypoint_file(tmp_path: Path) -> None:
    items = [gwp(0, 0.0, 0.0, 2.0, ms.CMD_TAKEOFF), gwp(1, 3.0, 0.0, 2.0), gwp(2, 3.0, -2.0, 2.5),
             MissionItem(3, ms.FRAME_GLOBAL_REL, ms.CMD_LAND, x=0, y=0, z=0.0)]  # fmt: skip
    wp_file = tmp_path / "mission.waypoints"
    write_waypoints(wp_file, items, HOME)
    with vehicle_and_mavproxy(tmp_path) as (mp, api_port):
        mp.expect(r"online system 1", START_S)
        time.sleep(1.5)  # a second of telemetry for "status"

        at = mp.send("status")
        for kind in TELEMETRY:
            mp.expect(rf"^\d+: {kind} \{{", 5.0, at)
        # MAVProxy counts each gap in a link's sequence numbers as lost messages: every one
        # of ours is numbered in turn (a link that repeated 0 read as 99 % loss)
        at = mp.send("link")
        pattern = r"link \S+ \S+ \((\d+) packets, \d+ bytes, [\d.]+s delay, (\d+) lost, ([\d.]+)% loss"
        link = mp.expect(pattern, 5.0, at)
        assert int(link.group(1)) > 50 and int(link.group(2)) == 0, link.group(0)

        t0 = time.monotonic()
        at = mp.send("param fetch")
        mp.expect(rf"Received {len(SPECS)} parameters", 30.0, at)
        fetch_s = time.monotonic() - t0
        at = mp.send("param show TLC_L1_W_X")
        mp.expect(r"TLC_L1_W_X\s+0\.1875", 5.0, at)

        at = mp.send(f"wp load {wp_file}")
        mp.expect(r"Loaded 5 waypoint", 10.0, at)
        mp.expect(r"Sent all 5 waypoints", 10.0, at)

        at = mp.send("wp list")
        mp.expect(r"Requesting 5 waypoints", 10.0, at)
        listed = mp.expect(r"((?:^.*\d+ \d+ -?\d+\.\d{10} -?\d+\.\d{10} .*cur=\d auto=\d\s*\n){5})", 10.0, at)
        rows = [ln.split()[:5] for ln in listed.group(1).strip().splitlines()]
        assert [r[0] for r in rows] == ["16", "22", "16", "16", "21"]  # home line, then ours

        with GroundClient(api_port) as gc:
            gc.connect(10.0)
            stored = gc.download_mission()
            # MAVProxy truncates x * 1e7 (wp_to_mission_item_int): at most 1e-7 deg (~1 cm) off
            for got, want in zip(stored[1:], items, strict=True):
                assert (got.command, got.frame) == (want.command, want.frame)
                assert abs(got.x - want.x) <= 1 and abs(got.y - want.y) <= 1 and got.z == want.z
            saved = tmp_path / "saved.waypoints"
            at = mp.send(f"wp save {saved}")
            mp.expect(r"Saved 5 waypoints", 10.0, at)
            assert [it.command for it in read_waypoints(saved).items] == [22, 16, 16, 21]

            positions: list[tuple[float, float, float]] = []

            def record(m: Message) -> None:
                if m.get_type() == "LOCAL_POSITION_NED":
                    positions.append(flip((m.x, m.y, m.z)))

            gc.listeners.append(record)
            at = mp.send("arm throttle")
            mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED", 5.0, at)
            at = mp.send("long MISSION_START 0 0")
            mp.expect(r"MISSION_START: ACCEPTED", 5.0, at)
            t_fly = time.monotonic()
            prog = gc.follow_mission(5, timeout_s=90.0)
            gc.wait_landed(30.0)
            fly_s = time.monotonic() - t_fly

        pos = np.array(positions)
        closest = []
        for it in items[:3]:
            target = np.array(nwu_target(it))
            closest.append(float(np.linalg.norm(pos - target, axis=1).min()))
        print(f"MAVProxy: param fetch {fetch_s:.1f} s; flight {fly_s:.1f} s ({prog.reason}); "
              f"closest approach to items 1-3: {[round(c, 3) for c in closest]} m")
        assert all(c < 1.0 for c in closest), closest
        assert pos[-1][2] < 0.1  # landed
    assert mp.proc.returncode == 1  # MAVProxy's exit status on EOF, whatever happened


def _status(mp: MavProxy, kind: str) -> dict[str, float]:
    """The fields of the newest ``kind`` as MAVProxy's ``status`` prints it."""
    at = mp.send(f"status {kind}")
    m = mp.expect(rf"\d+: {kind} \{{(.*)\}}", 5.0, at)  # maybe after MAVProxy's prompt
    return {k.strip(): float(v) for k, v in (f.split(":") for f in m.group(1).split(","))}


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_mavproxy_shows_the_ekf_status_and_the_gps_fix_honestly(tmp_path: Path) -> None:
    """The consumer sensors (u-blox M8 class GPS, MPU-6000, HMC5883L, baro): MAVProxy reads
    a 3-D fix with 14 satellites and the receiver's accuracy, and ArduPilot's
    EKF_STATUS_REPORT with a healthy solution; SIM_GPS_DISABLE = 1 and it reads no fix, no
    satellites, and an EKF in constant-position (dead-reckoning) mode."""
    with vehicle_and_mavproxy(tmp_path, None, "--world", "consumer") as (mp, _):
        mp.expect(r"online system 1", START_S)
        time.sleep(2.0)
        gps, ekf = _status(mp, "GPS_RAW_INT"), _status(mp, "EKF_STATUS_REPORT")
        print(f"GPS_RAW_INT {gps}\nEKF_STATUS_REPORT {ekf}")
        assert (gps["fix_type"], gps["satellites_visible"]) == (3, 14)
        # the receiver's 1-sigma: sqrt(2.1^2 + 0.3^2) per axis, sqrt(2) of it horizontally (in
        # mm; HIL_GPS carries it in cm)
        assert gps["h_acc"] == pytest.approx(1000 * math.sqrt(2.0) * math.hypot(2.1, 0.3), abs=15)
        assert gps["eph"] == 65535  # no satellite geometry in the model: DOP unknown
        flags = int(ekf["flags"])
        assert flags & 1 and flags & 16 and not flags & 128  # attitude, absolute position
        for k in ("velocity_variance", "pos_horiz_variance", "pos_vert_variance"):
            assert 0.0 < ekf[k] < 1.0, (k, ekf[k])  # inside the gates
        at = mp.send("param set SIM_GPS_DISABLE 1")
        mp.expect(r"GPS fix lost", 10.0, at)  # MAVProxy's own word, from GPS_RAW_INT
        mp.expect(r"AP: GPS lost", 10.0, at)  # the vehicle's STATUSTEXT
        time.sleep(0.5)
        gps, ekf = _status(mp, "GPS_RAW_INT"), _status(mp, "EKF_STATUS_REPORT")
        print(f"after SIM_GPS_DISABLE: GPS_RAW_INT {gps}\nEKF_STATUS_REPORT {ekf}")
        assert (gps["fix_type"], gps["satellites_visible"]) == (1, 0)
        flags = int(ekf["flags"])
        assert flags & 128 and not flags & 16  # constant position mode, no absolute position


def nwu_target(item: MissionItem) -> tuple[float, float, float]:
    p = ms.item_position_ned_m(item, HOME)
    assert p.north_east_m is not None and p.down_m is not None
    n, e, d = p.north_east_m[0], p.north_east_m[1], p.down_m
    assert math.isfinite(n + e + d)
    return flip((n, e, d))


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_mavproxy_names_and_sets_modes_reads_parameters_and_sees_no_fence(tmp_path: Path) -> None:
    """With the vehicle's mode map installed where pymavlink looks for one
    (configs/pymavlink_custom_mode_map.json -> ~/.pymavlink/custom_mode_map.json), the prompt
    names the mode and ``mode NAME`` works; parameters read and set as the numbers they are;
    SYS_STATUS gives MAVProxy no reason to report a fence breach."""
    home = tmp_path / "home"
    (home / ".pymavlink").mkdir(parents=True)
    shutil.copy(CONFIGS / "pymavlink_custom_mode_map.json", home / ".pymavlink" / "custom_mode_map.json")
    with vehicle_and_mavproxy(tmp_path, {**os.environ, "HOME": str(home)}) as (mp, _):
        mp.expect(rf"Received {len(SPECS)} parameters", START_S)
        mp.expect(r"^HOLD> |Mode HOLD", 5.0)
        pos = mp.send("param show MAV_SYS_ID")
        mp.expect(r"MAV_SYS_ID\s+1(\.0)?\s*$", 5.0, pos)
        pos = mp.send("param set TLC_RATE_HZ 200")
        time.sleep(1.0)  # the vehicle's PARAM_VALUE updates MAVProxy's copy
        mp.send("param show TLC_RATE_HZ")
        mp.expect(r"TLC_RATE_HZ\s+200(\.0)?\s*$", 5.0, pos)
        pos = mp.send("mode")
        mp.expect(r"Available modes:\s+HOLD, MISSION, RETURN, LAND, TAKEOFF, OFFBOARD", 5.0, pos)
        pos = mp.send("mode MISSION")  # no mission: refused, and said why
        mp.expect(r"Mission mode refused: no mission", 5.0, pos)
        mp.expect(r"DO_SET_MODE: DENIED", 5.0, pos)
        pos = mp.send("mode HOLD")
        mp.expect(r"DO_SET_MODE: ACCEPTED", 5.0, pos)
        assert "fence breach" not in mp.text.lower()
        assert "Mode(" not in mp.text
