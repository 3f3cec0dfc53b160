"""Ports without races: a launcher binds its children's ports and hands the sockets down
(heli_common.port_handoff); `heli-sitl up` started many times, one at a time and four at
once, never collides."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

from ports import new_port
from vehicle import free_ports, spawn_up

from heli_common import port_handoff
from heli_common.port_handoff import ENV, HeldPorts
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp, bind_udp

CHILD = """
import os, socket, sys
from heli_common.wire.mavlink.udp import bind_udp
port = int(sys.argv[1])
s = bind_udp(("127.0.0.1", port))
s.setblocking(True)
s.settimeout(10)
print(s.recv(64).decode(), flush=True)
"""


def test_a_child_adopts_the_socket_its_launcher_bound_and_hears_what_came_before_it() -> None:
    """The port is never free between the launcher's bind and the child's: a datagram sent
    before the child started waits in the socket's queue and is the child's first."""
    with HeldPorts() as held:
        port = held.new()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"sent before the child", (LOOPBACK, port))
        child = subprocess.run([sys.executable, "-c", CHILD, str(port)], env=held.env((port,)),
                               pass_fds=held.fds((port,)), capture_output=True, text=True,
                               timeout=60)  # fmt: skip
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == "sent before the child"


def test_held_ports_are_distinct_and_bound_until_closed() -> None:
    with HeldPorts() as held:
        ports = [held.new() for _ in range(500)]
        assert len(set(ports)) == len(ports)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((LOOPBACK, ports[0]))
                raise AssertionError("a held port could be bound by another socket")
            except OSError:
                pass
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((LOOPBACK, ports[0]))  # free again once the launcher let go


def test_a_stale_or_malformed_variable_never_makes_a_process_listen_elsewhere(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """An entry whose descriptor is not a UDP socket bound to the address asked for is
    ignored: the process binds the port itself, as without the variable."""
    port = new_port()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
        other.bind((LOOPBACK, 0))  # a real socket, on another port
        r, w = os.pipe()
        try:
            monkeypatch.setenv(ENV, f"{LOOPBACK}:{port}={other.fileno()},{LOOPBACK}:{port}={r},junk,:=,x:y=z")
            s = bind_udp((LOOPBACK, port))
            try:
                assert s.getsockname() == (LOOPBACK, port) and s.fileno() != other.fileno()
            finally:
                s.close()
            assert other.getsockname()[1] != port  # untouched, still open
            os.fstat(r)  # the pipe was not closed by the refusal
        finally:
            os.close(r)
            os.close(w)


def test_each_inherited_socket_is_adopted_once(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A second bind of the same address in one process is an ordinary bind (busy), not a
    second wrapper around the same descriptor."""
    with HeldPorts() as held:
        port = held.new()
        fd = os.dup(held.fds((port,))[0])
        monkeypatch.setenv(ENV, f"{LOOPBACK}:{port}={fd}")
        monkeypatch.setattr(port_handoff, "_adopted", set())
        first = MavlinkUdp((LOOPBACK, port))
        try:
            assert first.sock.fileno() == fd
            assert port_handoff.adopt((LOOPBACK, port)) is None
        finally:
            first.close()


# a fork copies every descriptor the process holds until the child's exec closes it: a
# probe socket of tests/ports.py open in one thread while another forks stays bound in that
# child for a moment, and the first thread's bind of the port fails. One thread at a time
# deals its ports, binds its listener and starts its `up`.
_STARTING = threading.Lock()


def _start_up_once(timeout_s: float = 90.0) -> str:
    """`heli-sitl up` until its first heartbeat reaches our ground-station port, then
    stopped: '' or what went wrong (its exit status and last line)."""
    with _STARTING:
        ports = free_ports()
        gcs = MavlinkUdp((LOOPBACK, ports.gcs), None)
        up = spawn_up(ports)
    with gcs:
        try:
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                if up.poll() is not None:
                    return f"up exited ({up.returncode}): {up.last_error_line()}"
                for m, _ in gcs.recv(0.2):
                    if m.get_type() == "HEARTBEAT":
                        return ""
            return "no heartbeat"
        finally:
            up.send_signal(signal.SIGTERM)
            up.stop(grace_s=20.0, resend=False)


def test_up_starts_one_at_a_time_and_four_at_once_without_a_port_collision() -> None:
    """Bounded: 2 starts in a row, then 4 at once (the soak `python -m benchmarks.up_starts`
    runs 200 of each; each start costs ~7 s of CPU); every one hears its vehicle, none
    exits with a busy port or equal sim-link ports."""
    failures = [f for f in (_start_up_once() for _ in range(2)) if f]
    with ThreadPoolExecutor(4) as pool:
        failures += [f for f in pool.map(lambda _: _start_up_once(), range(4)) if f]
    assert not failures, failures
