"""Not a test: the script that takes docs/img/view.png and measures the live view's frame rate.

    .venv/bin/python tests/view_screenshot.py docs/img/view.png [--duration-s 60]

It flies `heli-sitl demo --autostart --mode lockstep --duration-s D --view` (the paper's
scenario), opens the page in headless Chromium while the vehicle flies, waits for the end of
the flight, closes viser's "software WebGL" notice, saves the screenshot and prints the
demo's closing line of the view: frames pushed to the browsers and their rate (docs/view.md,
"Cost"). Every wait is bounded."""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from view_browser import orange_pixels, page_text, screenshot, start_chromium

ROOT = Path(__file__).resolve().parent.parent
CLOSE_NOTICES = ("document.querySelectorAll('.mantine-Notification-closeButton, "
                 "[class*=Notification] button').forEach(b => b.click())")  # fmt: skip


def _wait_for(log: Path, text: str, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while text not in log.read_text(errors="replace"):
        if proc.poll() is not None:
            raise SystemExit(f"the demo ended early ({proc.returncode}):\n{log.read_text()[-2000:]}")
        if time.monotonic() > end:
            raise SystemExit(f"timed out after {timeout_s:.0f} s waiting for {text!r}")
        time.sleep(0.1)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("png", type=Path)
    p.add_argument("--duration-s", type=float, default=60.0)
    p.add_argument("--port", type=int, default=28211)
    a = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="heli-view-"))
    log = work / "demo.log"
    with log.open("wb") as fh:
        cmd = [sys.executable, "-m", "heli_sitl.cli", "demo", "--autostart", "--mode", "lockstep",
               "--duration-s", str(a.duration_s), "--out", str(work / "run"),
               "--view", "--view-port", str(a.port)]  # fmt: skip
        demo = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT)  # fmt: skip
    browser = None
    try:
        _wait_for(log, "live view at", demo, 120)
        browser = start_chromium(work / "chromium-profile")
        browser.get(f"http://127.0.0.1:{a.port}/")
        _wait_for(log, "the flight is over", demo, 600)
        time.sleep(3.0)  # the last frames reach the page
        browser.execute_script(CLOSE_NOTICES)
        time.sleep(1.0)
        rgb = screenshot(browser, a.png)
        print(f"wrote {a.png}: {orange_pixels(rgb)} fuselage-orange pixels at the centre")
        print("\n".join(page_text(browser).splitlines()[:8]))
    finally:
        if browser is not None:
            browser.quit()
        if demo.poll() is None:
            demo.send_signal(signal.SIGTERM)
        demo.wait(timeout=30)
    print("\n".join(line for line in log.read_text().splitlines() if "view pushed" in line or "wall" in line))


if __name__ == "__main__":
    main()
