"""Bad numbers on the command line, and the flight record when a process ends badly.

Every numeric option is checked where it is parsed: a one-line usage error (exit 2), never a
traceback or a silent default. The autopilot streams run.csv as it flies (a kill -9 loses
about a second of it), writes a record of an unarmed session without crashing, and the
launcher's exit status says when one of its children failed.
"""

from __future__ import annotations

import importlib
import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from ports import new_port
from vehicle import free_ports, spawn_up

from autopilot import cli as autopilot_cli
from ground import cli as ground_cli
from ground.plots import read_csv_columns
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp
from heli_sitl import cli as sitl_cli
from heli_sitl.launch.children import spawn

BAD_OPTIONS = [
    (sitl_cli.main, ["run", "--port", "99999"], "--port"),
    (sitl_cli.main, ["run", "--rate-hz", "0"], "--rate-hz"),
    (sitl_cli.main, ["run", "--plant-substeps", "0"], "--plant-substeps"),
    (sitl_cli.main, ["run", "--timeout-s", "nan"], "--timeout-s"),
    (sitl_cli.main, ["simulate", "--duration-s", "-1", "--out", "x"], "--duration-s"),
    (sitl_cli.main, ["up", "--gcs-port", "0"], "--gcs-port"),
    (sitl_cli.main, ["demo", "--rate-hz", "5000", "--out", "x"], "--rate-hz"),
    (autopilot_cli.main, ["--rate-hz", "0"], "--rate-hz"),
    (autopilot_cli.main, ["--stale-timeout-s", "0"], "--stale-timeout-s"),
    (autopilot_cli.main, ["--can-node-id", "200"], "--can-node-id"),
    (ground_cli.main, ["log", "--gcs-port", "70000", "--out", "x.tlog"], "--gcs-port"),
    (ground_cli.main, ["fly", "f.waypoints", "--timeout-s", "-3"], "--timeout-s"),
]


@pytest.mark.parametrize(("main", "argv", "option"), BAD_OPTIONS)
def test_bad_numbers_are_usage_errors(main, argv, option, capsys: pytest.CaptureFixture[str]) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(("heli-sitl", "heli-autopilot", "heli-ground")) and option in err[-1]
    assert "Traceback" not in "\n".join(err)


def test_a_port_that_would_talk_to_itself_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert sitl_cli.main(["run", "--port", "5999", "--autopilot-port", "5999"]) == 2
    assert "must differ" in capsys.readouterr().err
    assert autopilot_cli.main(["--port", "5998", "--plant-port", "5998"]) == 2
    assert "must differ" in capsys.readouterr().err


def test_a_missing_signing_key_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    rc = autopilot_cli.main(["--signing-key", "/nonexistent/key", "--port", str(new_port()),
                             "--plant-port", str(new_port()), "--local-gcs-port", "0",
                             "--local-api-port", "0"])  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "signing key" in err[0]


