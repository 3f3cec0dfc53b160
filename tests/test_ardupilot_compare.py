"""`heli-sitl compare` with an "ArduPilot heli" contender: the real `arducopter-heli` SITL binary
from ../shared/ardupilot (skipped with a message where it is not) flies the position step
beside the paper's TLC, through processes, in a private network namespace made by the test
(the firmware opens TCP 5760-5763 and UDP 9002-9008)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from netns import skip_without_firmware_netns

from heli_sitl.studies.comparison import FIRMWARE_NOTE

pytestmark = [pytest.mark.slow, pytest.mark.netns]
ROOT = Path(__file__).resolve().parent.parent

COMPARE = """
name = "The paper's TLC against ArduPilot"
plants = ["paper"]
reference = "TLC"
seeds = 2
worlds = []
campaigns = []

[[trajectory]]
name = "position_step"

[[contender]]
label = "TLC"

[[contender]]
label = "ArduPilot heli"
controller = "ardupilot"
"""


def test_compare_flies_ardupilot_beside_the_tlc(tmp_path: Path) -> None:
    """Both contenders in the trajectory table, scored by the same scorecard. Measured for
    ArduPilot on the 5 m position step (paper plant), two runs: transient RMS 0.088-0.115 m,
    overshoot 0.116-0.121 m, steady RMS 0.075-0.099 m; settling to 0.1 m 6.1 s or never (then
    with its EKF's height ~0.1 m off the truth, on the band's edge: not asserted; since the
    barometers are noise-free, within 0.01 m: tests/test_ardupilot_sitl.py); nothing lost.
    (The TLC, from the scenario's initial state off the path: transient 0.23 m, overshoot
    0.45 m, steady 0.022 m.)"""
    skip_without_firmware_netns()
    spec = tmp_path / "ap.toml"
    spec.write_text(COMPARE)
    out, work = tmp_path / "report", tmp_path / "work"
    inner = (f"ip link set lo up && exec {sys.executable} -m heli_sitl.cli compare {spec} --out {out} "
             f"--work {work} --quiet")  # fmt: skip
    proc = subprocess.run(["unshare", "--net", "--map-root-user", "bash", "-c", inner], cwd=ROOT,
                          capture_output=True, text=True, timeout=400, env=dict(os.environ))  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    res = json.loads((out / "comparison.json").read_text())
    row = res["plants"]["paper"]["trajectories"]["position_step"]
    print(json.dumps(row, indent=1))
    assert set(row) == {"TLC", "ArduPilot heli"}
    ap = row["ArduPilot heli"]
    assert ap["lost"] == 0.0
    assert ap["steady_rms_m"] < 0.2 and ap["transient_rms_m"] < 0.23  # twice the worst measured
    assert 0.0 < ap["overshoot_m"] < 0.25  # twice the worst measured (0.121 m)
    report = (out / "report.md").read_text()
    assert "ArduPilot heli" in report and FIRMWARE_NOTE[:60] in report
    assert (work / "paper" / "ardupilot-heli-position_step" / "plant.csv").is_file()
