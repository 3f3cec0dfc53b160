"""The 3-D view in a real browser (docs/view.md): `heli-sitl demo --view` (lockstep) shows the
vehicle and the flight's own numbers in headless Chromium, and flies the same run.csv, bit for
bit, as a demo without it; `heli-sitl view DIR` replays a saved flight in the same page. Also
the pieces without a browser: the telemetry feed's pairing of a target with its tick's
position, and the recordings the replay reads.

Chromium and chromedriver are Debian's (/usr/bin); without them the browser tests are skipped
with that reason. HELI_SITL_VIEW_SCREENSHOT=FILE keeps a copy of the live view's screenshot
(docs/img/view.png is one)."""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ports import new_port
from view_browser import (
    ERROR_RE,
    MISSING,
    TIME_RE,
    orange_pixels,
    page_text,
    poll,
    screenshot,
    start_chromium,
)

from autopilot.mcap_log import read_run_csv
from heli_common import frames
from heli_common.wire.mavlink.udp import mavlink2
from heli_sitl.view.mavlink_feed import MavlinkFeed
from heli_sitl.view.recording import RecordingError, load_recording

pytestmark = pytest.mark.processes
ROOT = Path(__file__).resolve().parent.parent
DURATION_S = "5"  # the demo's flight (lockstep: ~0.5 s of wall time)
needs_browser = pytest.mark.skipif(bool(MISSING), reason=f"no {' and no '.join(MISSING)} on this machine "
                                   "(Debian: apt-get install chromium chromium-driver)")  # fmt: skip
# bounds of the waits, never reached when all is well (the test takes ~15-30 s): a lockstep flight
# beside 4 busy workers on 2 cores has taken 90 s (its plant and autopilot starved); the page's
# first WebGL frame on SwiftShader under that load ~30 s
FLIGHT_WAIT_S = 300
PAGE_WAIT_S = 120
MIN_ORANGE_PIXELS = 300  # measured ~1500 in the 120 x 120 box at the centre (the fuselage's side)


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """One Chromium for the module's tests (its start is the slowest part of each)."""
    if MISSING:
        pytest.skip(f"no {' and no '.join(MISSING)} on this machine")
    driver = start_chromium(tmp_path_factory.mktemp("chromium-profile"))
    try:
        yield driver
    finally:
        driver.quit()


def _start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as fh:
        return subprocess.Popen([sys.executable, "-m", "heli_sitl.cli", *args], stdout=fh,
                                stderr=subprocess.STDOUT, cwd=ROOT)  # fmt: skip


def _line(log: Path, text: str) -> str | None:
    for line in log.read_text(errors="replace").splitlines():
        if text in line:
            return line
    return None


def _stop(p: subprocess.Popen[bytes]) -> int:
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
    try:
        return p.wait(timeout=20)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()
        raise


