"""A ground station in the ArduPilot JSON lockstep: the pacer (heli_plant.pacer; real UDP on
loopback, the physics side is the Pacer, the client a plain socket), and the guided flight's
record read by the comparison's scorecard (heli_sitl.guided_record)."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from autopilot.scenario import Scenario
from heli_common.ardupilot_json import encode_pace
from heli_common.mavlink.udp import LOOPBACK, free_udp_port
from heli_plant.pacer import Pacer
from heli_sitl.guided_record import guided_record
from heli_sitl.scorecard import score


@pytest.fixture
def pacer() -> Iterator[tuple[Pacer, socket.socket]]:
    port = free_udp_port()
    with Pacer(port, release_after_s=0.4) as p, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c:
        c.connect((LOOPBACK, port))
        yield p, c


def test_without_a_client_nothing_waits(pacer: tuple[Pacer, socket.socket]) -> None:
    p, _ = pacer
    t0 = time.monotonic()
    p.wait_until(1e6)
    assert time.monotonic() - t0 < 0.05 and p.counts.waits == 0


def test_the_physics_waits_for_the_client_then_runs_free_when_released(
    pacer: tuple[Pacer, socket.socket],
) -> None:
    p, c = pacer
    c.send(encode_pace(1.0))
    p.wait_until(0.9)  # ahead of the client: no wait
    assert p.counts.waits == 0
    threading.Timer(0.2, lambda: c.send(encode_pace(2.0))).start()
    t0 = time.monotonic()
    p.wait_until(1.5)  # until the client is ready for 1.5 s
    waited = time.monotonic() - t0
    assert 0.15 < waited < 0.35 and p.counts.waits == 1
    c.send(encode_pace(math.inf))  # released
    t0 = time.monotonic()
    p.wait_until(100.0)
    assert time.monotonic() - t0 < 0.05 and p.counts.releases == 1


def test_a_silent_client_releases_the_physics_and_bad_datagrams_are_counted(
    pacer: tuple[Pacer, socket.socket],
) -> None:
    p, c = pacer
    c.send(b"not eight")  # wrong size: counted, ignored
    c.send(encode_pace(1.0))
    t0 = time.monotonic()
    p.wait_until(5.0)  # the client never answers: free after release_after_s
    waited = time.monotonic() - t0
    assert 0.3 < waited < 0.6
    assert p.counts.refused == 1 and p.counts.releases == 1 and p.until_s is None


def test_a_guided_flight_reads_into_the_scorecard(tmp_path: Path) -> None:
    """heli_sitl.guided_record: plant.csv (truth, NWU, the firmware's clock) and track.csv
    (the targets streamed, NED) into a FlightRecord; a vehicle 0.2 m north of a target that
    moves east at 1 m/s scores a steady RMS of 0.2 m and a 1 m/s reference."""
    t = np.arange(0.0, 30.0, 0.01)
    t0 = 50.0  # the vehicle's clock at trajectory time 0
    with (tmp_path / "plant.csv").open("w") as f:
        f.write("t,x,y,z,u,v,w,phi,theta,psi,p,q,r,theta_m,theta_t,eps,eta,interlock\n")
        for k in t:  # east is -y in NWU; 5 m up
            f.write(f"{t0 + k:.6f},0.2,{-k},5,0,0,0,0,0,0,0,0,0,0.1,0,0,0,1\n")
    with (tmp_path / "track.csv").open("w") as f:
        f.write("t_vehicle_s,t_traj_s,target_n_m,target_e_m,target_d_m,est_n_m,est_e_m,est_d_m\n")
        for k in t[::4]:
            f.write(f"{t0 + k:.3f},{k:.3f},0,{k},-5,0,{k},-5\n")
    rec = guided_record(tmp_path / "plant.csv", tmp_path / "track.csv", 30.0)
    card = score(rec, Scenario.load("paper"))
    assert card.steady_rms_m == pytest.approx(0.2, abs=1e-5) and card.lost == 0.0
    assert np.allclose(rec.ref[5:-5, 4], -1.0)  # NWU velocity: east
