"""The pacer (heli_plant.pacer): a ground station in the ArduPilot JSON lockstep. Real UDP on
loopback; the physics side is the Pacer, the client a plain socket."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from heli_common.ardupilot_json import encode_pace
from heli_common.mavlink.udp import LOOPBACK, free_udp_port
from heli_plant.pacer import Pacer


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