@needs_browser
def test_demo_view_shows_the_flight_and_leaves_it_unchanged(tmp_path: Path, browser: Any) -> None:
    """Both demos fly at once (lockstep: each is reproducible whatever the load); the one with
    the view keeps its last frame up after the flight, where the browser reads it."""
    port = new_port()
    demo = ["demo", "--autostart", "--mode", "lockstep", "--duration-s", DURATION_S]
    plain = _start([*demo, "--out", str(tmp_path / "plain")], tmp_path / "plain.log")
    viewed = _start([*demo, "--out", str(tmp_path / "viewed"), "--view", "--view-port", str(port)],
                    tmp_path / "viewed.log")  # fmt: skip
    try:
        poll("the viewed demo's flight to end", lambda: _line(tmp_path / "viewed.log", "the flight is over")
             or (_fail(viewed, tmp_path / "viewed.log") if viewed.poll() is not None else None),
             FLIGHT_WAIT_S)  # fmt: skip
        browser.get(f"http://127.0.0.1:{port}/")
        poll("the error panel", lambda: ERROR_RE.search(page_text(browser)), PAGE_WAIT_S)
        def fuselage_seen() -> np.ndarray | None:
            a = screenshot(browser, tmp_path / "view.png")
            return a if orange_pixels(a) >= MIN_ORANGE_PIXELS else None

        rgb = poll("the fuselage at the centre of the canvas", fuselage_seen, PAGE_WAIT_S)
        text = page_text(browser)  # the panels as they stay (the demo held its last frame before it said so)
        if os.environ.get("HELI_SITL_VIEW_SCREENSHOT"):
            shutil.copy(tmp_path / "view.png", os.environ["HELI_SITL_VIEW_SCREENSHOT"])
    finally:
        rc = _stop(viewed)
        assert plain.wait(timeout=FLIGHT_WAIT_S) == 0, (tmp_path / "plain.log").read_text()[-2000:]
    assert rc == 0, (tmp_path / "viewed.log").read_text()[-2000:]
    print(f"orange pixels at the centre: {orange_pixels(rgb)}; "
          f"{_line(tmp_path / 'viewed.log', 'view pushed')}")  # fmt: skip
    # the page's numbers are the flight's: the error of the tick it names, from run.csv
    m = ERROR_RE.search(text)
    assert m is not None
    approx, err_page, t_page = m.group(1) == "≈", float(m.group(2)), float(m.group(3))
    cols = read_run_csv(tmp_path / "viewed" / "run.csv")
    i = int(np.argmin(np.abs(cols["t_s"] - t_page)))
    assert abs(cols["t_s"][i] - t_page) < 0.006
    pos = [cols[k][i] for k in ("x_m", "y_m", "z_m")]
    ref = [cols[k][i] for k in ("x_ref_m", "y_ref_m", "z_ref_m")]
    # the page rounds to 0.1 mm; the telemetry carries float32 (run.csv 9 digits); a position
    # interpolated over 50 ms (the target's tick without one of its own) is within a millimetre
    assert err_page == pytest.approx(math.dist(pos, ref), abs=1e-3 if approx else 1.5e-4)
    assert t_page == pytest.approx(float(DURATION_S), abs=0.06)  # the last frame: the flight's end
    assert "MISSION" in text and "ARMED" in text  # the autostarted flight's mode and arming
    assert "live: paper" in text
    # the view changed nothing: the same flight, bit for bit
    assert (tmp_path / "viewed" / "run.csv").read_bytes() == (tmp_path / "plain" / "run.csv").read_bytes()
    pushed = _line(tmp_path / "viewed.log", "view pushed")
    assert pushed is not None and int(pushed.split("view pushed ")[1].split()[0]) >= 1


def _fail(p: subprocess.Popen[bytes], log: Path) -> None:
    raise AssertionError(f"the process ended early ({p.returncode}):\n{log.read_text()[-3000:]}")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 5 s flight as a run directory leaves it (run.csv, flight.parquet): the paper's
    reference at 100 Hz, flown 0.3 m north of it with a gentle roll (no numerics compiled)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from autopilot.metrics import CSV_HEADER
    from autopilot.scenario import Scenario

    d = tmp_path_factory.mktemp("flight")
    t = np.round(np.arange(501) * 0.01, 2)
    ref = Scenario.load("paper").trajectory.sample(t)[:, 0:3]
    cols = {k: np.zeros_like(t) for k in CSV_HEADER}
    cols["t_s"] = t
    for i, k in enumerate(("x", "y", "z")):
        cols[f"{k}_ref_m"] = ref[:, i]
        cols[f"{k}_m"] = ref[:, i] + (0.3 if k == "x" else 0.0)
    cols["phi_rad"] = 0.1 * np.sin(t)
    cols["theta_m_rad"] = np.full_like(t, 0.09)
    rows = np.column_stack([cols[k] for k in CSV_HEADER])
    np.savetxt(d / "run.csv", rows, delimiter=",", fmt="%.9g", header=",".join(CSV_HEADER), comments="")
    pq.write_table(pa.table(cols), d / "flight.parquet")
    return d


