"""`heli-sitl demo --servo-link can`: plant and autopilot as processes, servos on DroneCAN over
python-can udp_multicast, and over DroneCAN's own UDP multicast (`mcast:0`) watched by a
pydronecan node with dronecan's own `mcast` driver and by `heli-sitl can monitor`, each
inside a network namespace the test makes (never the host's)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from netns import NETNS_SETUP, unshare_reason

ME = str(Path(__file__).resolve())
OBSERVER_NODE_ID = 100

pytestmark = [pytest.mark.slow, pytest.mark.netns]


def _bus_was_clean(stderr: str, s: dict[str, Any]) -> None:
    """Every bus closed, no send error, a command per tick and NodeStatus at 1 Hz."""
    assert "not properly shut down" not in stderr  # every bus closed
    assert s["servo_link"] == "can"
    assert s["can"]["send_errors"] == 0 and s["can"]["commands_sent"] >= 12001
    assert s["can"]["node_status_sent"] >= 120  # 1 Hz of flight time


def _pause_the_autopilot(proc: subprocess.Popen[str], *, times: int, pause_s: float,
                         every_s: float) -> threading.Thread:
    """In a thread: find the demo's autopilot process and stop it (SIGSTOP) ``times`` times
    for ``pause_s``, every ``every_s``; it always resumes it (SIGCONT), also on an error."""
    import psutil

    def run() -> None:
        deadline = time.monotonic() + 120.0
        ap = None
        while ap is None and time.monotonic() < deadline and proc.poll() is None:
            try:
                for c in psutil.Process(proc.pid).children(recursive=True):
                    if "autopilot.cli" in " ".join(c.cmdline()):
                        ap = c
            except psutil.Error:
                pass
            time.sleep(0.1)
        for _ in range(times):
            time.sleep(every_s)
            if ap is None or proc.poll() is not None:
                return
            try:
                ap.suspend()
                time.sleep(pause_s)
            except psutil.Error:
                return
            finally:
                with contextlib.suppress(psutil.Error):
                    ap.resume()

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_demo_over_can_flies_the_paper_scenario(tmp_path: Path) -> None:
    """docs/can.md's command as written, on the default bus `mcast:0` (through the ground
    script, the plant held until the autopilot's DroneCAN ArmingStatus says armed); the
    autostart form flies in the next test, on python-can's `udp_multicast`."""
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    demo = f"{sys.executable} -m heli_sitl.cli demo --servo-link can --can-bus mcast:0 --out {tmp_path}"
    proc = subprocess.Popen(
        ["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {demo}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    # the autopilot stopped for 0.25 s (longer than the plant's 0.2 s re-send) every 0.25 s
    # of the flight: stopped between reading a state and answering it (about a third of
    # the stops), it answers that state, then the plant's re-send of it; the plant must apply
    # one answer per tick (a command on CAN carries no time stamp: the repeat is the same
    # transfer, dropped). Before, the flight ran a tick behind from the first such stop.
    pauses = _pause_the_autopilot(proc, times=60, pause_s=0.25, every_s=0.25)
    try:
        _, stderr = proc.communicate(timeout=600)
    finally:
        pauses.join(timeout=30)
    assert proc.returncode == 0, stderr[-2000:]
    s = json.loads((tmp_path / "summary.json").read_text())
    _bus_was_clean(stderr, s)
    print(f"over mcast:0: RMS [45, 120] s {s['rms_pos_err_m']['45-120']:.6f} m, "
          f"max [40, 45] s {s['max_pos_err_40_45_m']:.4f} m; repeated {s['can']['commands_repeated']}")
    assert s["can"]["commands_repeated"] >= 1  # the race happened
    # the in-process flight over a CAN bus (float16 commands: tests/test_can_closed_loop.py)
    assert s["rms_pos_err_m"]["45-120"] == pytest.approx(0.04012748786, rel=1e-4)
    assert s["max_pos_err_40_45_m"] <= 0.3


def test_the_world_flies_over_can_too(tmp_path: Path) -> None:
    """The world is the plant's: with the servos on DroneCAN, `--world gusty` flies as it
    does in-process, up to the float16 commands (the same air, seeded). The autostart form
    (no ground script): the buses as clean as through the README's command."""
    from autopilot.scenario import Scenario
    from heli_common.world.config import World
    from heli_sitl.engine.closed_loop import SimOptions, simulate

    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    demo = (f"{sys.executable} -m heli_sitl.cli demo --servo-link can --can-bus udp_multicast --autostart "
            f"--world gusty --out {tmp_path}")  # fmt: skip
    proc = subprocess.run(["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {demo}"],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((tmp_path / "summary.json").read_text())
    _bus_was_clean(proc.stderr, s)
    assert s["world"]["name"] == "gusty"
    rms_in_process = simulate(Scenario.load("paper"), SimOptions(world=World.load("gusty"))).summary()
    ref = rms_in_process["rms_pos_err_m"]["45-120"]
    print(f"gusty over CAN: RMS [45, 120] s {s['rms_pos_err_m']['45-120']:.4f} m, in-process {ref:.4f} m")
    assert s["rms_pos_err_m"]["45-120"] == pytest.approx(ref, rel=0.05)


def test_a_dronecan_node_on_mcast_sees_the_bench_fly(tmp_path: Path) -> None:
    """The done-when of issue 47: a lockstep flight with `--servo-link can --can-bus mcast:0`;
    beside it, in the same namespace, a pydronecan node on `mcast:0` (dronecan's own
    driver, its own Node, transfer manager and DSDL) and `heli-sitl can monitor`. The node
    sees the autopilot's NodeStatus, gets both nodes' GetNodeInfo answers, decodes the
    servo commands and the servos' actuator Status."""
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    parent = os.readlink("/proc/self/ns/net")
    script = f"{NETNS_SETUP} && exec {sys.executable} {ME} flight {tmp_path} {parent}"
    t0 = time.monotonic()
    proc = subprocess.run(["unshare", "--net", "--", "bash", "-c", script],
                          capture_output=True, text=True, timeout=400)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    print(f"flight, node and monitor: {time.monotonic() - t0:.1f} s")
    s = json.loads((tmp_path / "flight" / "summary.json").read_text())
    assert s["servo_link"] == "can" and s["can"]["send_errors"] == 0
    assert s["can"]["commands_sent"] >= 4001 and s["can"]["node_info_answered"] >= 1
    seen = json.loads((tmp_path / "observer.json").read_text())
    print(json.dumps({k: v for k, v in seen.items() if k != "commands_sample"}, indent=1))
    assert seen["node_status_from"]["10"] >= 3 and seen["node_status_from"]["20"] >= 1
    ap, servos = seen["node_info"]["10"], seen["node_info"]["20"]
    assert ap["name"] == "org.heli-tlc-sitl.autopilot" and servos["name"] == "org.heli-tlc-sitl.servos"
    assert ap["software_version"] == [0, 1] and ap["unique_id"] != servos["unique_id"]
    assert seen["array_commands"] >= 100  # it lags the lockstep flight; it need not see all
    for cmds in seen["commands_sample"]:
        assert [(a, t) for a, t, _ in cmds] == [(1, 1), (2, 1), (3, 1), (4, 1)]
        assert all(abs(v) <= 0.8 for _, _, v in cmds)
    assert seen["actuator_status"] >= 4 and sorted(seen["actuator_ids"]) == [1, 2, 3, 4]
    assert seen["positions_finite"] >= 4  # positions once commands flow (NaN before: unknown)
    mon = (tmp_path / "monitor.out").read_text().splitlines()
    # the servo commands only (--type): the plant's node speaks from its start, before the
    # autopilot's first command, and a count of any 300 transfers was once all its own
    assert len(mon) == 300 and all("uavcan.equipment.actuator.ArrayCommand" in line for line in mon)


def _flight_main(out: Path) -> int:
    """In the namespace: the observer node, then the monitor and the flight; the observer
    stops once the flight is over and its queue drained."""
    obs = subprocess.Popen([sys.executable, ME, "observe", str(out), "-"])
    try:
        deadline = time.monotonic() + 30.0
        while not (out / "observer.ready").exists():
            if time.monotonic() > deadline or obs.poll() is not None:
                print("the observer node did not start", file=sys.stderr)
                return 4
            time.sleep(0.05)
        cli = [sys.executable, "-m", "heli_sitl.cli"]
        with (out / "monitor.out").open("w") as mo:
            mon = subprocess.Popen([*cli, "can", "monitor", "mcast:0", "--type", "ArrayCommand",
                                    "--count", "300", "--duration", "300"],
                                   stdout=mo, stderr=subprocess.DEVNULL)  # fmt: skip
            demo = subprocess.run([*cli, "demo", "--servo-link", "can", "--can-bus", "mcast:0", "--autostart",
                                   "--duration-s", "40", "--out", str(out / "flight")],
                                  capture_output=True, text=True, timeout=300)  # fmt: skip
            (out / "observer.stop").touch()
            if demo.returncode != 0:
                print(demo.stderr[-3000:], file=sys.stderr)
                return demo.returncode
            rc_obs = obs.wait(timeout=60)
            rc_mon = mon.wait(timeout=30)
        return max(rc_obs, rc_mon)
    finally:
        for p in (obs,):
            if p.poll() is None:
                p.kill()


def _observe_main(out: Path) -> int:
    """A pydronecan node (id 100) on dronecan's own `mcast:0` driver."""
    import dronecan

    node = dronecan.make_node("mcast:0", node_id=OBSERVER_NODE_ID)
    seen: dict[str, Any] = {"node_status_from": {}, "node_info": {}, "array_commands": 0,
                            "commands_sample": [], "actuator_status": 0, "actuator_ids": [],
                            "positions_finite": 0}  # fmt: skip
    asked: dict[int, float] = {}

    def on_status(e: Any) -> None:
        src = str(e.transfer.source_node_id)
        seen["node_status_from"][src] = seen["node_status_from"].get(src, 0) + 1

    def on_command(e: Any) -> None:
        seen["array_commands"] += 1
        if len(seen["commands_sample"]) < 50:
            seen["commands_sample"].append([(int(c.actuator_id), int(c.command_type), float(c.command_value))
                                            for c in e.message.commands])  # fmt: skip

    def on_actuator(e: Any) -> None:
        seen["actuator_status"] += 1
        aid = int(e.message.actuator_id)
        if aid not in seen["actuator_ids"]:
            seen["actuator_ids"].append(aid)
        seen["positions_finite"] += math.isfinite(float(e.message.position))

    def on_info(nid: int, e: Any) -> None:
        if e is None:  # timed out: ask again
            asked.pop(nid, None)
            return
        r = e.response
        seen["node_info"][str(nid)] = {
            "name": r.name.decode(),
            "software_version": [int(r.software_version.major), int(r.software_version.minor)],
            "unique_id": bytes(r.hardware_version.unique_id.to_bytes()).hex(),
            "uptime_s": int(r.status.uptime_sec),
        }

    node.add_handler(dronecan.uavcan.protocol.NodeStatus, on_status)
    node.add_handler(dronecan.uavcan.equipment.actuator.ArrayCommand, on_command)
    node.add_handler(dronecan.uavcan.equipment.actuator.Status, on_actuator)
    (out / "observer.ready").touch()
    t0 = time.monotonic()
    quiet_since: float | None = None
    while time.monotonic() - t0 < 300.0:
        now = time.monotonic()
        for nid in (10, 20):  # ask until answered, once every 2 s
            if str(nid) not in seen["node_info"] and now - asked.get(nid, -1e9) > 2.0:
                asked[nid] = now
                node.request(dronecan.uavcan.protocol.GetNodeInfo.Request(), nid,
                             lambda e, nid=nid: on_info(nid, e), timeout=30.0)  # fmt: skip
        n = node.spin(0)
        if (out / "observer.stop").exists():  # the flight is over: drain what is queued
            quiet_since = quiet_since if n == 0 and quiet_since is not None else (now if n == 0 else None)
            if quiet_since is not None and now - quiet_since > 2.0:
                break
        time.sleep(0.002)
    (out / "observer.json").write_text(json.dumps(seen))
    return 0


if __name__ == "__main__":  # roles of the mcast test, run in the namespace it makes
    role, out_dir, parent_netns = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
    if parent_netns != "-" and os.readlink("/proc/self/ns/net") == parent_netns:
        print("refusing: not inside a private network namespace", file=sys.stderr)
        sys.exit(3)
    sys.exit(_flight_main(out_dir) if role == "flight" else _observe_main(out_dir))
