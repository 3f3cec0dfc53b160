"""Plant and autopilot as real OS processes on loopback: lockstep, real time, faults, fuzz."""

from __future__ import annotations

import json
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from ports import new_port

from autopilot.scenario import Scenario
from ground.plots import read_csv_columns
from heli_common.port_handoff import HeldPorts
from heli_common.wire.mavlink.sim_protocol import command_message, state_messages
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp, mavlink2
from heli_sitl.engine.closed_loop import SimOptions, simulate
from heli_sitl.launch.children import Child, spawn
from heli_sitl.launch.demo import DemoError, DemoOptions, UpOptions, run_demo, up_commands

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def in_process() -> dict[str, np.ndarray]:
    rec = simulate(Scenario.load("paper"))
    cols = rec.columns()
    cols["summary"] = rec.summary()  # type: ignore[assignment]
    return cols


def _f32(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, dtype=float).astype(np.float32).astype(float)


def test_lockstep_reproduces_the_in_process_flight(tmp_path: Path, in_process) -> None:  # type: ignore[no-untyped-def]
    summary = run_demo(
        DemoOptions(mode="lockstep", rate_hz=100.0, out=tmp_path, timeout_s=600, via_ground=False)
    )
    cols = read_csv_columns(tmp_path / "run.csv")
    assert cols["t_s"].size == in_process["t_s"].size == 12001
    # the positions as the sim link carried them (float32; run.csv's 9 digits read back to
    # that very float32): the same flight, bit for bit (tests/test_lockstep_bit_identical.py)
    d = np.stack([_f32(cols[k]) - _f32(in_process[k]) for k in ("x_m", "y_m", "z_m")], axis=1)
    worst = float(np.abs(d).max())
    assert worst <= 1e-9, f"lockstep vs in-process max {worst:.2e} m"
    assert summary["loop"]["bad_outputs"] == 0  # type: ignore[index]
    assert summary["sim_link"]["rx_bad"] == 0  # type: ignore[index]
    # the .tlog is a pymavlink log with the required messages
    dump = subprocess.run(
        [sys.executable, "-m", "pymavlink.tools.mavlogdump", "--types",
         "LOCAL_POSITION_NED,ATTITUDE,POSITION_TARGET_LOCAL_NED,SERVO_OUTPUT_RAW",
         str(tmp_path / "flight.tlog")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    kinds = {ln.split()[2] for ln in dump.stdout.splitlines() if len(ln.split()) > 2}
    assert {"LOCAL_POSITION_NED", "ATTITUDE", "POSITION_TARGET_LOCAL_NED", "SERVO_OUTPUT_RAW"} <= kinds


def _err_45_60(cols: dict[str, np.ndarray]) -> np.ndarray:
    """|reference - position| over [45, 60] s of the flight's columns."""
    t = cols["t_s"]
    m = (t >= 45.0) & (t <= 60.0)
    return np.asarray(np.sqrt(sum((cols[f"{a}_ref_m"][m] - cols[f"{a}_m"][m]) ** 2 for a in "xyz")))


def test_realtime_100hz_tracks_the_paper(tmp_path: Path) -> None:
    """Real time at 100 Hz through the slope break at 40 s and 20 s of the circle (the whole
    120 s flies in lockstep above; 60 s of wall clock here keep the suite short), against the
    in-process flight of the same length. While the loops keep their deadlines the real-time
    flight is the in-process one to 4 digits of the error; one late wake-up of the OS makes a
    transient: in a fresh-clone suite a 115 ms wake-up at 53.15 s (11 skipped ticks) put the
    error to 0.15 m for a second, RMS [45, 60] 0.061 m against 0.043 m, median 0.0469 m against
    0.0450. So the median says whether it tracks (within 10 %: 0.0450 alone), the RMS that it
    was not lost (within 2x), the peak after the slope break that the transient is the same
    (within 20 %). Both loops under SCHED_FIFO at 20 (`--rt-priority`), above the suite's other
    real-time flights (10): no other test's loop can hold a core from them."""
    summary = run_demo(
        DemoOptions(mode="realtime", rate_hz=100.0, out=tmp_path, timeout_s=400, via_ground=False,
                    duration_s=60.0, rt_priority=20)
    )  # fmt: skip
    flight = simulate(Scenario.load("paper"), SimOptions(duration_s=60.0))
    ref = flight.summary()
    rms, rms_ref = summary["rms_pos_err_m"]["45-60"], ref["rms_pos_err_m"]["45-60"]  # type: ignore[index]
    jump, jump_ref = summary["max_pos_err_40_45_m"], ref["max_pos_err_40_45_m"]
    med = float(np.median(_err_45_60(read_csv_columns(tmp_path / "run.csv"))))
    med_ref = float(np.median(_err_45_60(flight.columns())))
    loop = summary["loop"]
    assert isinstance(loop, dict)
    why = {k: loop.get(k) for k in ("skipped_ticks", "stale_ticks", "overruns", "jitter_max_ms")}
    why["skips"] = loop.get("tick_sections", {}).get("skips")  # when, how late: the machine or the loop
    print(f"real time 100 Hz: [45,60] median {med:.4f} m, RMS {rms:.4f} m; in-process {med_ref:.4f}, "
          f"{rms_ref:.4f}; max [40,45] {jump:.3f} m, in-process {jump_ref:.3f} m; {why}")  # fmt: skip
    assert med <= 1.1 * med_ref, f"median [45,60] {med:.4f} vs {med_ref:.4f} in-process; {why}"
    assert rms <= 2.0 * rms_ref, f"RMS [45,60] {rms:.4f} vs {rms_ref:.4f} in-process; {why}"
    assert jump <= 1.2 * jump_ref, f"max [40,45] {jump:.3f} vs {jump_ref:.3f} in-process; {why}"  # type: ignore[operator]
    assert loop["plant_stale_events"] == 0 and loop["bad_outputs"] == 0


def test_a_busy_port_is_a_one_line_failure(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, 0))
        with pytest.raises(DemoError, match=r"plant died \(exit code 3\): .*busy"):
            run_demo(DemoOptions(plant_port=s.getsockname()[1], out=tmp_path, duration_s=2.0,
                                 timeout_s=120, via_ground=False))  # fmt: skip


def _wait_for(link: MavlinkUdp, kind: str, timeout_s: float) -> object:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for m, _ in link.recv(timeout_s=0.2):
            if m.get_type() == kind:
                return m
    raise AssertionError(f"no {kind} within {timeout_s} s")


@pytest.fixture
def served() -> Iterator[tuple[UpOptions, list[Child], MavlinkUdp]]:
    """`heli-sitl up` (real time, on the ground) with every port chosen here, and a GCS socket;
    the sim link's two ports bound here and handed to the processes, as `up` does."""
    gcs = MavlinkUdp((LOOPBACK, 0), drop_nonfinite=False)
    opts = UpOptions(
        gcs_port=gcs.local[1], api_port=new_port(), local_gcs_port=new_port(), local_api_port=new_port(),
    )  # fmt: skip
    with HeldPorts() as held:
        commands = up_commands(opts, held)
        procs = [spawn(cmd, handoff=(held, own)) for _, cmd, own in commands]
    plant_cmd = commands[0][1]
    opts = replace(opts, plant_port=int(plant_cmd[plant_cmd.index("--port") + 1]),
                   autopilot_port=int(plant_cmd[plant_cmd.index("--autopilot-port") + 1]))  # fmt: skip
    try:
        _wait_for(gcs, "HEARTBEAT", 120.0)
        yield opts, procs, gcs
    finally:
        for p in procs:
            p.send_signal(signal.SIGTERM)
        for p in procs:
            p.wait(timeout=10)
        gcs.close()


def _mutations(rng: random.Random) -> list[bytes]:
    """Valid sim and GCS packets, and the raw material for truncating and mutating them."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    limits = np.array([[-0.1, 0.3]] * 4)
    good = [
        b"".join(bytes(m.pack(mav)) for m in state_messages(rng.randrange(10**9), np.zeros(12))),
        bytes(command_message(rng.randrange(10**9), np.zeros(4), limits, True).pack(mav)),
        bytes(mavlink2.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)),
        bytes(mavlink2.MAVLink_param_request_list_message(1, 1).pack(mav)),
        bytes(mavlink2.MAVLink_mission_count_message(1, 1, 3, 0).pack(mav)),
    ]
    nan_cmd = command_message(5, np.zeros(4), limits, True)
    nan_cmd.controls = [float("nan")] * 16
    good.append(bytes(nan_cmd.pack(mav)))
    return good


def test_fuzz_both_processes_keep_flying(served) -> None:  # type: ignore[no-untyped-def]
    opts, procs, gcs = served
    rng = random.Random(1234)
    good = _mutations(rng)
    targets = [opts.plant_port, opts.autopilot_port, opts.local_gcs_port, opts.local_api_port]
    sent = 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        t_end = time.monotonic() + 60.0  # bounded in time as well as in count
        while sent < 20_000 and time.monotonic() < t_end:
            kind = sent % 4
            base = bytearray(rng.choice(good))
            if kind == 0:
                data = bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 300)))
            elif kind == 1:
                data = bytes(base[: rng.randrange(1, len(base))])
            elif kind == 2:
                for _ in range(rng.randrange(1, 4)):
                    base[rng.randrange(len(base))] ^= 1 << rng.randrange(8)
                data = bytes(base)
            else:
                data = bytes(base)  # valid: out-of-order times, NaN commands, commands, lists
            s.sendto(data, (LOOPBACK, targets[sent % len(targets)]))
            sent += 1
            if sent % 200 == 0:
                time.sleep(0.01)  # about 20k datagrams a second at most
    assert sent == 20_000
    assert all(p.poll() is None for p in procs), "a process died under fuzzing"
    # the loop still runs: telemetry keeps coming with advancing time
    first = _wait_for(gcs, "LOCAL_POSITION_NED", 10.0)
    time.sleep(0.5)
    later = _wait_for(gcs, "LOCAL_POSITION_NED", 10.0)
    assert later.time_boot_ms > first.time_boot_ms  # type: ignore[attr-defined]
    for m in (first, later):
        assert all(np.isfinite([m.x, m.y, m.z]))  # type: ignore[attr-defined]
    servo = _wait_for(gcs, "SERVO_OUTPUT_RAW", 10.0)
    assert all(1000 <= getattr(servo, f"servo{i}_raw") <= 2000 for i in range(1, 5))


def _json_from_stderr(p: Child) -> dict[str, object]:
    p.join_output()
    err = p.output()
    for line in reversed(err.splitlines()):
        if line.startswith("{"):
            return json.loads(line)  # type: ignore[no-any-return]
    raise AssertionError(f"no stats line in: {err[-500:]}")


def test_silent_links_are_detected_and_the_command_held(tmp_path: Path) -> None:
    pp, ap = new_port(), new_port()
    gcs = MavlinkUdp((LOOPBACK, 0), drop_nonfinite=False)
    common = ["--mode", "realtime", "--rate-hz", "100", "--duration-s", "8"]
    plant = spawn([sys.executable, "-m", "heli_sitl.cli", "run", *common, "--port", str(pp),
                   "--autopilot-port", str(ap), "--timeout-s", "0.5", "-v"])  # fmt: skip
    autopilot = spawn([sys.executable, "-m", "autopilot.cli", *common, "--port", str(ap),
                       "--plant-port", str(pp), "--autostart", "--out", str(tmp_path),
                       "--stale-timeout-s", "0.3", "--gcs-port", str(gcs.local[1]),
                       "--api-port", str(new_port()), "--local-gcs-port", str(new_port()),
                       "--local-api-port", str(new_port())])  # fmt: skip
    try:
        _wait_for(gcs, "LOCAL_POSITION_NED", 120.0)  # flying (after a cold compile, too)
        time.sleep(1.0)
        plant.send_signal(signal.SIGSTOP)  # the plant goes silent ...
        time.sleep(1.0)
        plant.send_signal(signal.SIGCONT)
        time.sleep(1.0)
        autopilot.send_signal(signal.SIGSTOP)  # ... then the autopilot does
        time.sleep(1.0)
        autopilot.send_signal(signal.SIGCONT)
        assert autopilot.wait(timeout=60) == 0
        assert plant.wait(timeout=60) == 0
    finally:
        gcs.close()
        for p in (plant, autopilot):
            if p.poll() is None:
                p.kill()
    plant_stats = _json_from_stderr(plant)
    assert plant_stats["silent_events"] >= 1  # type: ignore[operator]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["loop"]["plant_stale_events"] >= 1
    assert summary["loop"]["bad_outputs"] == 0
    cols = read_csv_columns(tmp_path / "run.csv")
    assert all(np.all(np.isfinite(cols[k])) for k in ("theta_m_rad", "theta_t_rad", "eps_rad", "eta_rad"))


def test_demo_through_the_ground_script_matches_in_process(tmp_path: Path, in_process) -> None:  # type: ignore[no-untyped-def]
    """Three processes: heli-ground uploads the paper trajectory (timed-trajectory encoding),
    selects mission mode and arms; the held plant is released on that tick."""
    summary = run_demo(DemoOptions(mode="lockstep", rate_hz=100.0, out=tmp_path, timeout_s=600))
    cols = read_csv_columns(tmp_path / "run.csv")
    flight = cols["t_s"] <= 120.0 + 1e-9
    d = np.stack(
        [np.interp(in_process["t_s"], cols["t_s"][flight], cols[k][flight]) - in_process[k]
         for k in ("x_m", "y_m", "z_m")], axis=1,
    )  # fmt: skip
    rms = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    assert rms <= 1e-3, f"ground-script flight vs in-process RMS {rms:.2e} m"
    rms_ref = in_process["summary"]["rms_pos_err_m"]["45-120"]  # type: ignore[index]
    assert abs(summary["rms_pos_err_m"]["45-120"] - rms_ref) < 0.002  # type: ignore[index]
    assert (tmp_path / "ground.tlog").stat().st_size > 0
    # After the spiral (still moving at 0.785 m/s) the reference brakes to a hold and the
    # landing starts there: no step in the reference, no kick beyond the start transient.
    after = cols["t_s"] > 120.0
    cmd = np.stack([cols[k] for k in ("x_ref_m", "y_ref_m", "z_ref_m")], axis=1)
    steps = np.linalg.norm(np.diff(cmd, axis=0), axis=1)
    assert steps[after[1:]].max() < 0.01, f"reference step {steps[after[1:]].max():.3f} m after 120 s"
    kick = float(np.abs(cols["theta_rad"][after]).max())
    assert kick <= float(np.abs(in_process["theta_rad"]).max()), f"pitch {kick:.3f} rad after the mission"
