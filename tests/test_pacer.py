"""A ground station in the ArduPilot JSON lockstep: the pacer (heli_plant.pacer; real UDP on
loopback, the physics side is the Pacer on a fake clock, the client a plain socket), and the guided flight's
record read by the comparison's scorecard (heli_sitl.engine.guided_record)."""

from __future__ import annotations

import math
import socket
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from autopilot.scenario import Scenario
from heli_common.state import PITCH_LABELS, STATE_NAMES
from heli_common.wire.ardupilot_json import encode_pace
from heli_common.wire.mavlink.udp import LOOPBACK
from heli_plant.pacer import Pacer
from heli_sitl.engine.guided_record import guided_record
from heli_sitl.studies.scorecard import score


class FakeClock:
    """The pacer's clock: each read moves it ``step_s`` on; ``on_read(t)``, if set, runs at
    each read with the new time (a client that answers while the physics waits)."""

    def __init__(self, step_s: float) -> None:
        self.now = 0.0
        self.step_s = step_s
        self.reads = 0
        self.on_read: Callable[[float], None] | None = None

    def monotonic(self) -> float:
        self.now += self.step_s
        self.reads += 1
        if self.on_read is not None:
            self.on_read(self.now)
        return self.now

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        raise AssertionError("the pacer waits on its socket, never sleeps")


RELEASE_S = 0.04  # a silent client is given up after this much of the fake clock's time
STEP_S = 0.005


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock(STEP_S)


@pytest.fixture
def pacer(clock: FakeClock) -> Iterator[tuple[Pacer, socket.socket]]:
    # port 0: the system picks a free one, bound here (no probe socket closed and re-bound)
    with (
        Pacer(0, release_after_s=RELEASE_S, clock=clock) as p,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c,
    ):
        c.connect((LOOPBACK, p.sock.getsockname()[1]))
        yield p, c


def test_without_a_client_nothing_waits(pacer: tuple[Pacer, socket.socket], clock: FakeClock) -> None:
    p, _ = pacer
    p.wait_until(1e6)
    assert p.counts.waits == 0 and p.counts.wait_s == 0.0 and p.until_s is None
    assert clock.reads == 0  # not even a look at the time


def test_the_physics_waits_for_the_client_then_runs_free_when_released(
    pacer: tuple[Pacer, socket.socket], clock: FakeClock
) -> None:
    p, c = pacer
    c.send(encode_pace(1.0))
    p.wait_until(0.9)  # behind the client: no wait
    assert p.counts.waits == 0 and p.until_s == 1.0
    sent: list[float] = []

    def answer(t: float) -> None:  # the client answers once the physics is waiting for it
        if not sent and p.counts.waits == 1:
            sent.append(t)
            c.send(encode_pace(2.0))

    clock.on_read = answer
    p.wait_until(1.5)  # until the client is ready for 1.5 s
    clock.on_read = None
    assert sent and p.until_s == 2.0  # it returned on the client's answer
    assert p.counts.waits == 1 and p.counts.releases == 0
    assert 0.0 < p.counts.wait_s < RELEASE_S  # answered in time: not given up
    p.wait_until(1.9)  # the client is ahead: no wait
    assert p.counts.waits == 1
    c.send(encode_pace(math.inf))  # released
    p.wait_until(100.0)
    assert p.counts.releases == 1 and p.until_s is None and p.counts.waits == 1


def test_a_silent_client_releases_the_physics_and_bad_datagrams_are_counted(
    pacer: tuple[Pacer, socket.socket], clock: FakeClock
) -> None:
    p, c = pacer
    c.send(b"not eight")  # wrong size: counted, ignored
    c.send(encode_pace(1.0))
    p.wait_until(5.0)  # the client never answers: free after release_after_s of its clock
    assert p.counts.datagrams == 2 and p.counts.refused == 1
    assert p.counts.waits == 1 and p.counts.releases == 1 and p.until_s is None
    # given up once RELEASE_S had passed since the client was last heard (within a read)
    assert RELEASE_S - 2 * STEP_S <= p.counts.wait_s <= RELEASE_S + 2 * STEP_S, p.counts.wait_s
    p.wait_until(10.0)  # released: runs free
    assert p.counts.waits == 1


def test_a_guided_flight_reads_into_the_scorecard(tmp_path: Path) -> None:
    """heli_sitl.engine.guided_record: plant.csv (truth, NWU, the firmware's clock) and track.csv
    (the targets streamed, NED) into a FlightRecord; a vehicle 0.2 m north of a target that
    moves east at 1 m/s scores a steady RMS of 0.2 m and a 1 m/s reference."""
    t = np.arange(0.0, 30.0, 0.01)
    t0 = 50.0  # the vehicle's clock at trajectory time 0
    with (tmp_path / "plant.csv").open("w") as f:
        f.write(",".join(("t_s", *STATE_NAMES, *PITCH_LABELS, "interlock")) + "\n")  # the backend's header
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
