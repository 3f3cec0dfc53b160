"""`heli-sitl demo --servo-link can`: plant and autopilot as processes, servos on DroneCAN over
python-can udp_multicast, inside a network namespace this test makes (never the host's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from netns import NETNS_SETUP, unshare_reason

pytestmark = [pytest.mark.slow, pytest.mark.netns]


def _bus_was_clean(stderr: str, s: dict[str, Any]) -> None:
    """Every bus closed, no send error, a command per tick and NodeStatus at 1 Hz."""
    assert "not properly shut down" not in stderr  # every bus closed
    assert s["servo_link"] == "can"
    assert s["can"]["send_errors"] == 0 and s["can"]["commands_sent"] >= 12001
    assert s["can"]["node_status_sent"] >= 120  # 1 Hz of flight time


def test_demo_over_can_flies_the_paper_scenario(tmp_path: Path) -> None:
    """The README's command as written (through the ground script, the plant held until the
    autopilot's DroneCAN ArmingStatus says armed); the autostart form flies in the next test."""
    reason = unshare_reason()
    if reason is not None:
        pytest.skip(reason)
    demo = f"{sys.executable} -m heli_sitl.cli demo --servo-link can --can-bus udp_multicast --out {tmp_path}"
    proc = subprocess.run(
        ["unshare", "--net", "--", "bash", "-c", f"{NETNS_SETUP} && {demo}"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = json.loads((tmp_path / "summary.json").read_text())
    _bus_was_clean(proc.stderr, s)
    assert s["rms_pos_err_m"]["45-120"] <= 0.05
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