@needs_browser
def test_view_replays_a_saved_flight(tmp_path: Path, browser: Any, run_dir: Path) -> None:
    port = new_port()
    p = _start(["view", str(run_dir), "--port", str(port), "--paused"], tmp_path / "view.log")
    try:
        poll("the replay's address", lambda: _line(tmp_path / "view.log", "replay of")
             or (_fail(p, tmp_path / "view.log") if p.poll() is not None else None), PAGE_WAIT_S)  # fmt: skip
        browser.get(f"http://127.0.0.1:{port}/")
        poll("the fuselage in the replay",
             lambda: (True if orange_pixels(screenshot(browser, tmp_path / "replay.png")) >= MIN_ORANGE_PIXELS
                      else None), PAGE_WAIT_S)  # fmt: skip

        def t_shown() -> float | None:
            m = TIME_RE.search(page_text(browser))
            return float(m.group(1)) if m else None

        t1 = poll("the replay's time", t_shown, PAGE_WAIT_S)
        assert t1 == 0.0  # paused at the first row
        from selenium.webdriver.common.by import By

        browser.find_element(By.XPATH, "//button[normalize-space()='play']").click()
        t2 = poll("the replay's time to move on",
                  lambda: (t if (t := t_shown()) is not None and t > t1 else None), PAGE_WAIT_S)  # fmt: skip
        assert 0.0 < t2 <= 5.0
        assert "replay: " in page_text(browser)
    finally:
        assert _stop(p) == 0, (tmp_path / "view.log").read_text()[-2000:]


def _msg(m: Any) -> Any:
    """A message as the vehicle (system 1, component 1) sends it."""
    m.pack(mavlink2.MAVLink(None, srcSystem=1, srcComponent=1))
    return m


def test_feed_pairs_each_target_with_the_position_of_its_tick() -> None:
    feed = MavlinkFeed(0)
    try:
        hb = mavlink2.MAVLink_heartbeat_message(2, 0, mavlink2.MAV_MODE_FLAG_SAFETY_ARMED, 0, 4, 3)
        feed.on_message(_msg(hb))
        for t_ms, x in ((1000, 1.0), (1010, 2.0)):
            feed.on_message(_msg(mavlink2.MAVLink_attitude_message(t_ms, 0.1, -0.2, 0.3, 0, 0, 0)))
            n, e, d = frames.nwu_to_ned((x, 0.0, 5.0))
            feed.on_message(_msg(mavlink2.MAVLink_local_position_ned_message(t_ms, n, e, d, 0, 0, 0)))
        n, e, d = frames.nwu_to_ned((1.5, 0.0, 5.0))  # the target of the first tick (1000 ms)
        feed.on_message(_msg(mavlink2.MAVLink_position_target_local_ned_message(
            1000, 1, 0, n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)))  # fmt: skip
        frame, trail = feed.snapshot()
        # a target of a tick without a position (1015 ms): against the one interpolated to it
        n, e, d = frames.nwu_to_ned((3.0, 0.0, 5.0))
        feed.on_message(_msg(mavlink2.MAVLink_position_target_local_ned_message(
            1015, 1, 0, n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)))  # fmt: skip
        n, e, d = frames.nwu_to_ned((4.0, 0.0, 5.0))
        feed.on_message(_msg(mavlink2.MAVLink_local_position_ned_message(1020, n, e, d, 0, 0, 0)))
        later, _ = feed.snapshot()
    finally:
        feed.stop()
    assert frame is not None
    assert frame.err_m == pytest.approx(0.5) and frame.err_exact  # against 1.0, not the newer 2.0
    assert frame.err_t_s == pytest.approx(0.0)  # the arming tick is t = 0
    assert frame.t_s == pytest.approx(0.01) and frame.pos_nwu_m == pytest.approx((2.0, 0.0, 5.0))
    assert frame.euler_flu_rad == pytest.approx(frames.euler_frd_to_flu((0.1, -0.2, 0.3)))
    assert frame.armed is True
    assert len(trail) == 2
    assert later is not None and not later.err_exact
    assert later.err_m == pytest.approx(0.0) and later.err_t_s == pytest.approx(0.015)  # 2.0 -> 4.0 at 1/2


def test_recordings_the_replay_reads(run_dir: Path, tmp_path: Path) -> None:
    csv = load_recording(run_dir)  # the directory: its run.csv first
    pq = load_recording(run_dir / "flight.parquet")
    assert csv.source.name == "run.csv" and len(csv.t_s) == 501
    f_csv, f_pq = csv.frame(csv.index_at(2.5)), pq.frame(pq.index_at(2.5))
    assert f_csv.t_s == pytest.approx(2.5) and f_pq.t_s == pytest.approx(2.5)
    assert f_csv.pos_nwu_m == pytest.approx(f_pq.pos_nwu_m, abs=1e-8)  # run.csv keeps 9 digits
    assert f_csv.err_m == pytest.approx(0.3, abs=1e-7) and f_pq.err_m == pytest.approx(0.3, abs=1e-9)
    assert f_csv.euler_flu_rad[0] == pytest.approx(0.1 * math.sin(2.5), abs=1e-9)
    assert f_csv.pitches_rad is not None and f_csv.pitches_rad[0] == pytest.approx(0.09)
    (tmp_path / "x.txt").write_text("t\n")
    with pytest.raises(RecordingError, match=r"not a run\.csv"):
        load_recording(tmp_path / "x.txt")
    with pytest.raises(RecordingError, match=r"no run\.csv"):
        load_recording(tmp_path)


