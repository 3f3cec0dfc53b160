"""ArduPilot's helicopter firmware flies this bench's plant (`heli-sitl up --firmware ardupilot`),
with a ground station (pymavlink on TCP 5760) on top: the real `arducopter-heli` SITL binary
from ../shared/ardupilot (skipped with a message where it is not), inside a private network
namespace made by the test (the firmware opens TCP 5760-5763 and UDP 9002)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from netns import unshare_reason

from ground.plots import read_csv_columns
from heli_sitl.ardupilot import FirmwareNotFoundError, find_firmware

pytestmark = [pytest.mark.slow, pytest.mark.processes]
SCRIPT = Path(__file__).resolve().parent / "ardupilot_flight.py"


def _fly(tmp_path: Path, plant: str) -> tuple[dict[str, object], dict[str, np.ndarray]]:
    try:
        find_firmware(None)
    except FirmwareNotFoundError as exc:
        pytest.skip(f"ArduPilot's SITL binary is not here: {exc}")
    why = unshare_reason()
    if why is not None and "msgpack" not in why:  # (msgpack is python-can's, not needed here)
        pytest.skip(why)
    env = {**os.environ, "PARENT_NETNS": os.readlink("/proc/self/ns/net")}
    cmd = ["unshare", "--net", "--map-root-user", sys.executable, str(SCRIPT), str(tmp_path), plant]
    subprocess.run(cmd, env=env, timeout=240, check=True, cwd=Path(__file__).resolve().parent.parent)
    res = json.loads((tmp_path / "result.json").read_text())
    print({k: v for k, v in res.items() if k != "texts"})
    return res, read_csv_columns(tmp_path / "plant.csv")


def test_a_ground_station_sees_ardupilot_fly_the_plant(tmp_path: Path) -> None:
    """The ground station sees ArduPilot's heartbeat (helicopter), the parameters the bench
    gave it (the X-Cell's H3-120 head), its modes (GUIDED, then LAND) and its EKF status
    with an absolute horizontal position; ArduPilot arms, runs the rotor up and takes the plant
    to the 5 m it was asked for. (With ArduPilot's default heli gains its rate loops then
    oscillate on this plant and it crashes: the hover and the landing wait for the X-Cell's
    tuning, docs/ardupilot-tuning.md.)"""
    res, truth = _fly(tmp_path, "paper")
    assert "error" not in res, res.get("error")
    assert res["heartbeat"] == [4, 3]  # MAV_TYPE_HELICOPTER, MAV_AUTOPILOT_ARDUPILOTMEGA
    params = res["params"]
    assert isinstance(params, dict)
    assert (params["FRAME_CLASS"], params["H_SW_TYPE"], params["H_COL_MAX"]) == (6.0, 3.0, 1750.0)
    modes = res["modes"]
    assert isinstance(modes, list) and 4 in modes and modes[-1] == 9  # GUIDED, then LAND
    flags = res["ekf_flags"]
    assert isinstance(flags, int) and flags & 0x01 and flags & 0x10  # attitude, horizontal position
    t, z = truth["t"], truth["z"]
    climb = (t > float(str(res["t_takeoff"]))) & (t < float(str(res["t_hover_end"])))
    assert z[climb].max() > 4.5  # the 5 m it was asked for
