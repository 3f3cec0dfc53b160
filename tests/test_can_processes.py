"""`heli-sitl demo --servo-link can`: plant and autopilot as processes, servos on DroneCAN over
python-can udp_multicast, inside a network namespace this test makes (never the host's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from netns import NETNS_SETUP, unshare_reason

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("extra", ["", "--autostart"], ids=["readme-via-ground-script", "autostart"])
def test_demo_over_can_flies_the_paper_scenario(tmp_path: Path, extra: str) -> None:
    """The README's command as written (through the ground script, the plant held until the
    autopilot's DroneCAN ArmingStatus says armed), and the autostart form."""
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    demo = (f"{sys.executable} -m heli_sitl.cli demo --servo-link can --can-bus udp_multicast {extra} "
            f"--out {tmp_path}")  # fmt: skip
    proc = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {demo}"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "not properly shut down" not in proc.stderr  # every bus closed
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["servo_link"] == "can"
    assert s["rms_pos_err_m"]["45-120"] <= 0.05
    assert s["max_pos_err_40_45_m"] <= 0.3
    assert s["can"]["send_errors"] == 0 and s["can"]["commands_sent"] >= 12001
    assert s["can"]["node_status_sent"] >= 120  # 1 Hz of flight time