def test_ardupilot_view_wiring_asks_the_firmware_for_its_streams() -> None:
    """`up --firmware ardupilot --view` (no firmware here): SERIAL2 goes to the view's port, and
    the view answers an ArduPilot HEARTBEAT with REQUEST_DATA_STREAM (MAVProxy's way)."""
    import socket

    from heli_sitl.launch.ardupilot import ArduPilotOptions, commands

    def firmware_cmd(opts: ArduPilotOptions) -> list[str]:
        return next(cmd for name, cmd, _ in commands(opts) if name == "arducopter-heli")

    assert "udpclient:127.0.0.1:23456" in firmware_cmd(ArduPilotOptions(Path("fw"), view_port=23456))
    assert "--serial2" not in firmware_cmd(ArduPilotOptions(Path("fw")))
    feed = MavlinkFeed(0).start()
    fake = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        fake.bind(("127.0.0.1", 0))
        fake.settimeout(5.0)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        hb = mavlink2.MAVLink_heartbeat_message(mavlink2.MAV_TYPE_HELICOPTER,
                                                mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)  # fmt: skip
        fake.sendto(hb.pack(mav), ("127.0.0.1", feed.port))
        data, _ = fake.recvfrom(512)  # waits at most 5 s (the timeout above)
        msgs = mavlink2.MAVLink(None).parse_buffer(data) or []
    finally:
        fake.close()
        feed.stop()
    assert [m.get_type() for m in msgs] == ["REQUEST_DATA_STREAM"]
    assert msgs[0].req_stream_id == mavlink2.MAV_DATA_STREAM_ALL and msgs[0].start_stop == 1


def test_a_held_last_frame_is_where_a_new_browser_starts_looking() -> None:
    """After a demo's flight: the view shows the feed's last frame and makes it the initial
    camera of browsers that connect later (not the path's start, where it began)."""
    from heli_sitl.view.live import open_live_view
    from heli_sitl.view.scene import CAMERA_OFFSET_M

    path = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0]])
    view = open_live_view(new_port(), path_nwu_m=path)
    try:
        start = view.scene.server.initial_camera.position.copy()
        armed = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        view.feed.on_message(_msg(mavlink2.MAVLink_heartbeat_message(2, 0, armed, 0, 4, 3)))
        n, e, d = frames.nwu_to_ned((7.0, -3.0, 4.0))
        view.feed.on_message(_msg(mavlink2.MAVLink_local_position_ned_message(5000, n, e, d, 0, 0, 0)))
        view.hold_last_frame(quiet_s=0.05, timeout_s=2.0)
        held = view.scene.server.initial_camera
        shown = view.scene._last
    finally:
        view.close()
    assert start == pytest.approx(np.add(path[0], CAMERA_OFFSET_M))
    assert shown is not None and shown.pos_nwu_m == pytest.approx((7.0, -3.0, 4.0))
    assert held.position == pytest.approx(np.add((7.0, -3.0, 4.0), CAMERA_OFFSET_M))
    assert held.look_at == pytest.approx((7.0, -3.0, 4.0))


@pytest.mark.parametrize("name", ["flight.mcap", "run.csv", "flight.parquet", "flight.tlog"])
def test_a_file_its_reader_cannot_read_is_a_clear_error(tmp_path: Path, name: str) -> None:
    """Garbage under each accepted name: one line naming the file and the reader's complaint
    (`heli-sitl view` prints it and exits 2), never a traceback."""
    bad = tmp_path / name
    bad.write_bytes(b"garbage\x00\x01 not a flight\n")
    with pytest.raises(RecordingError, match=rf"{name}: (cannot be read as|no column|no rows)"):
        load_recording(bad)
    out = subprocess.run([sys.executable, "-m", "heli_sitl.cli", "view", str(bad)], capture_output=True,
                         text=True, timeout=60, cwd=ROOT)  # fmt: skip
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert name in out.stderr
