"""The plant as ArduPilot's JSON physics (heli_plant/ardupilot_backend.py), driven by a fake
firmware socket on loopback: the plant process (`heli-sitl run --backend ardupilot-json`)
steps once per new frame, answers re-sends without a step, drops bad packets, and the
rotor's interlock (channel 8) decides whether the blades make thrust."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from ports import new_port

from heli_common.vehicle.scenario_file import load_vehicle
from heli_common.vehicle.swashplate import Swashplate
from heli_common.wire.ardupilot_json import MAGIC_16, encode_servo_packet
from heli_plant.ardupilot_backend import ArduPilotBackend
from heli_plant.ardupilot_link import ArduPilotJsonLink
from heli_plant.model import Plant

RATE_HZ = 1200
REST = [1500] * 16  # swash and tail at neutral; channel 8 (HeliRSC) set below
RSC_OFF, RSC_ON = 1000, 1660  # H_RSC_SETPOINT 66 % once the rotor is engaged


def _frame(count: int, collective_us: int = 1500, rsc_us: int = RSC_ON) -> bytes:
    pwm = list(REST)
    pwm[0:3] = [collective_us] * 3  # H3-120: all three servos up = collective
    pwm[7] = rsc_us
    return encode_servo_packet(RATE_HZ, count, pwm)


def _state(data: bytes) -> dict[str, object]:
    assert data.startswith(b"\n") and data.endswith(b"\n")
    doc = json.loads(data)
    assert isinstance(doc, dict)
    return doc


@pytest.fixture
def plant_process(tmp_path: Path) -> Iterator[tuple[socket.socket, tuple[str, int], subprocess.Popen[bytes]]]:
    port = new_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "heli_sitl.cli", "run", "--backend", "ardupilot-json", "--port", str(port),
         "--duration-s", "2.0", "--out", str(tmp_path), "-v"],
        stderr=subprocess.PIPE,
    )  # fmt: skip
    fw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fw.bind(("127.0.0.1", 0))
    try:
        yield fw, ("127.0.0.1", port), proc
    finally:
        fw.close()
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


def test_the_plant_process_steps_once_per_new_frame_and_survives_bad_packets(
    plant_process: tuple[socket.socket, tuple[str, int], subprocess.Popen[bytes]], tmp_path: Path
) -> None:
    fw, addr, proc = plant_process
    # the first frame: the vehicle at rest at home, level, one step of 1/1200 s
    first = b""
    fw.settimeout(0.25)
    for _ in range(120):  # until the process is listening (a frame before that is lost)
        fw.sendto(_frame(0, rsc_us=RSC_OFF), addr)
        try:
            first, _ = fw.recvfrom(4096)
            break
        except TimeoutError:
            continue
    while True:  # answers to copies of frame 0 sent while the process started (re-sends)
        try:
            assert fw.recvfrom(4096)[0] == first
        except TimeoutError:
            break
    fw.settimeout(10.0)
    s0 = _state(first)
    assert s0["timestamp"] == pytest.approx(1.0 / RATE_HZ, abs=1e-6)
    imu = s0["imu"]
    assert isinstance(imu, dict)
    np.testing.assert_allclose(imu["accel_body"], [0.0, 0.0, -9.81], atol=1e-3)  # FRD specific force
    # a re-send of the same frame: the same answer, no step
    fw.sendto(_frame(0, rsc_us=RSC_OFF), addr)
    again, _ = fw.recvfrom(4096)
    assert again == first
    # bad packets: dropped, no answer, no step
    for bad in (b"\x00" * 5, _frame(1)[:-2], _frame(1) + b"\x00\x00",
                (MAGIC_16 + 1).to_bytes(2, "little") + _frame(1)[2:]):  # fmt: skip
        fw.sendto(bad, addr)
    # rotor off, full collective: no thrust, the vehicle stays on the ground
    count = 1
    for _ in range(RATE_HZ // 2):
        fw.sendto(_frame(count, collective_us=1750, rsc_us=RSC_OFF), addr)
        s = _state(fw.recvfrom(4096)[0])
        count += 1
    assert s["timestamp"] == pytest.approx((count) / RATE_HZ, abs=1e-5)  # one step per frame
    pos = s["position"]
    assert isinstance(pos, list) and abs(pos[2]) < 1e-6
    # rotor on, full collective: it climbs (NED z negative) until the process's 2 s end
    while proc.poll() is None:
        fw.sendto(_frame(count, collective_us=1750), addr)
        try:
            s = _state(fw.recvfrom(4096)[0])
        except TimeoutError:
            break
        count += 1
        if float(str(s["timestamp"])) >= 2.0:
            break
    pos = s["position"]
    assert isinstance(pos, list) and pos[2] < -0.5, pos
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0
    stats = json.loads(err.decode().strip().splitlines()[-1])
    link = stats["link"]
    print(stats)
    assert stats["frames"] == count and stats["resets"] == 0 and stats["interlock_changes"] == 1
    assert link["resends_answered"] >= 1
    assert link["refused"] == {"short": 2, "oversized": 1, "magic": 1, "frame_rate": 0}
    rows = (tmp_path / "plant.csv").read_text().splitlines()
    assert rows[0].startswith("t_s,x_m,y_m,z_m,u_m_s,v_m_s,w_m_s,phi_rad,theta_rad,psi_rad,p_rad_s,q_rad_s,"
                              "r_rad_s,theta_m_rad,theta_t_rad,eps_rad,eta_rad,interlock")
    assert len(rows) - 1 == pytest.approx(200, abs=2)  # 100 Hz over 2 s


def test_the_interlock_holds_the_blades_at_zero_pitch() -> None:
    """Channel 8 below the idle output: the swashplate's pitches are not applied (the paper
    rotor makes no thrust at zero pitch); engaged: they are, as the head reads them."""
    airframe, x0, _ = load_vehicle("paper", on_ground=True)
    swash = Swashplate.load("swashplate/xcell60-h3-120.toml")
    with ArduPilotJsonLink(new_port()) as link:
        be = ArduPilotBackend(lambda: Plant(airframe, x0, step_s=1.0 / RATE_HZ), swash, link)
        pwm = [1500] * 16
        pwm[7] = RSC_OFF
        assert not be.pitches_for(tuple(pwm)).any()
        pwm[7] = RSC_ON
        np.testing.assert_allclose(be.pitches_for(tuple(pwm)), swash.pitches_from_pwm(pwm[:4]).as_array())
        assert be.pitches_for(tuple(pwm))[0] == pytest.approx(0.10)  # mid collective: the hover trim
        assert be.stats.interlock_changes == 1
        # clipped at the head's stops: counted only with the rotor engaged (disarmed, the
        # firmware parks the collective at 1249 us, below the 1250 us stop)
        low = [1249] * 3 + [1500] * 13
        low[7] = RSC_OFF
        be.pitches_for(tuple(low))
        assert be.stats.saturated == 0
        low[7] = RSC_ON
        be.pitches_for(tuple(low))
        assert be.stats.saturated >= 1


def test_channel_8_runs_the_rotor_plant_up_and_winds_it_down() -> None:
    """Gavrilets' plant, started on the ground at rest: the interlock off keeps the rotor
    stopped; ArduPilot's ramp (H_RSC_MODE 2: 0 -> H_RSC_SETPOINT 66 % over H_RSC_RAMP_TIME 1 s)
    runs it up to the design speed, half the set point holds half of it, and the interlock
    off again stops the engine: the rotor winds down on its drag."""
    from heli_common.vehicle.plant_model import PlantModel

    airframe, x0, _ = load_vehicle("paper", on_ground=True)
    swash = Swashplate.load("swashplate/xcell60-h3-120.toml")
    model = PlantModel.load("gavrilets")
    dt = 1.0 / RATE_HZ
    with ArduPilotJsonLink(new_port()) as link:
        at_rest = lambda: Plant(airframe, x0, step_s=dt, model=model, rotor_at_rest=True)  # noqa: E731
        be = ArduPilotBackend(at_rest, swash, link)
        p = be.plant
        design = p.rotor_design_speed_rad_s
        assert design == pytest.approx(167.0) and p.rotor_speed_rad_s == 0.0

        def fly(seconds: float, rsc_us: float | None = None, ramp_to_us: float | None = None) -> None:
            n = round(seconds * RATE_HZ)
            for k in range(n):
                ramp = min(k / RATE_HZ, 1.0)
                us = rsc_us if ramp_to_us is None else RSC_OFF + (ramp_to_us - RSC_OFF) * ramp
                pwm = [1375] * 3 + [1500] * 13  # flat pitch: theta_m = 0.10 - 125 us x 0.0008 rad/us
                pwm[7] = round(us if us is not None else RSC_OFF)
                be.step(tuple(pwm), dt)

        fly(1.0, RSC_OFF)
        assert p.rotor_speed_rad_s == 0.0 and not p.u.any()
        fly(6.0, ramp_to_us=RSC_ON)  # the firmware's 1 s ramp, then 5 s at the set point
        assert p.rotor_speed_rad_s == pytest.approx(design, rel=2e-3)
        assert p.u[0] == pytest.approx(0.0, abs=1e-9)  # the blades follow the servos once engaged
        fly(5.0, (RSC_OFF + RSC_ON) / 2)  # half the set point: half the speed
        assert p.rotor_speed_rad_s == pytest.approx(design / 2, rel=2e-3)
        fly(5.0, RSC_OFF)  # engine off: 83.5 -> 47.5 rad/s on the blades' profile drag
        assert p.rotor_speed_rad_s == pytest.approx(47.5, rel=0.05)
        assert p.world is not None and p.world.rotor_truth[3] == 0.0  # no throttle
        # the paper's plant has no rotor speed: channel 8 gates the pitches only
        paper = Plant(airframe, x0, step_s=dt)
        assert not paper.set_rotor_speed_command(0.0) and paper.rotor_speed_rad_s == pytest.approx(167.0)