@pytest.mark.slow
def test_stopping_before_arming_writes_an_empty_record(tmp_path: Path) -> None:
    ports = free_ports()
    up = spawn_up(ports, "--out", str(tmp_path))
    with MavlinkUdp((LOOPBACK, ports.gcs), drop_nonfinite=False) as gcs:
        deadline = time.monotonic() + 120.0
        while not any(m.get_type() == "HEARTBEAT" for m, _ in gcs.recv(0.5)):
            assert time.monotonic() < deadline, "no heartbeat"
    up.send_signal(signal.SIGTERM)
    assert up.wait(timeout=60) == 0, up.output()[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ticks"] == 0 and summary["rms_pos_err_m"] == {}
    assert (tmp_path / "run.csv").read_text().startswith("t_s,x_m,y_m,z_m,")
    assert "Traceback" not in (tmp_path / "logs" / "autopilot.log").read_text()


@pytest.mark.slow
def test_a_killed_autopilot_leaves_its_record_up_to_a_second_before(tmp_path: Path) -> None:
    """run.csv is flushed once a second of flight: SIGKILLed after 5 s of flight, the record
    ends less than 1.5 s of the vehicle's clock before the last telemetry it sent (what a
    ground station saw of it: ATTITUDE's time_boot_ms)."""
    pp, ap, gcs_port = new_port(), new_port(), new_port()
    common = ["--mode", "realtime", "--rate-hz", "100"]
    plant = spawn([sys.executable, "-m", "heli_sitl.cli", "run", *common, "--port", str(pp),
                   "--autopilot-port", str(ap)], "plant")  # fmt: skip
    with MavlinkUdp((LOOPBACK, gcs_port)) as gcs:  # the ground station the vehicle sends to
        autopilot = spawn([sys.executable, "-m", "autopilot.cli", *common, "--port", str(ap), "--plant-port",
                           str(pp), "--autostart", "--out", str(tmp_path), "--gcs-port", str(gcs_port),
                           "--api-port", str(new_port()), "--local-gcs-port", str(new_port()),
                           "--local-api-port", str(new_port())], "autopilot")  # fmt: skip
        try:
            deadline = time.monotonic() + 120.0  # (a bound on a cold compile, not a measurement)
            vehicle_s, flying_from_s = -1.0, math.inf
            while vehicle_s < flying_from_s + 5.0:
                assert time.monotonic() < deadline and autopilot.proc.poll() is None, "no flight"
                for m, _ in gcs.recv(0.2):
                    if m.get_type() == "ATTITUDE":
                        vehicle_s = max(vehicle_s, m.time_boot_ms / 1e3)
                csv = tmp_path / "run.csv"
                if math.isinf(flying_from_s) and csv.exists() and csv.stat().st_size > 2000:
                    flying_from_s = vehicle_s  # rows flushed: flying
            autopilot.proc.kill()  # SIGKILL: no chance to write anything
            for m, _ in gcs.recv(0.5):  # what it sent before it died
                if m.get_type() == "ATTITUDE":
                    vehicle_s = max(vehicle_s, m.time_boot_ms / 1e3)
            autopilot.wait(timeout=10)
        finally:
            plant.kill()
            autopilot.kill()
    cols = read_csv_columns(tmp_path / "run.csv")
    print(f"record ends at {cols['t_s'][-1]:.2f} s; the last telemetry at {vehicle_s:.2f} s")
    assert vehicle_s - 1.5 < cols["t_s"][-1] <= vehicle_s, f"record ends at {cols['t_s'][-1]:.2f} s"
    assert np.all(np.diff(cols["t_s"]) > 0) and np.all(np.isfinite(cols["x_m"]))
    assert np.all(np.abs(np.diff(cols["psi_rad"])) < 0.5)  # unwrapped across the flushes


@pytest.mark.slow
def test_the_launcher_exit_status_names_a_failed_child(tmp_path: Path) -> None:
    ports = free_ports()
    with MavlinkUdp((LOOPBACK, ports.local_gcs)):  # the autopilot's own GCS port is taken
        up = spawn_up(ports)
        assert up.wait(timeout=120) == 1
    assert "autopilot" in up.last_error_line() and "busy" in up.last_error_line()


def test_the_benchmark_runner_answers_help_and_unknown_groups() -> None:
    root = Path(__file__).resolve().parent.parent
    helped = subprocess.run([sys.executable, "-m", "benchmarks", "--help"], cwd=root, capture_output=True,
                            text=True, timeout=120)  # fmt: skip
    assert helped.returncode == 0 and "usage: python -m benchmarks" in helped.stdout
    unknown = subprocess.run([sys.executable, "-m", "benchmarks", "nosuchgroup"], cwd=root,
                             capture_output=True, text=True, timeout=120)  # fmt: skip
    assert unknown.returncode == 2 and "no group matches nosuchgroup" in unknown.stderr
    assert "Traceback" not in unknown.stderr


def test_the_performance_page_table_is_the_benchmarks_own(tmp_path: Path) -> None:
    """docs/performance.md's table is written by `make bench` between its markers: the markers
    are there (and no longer in the README), every group in the table is a registered benchmark,
    and the writer replaces the section whole (nothing else in the file moves)."""
    root = Path(__file__).resolve().parent.parent
    sys.path.insert(0, str(root))
    from benchmarks import MODULES, REGISTRY
    from benchmarks.__main__ import TABLE_BEGIN, TABLE_END, write_table

    for mod in MODULES:
        importlib.import_module(mod)
    assert "--table docs/performance.md" in (root / "Makefile").read_text()
    assert TABLE_BEGIN not in (root / "README.md").read_text()
    page = (root / "docs" / "performance.md").read_text()
    assert page.count(TABLE_BEGIN) == 1 and page.count(TABLE_END) == 1
    section = page.split(TABLE_BEGIN, 1)[1].split(TABLE_END, 1)[0]
    titles = {t for t, _ in REGISTRY}
    groups = {line.split("|")[1].strip() for line in section.splitlines() if line.startswith("| ")}
    assert groups - {"group"} <= titles, groups - titles - {"group"}
    copy = tmp_path / "performance.md"
    copy.write_text("# x\nbefore\n" + TABLE_BEGIN + "\nold\n" + TABLE_END + "\nafter\n")
    write_table(copy, "| group | benchmark |\n| plant | step |")
    text = copy.read_text()
    assert text.startswith("# x\nbefore\n" + TABLE_BEGIN) and text.endswith(TABLE_END + "\nafter\n")
    assert "old" not in text and "| plant | step |" in text and "make bench" in text
    copy.write_text("no markers\n")
    with pytest.raises(ValueError, match="no <!-- make bench: begin -->"):
        write_table(copy, "x")


@pytest.mark.parametrize("n", [0, 1, 6, 7, 8, 21, 30])
def test_the_recorder_keeps_every_row_across_its_blocks(n: int) -> None:
    from autopilot.runner import Recorder

    r = Recorder(capacity=7)
    for k in range(n):
        x, ref = np.full(12, float(k)), np.full(9, -1.0 * k)
        r.add(k * 0.01, x, ref, np.full(4, k / 2), np.zeros(7), k, k % 2 == 0)
    for start in range(n + 2):
        rows = r.rows_array(start)
        assert rows.shape == (max(0, n - start), Recorder.WIDTH)
        assert np.array_equal(rows[:, 0], np.arange(start, n) * 0.01)
        assert np.array_equal(rows[:, 1], np.arange(start, n, dtype=float))
    rec = r.record(0.0, {})
    assert rec.t_s.size == n and np.array_equal(rec.traj_t_s, np.arange(n, dtype=float))


@pytest.mark.parametrize("rotor", [False, True])
def test_the_streamed_run_csv_is_the_records_csv(tmp_path: Path, rotor: bool) -> None:
    """run.csv streamed as it flies (flushed every 5 rows, across blocks of 7, the yaw wrapping
    past +-pi between flushes, the rotor plant's columns where its truth comes) is byte for
    byte the csv the whole record writes at the end."""
    from autopilot.runner import Recorder
    from heli_common.wire.mavlink.sim_protocol import StateSample

    rng = np.random.default_rng(3)
    r = Recorder(capacity=7, stream_csv=tmp_path / "run.csv", flush_every=5)
    for k in range(33):
        x = rng.normal(size=12)
        x[5] = (0.4 * k + math.pi) % (2 * math.pi) - math.pi  # yaw turning: wraps every ~16 rows
        truth = StateSample(k, x, rotor=tuple(rng.normal(size=4)) if rotor else None)  # type: ignore[arg-type]
        r.add(k * 0.01, x, rng.normal(size=9), rng.normal(size=4), rng.normal(size=7), k, False, truth)
        r.flush_if_due()
    r.close()
    r.record(0.0, {}).write_csv(tmp_path / "whole.csv")
    streamed = (tmp_path / "run.csv").read_text()
    assert streamed == (tmp_path / "whole.csv").read_text()
    assert streamed.splitlines()[0].endswith("throttle") == rotor and len(streamed.splitlines()) == 34
