"""Ports for the tests' own listeners and the processes they start, without a probe race.

A probe (bind port 0, read it, close it) hands out a port the kernel may give to the next
probe, or to any process, before the test's process binds it: two probes once returned the
same port and the plant refused `--port` equal to `--autopilot-port`. Here each test process
(a pytest-xdist worker, or a plain pytest) claims a block of ports below the kernel's
ephemeral range (`ip_local_port_range` starts at 32768, so the kernel hands these to nobody)
with an exclusive lock on a file named after the block, held until the process exits, and
deals its ports out in turn: no two tests, workers, suites or launches share one. The
launchers themselves bind their children's ports and hand the sockets down
(heli_common.port_handoff).
"""

from __future__ import annotations

import fcntl
import itertools
import os
import socket
import tempfile
import threading
from pathlib import Path

BASE = 20000  # to 31999: below the ephemeral range, above every default port of the bench
BLOCK = 500  # ports per process (a test takes at most a few dozen; they wrap around)
N_BLOCKS = 24
LOOPBACK = "127.0.0.1"
LOCKS = Path(tempfile.gettempdir()) / "heli-tlc-sitl-test-ports"

_lock = threading.Lock()
_claim: tuple[int, int] | None = None  # (block, the lock file's descriptor, kept open)
_next = itertools.count()


def _block() -> int:
    """This process's block, claimed on first use (the lock dies with the process)."""
    global _claim
    if _claim is None:
        LOCKS.mkdir(exist_ok=True)
        for block in range(N_BLOCKS):
            fd = os.open(LOCKS / f"{block}.lock", os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            _claim = (block, fd)
            break
        else:
            raise RuntimeError(f"all {N_BLOCKS} test port blocks are claimed (locks in {LOCKS})")
    return _claim[0]


def new_port() -> int:
    """A UDP (and TCP) port of this process's block, free now: the next one not bound by a
    process left over from an earlier run (such a port is skipped, never waited for)."""
    with _lock:  # threads of one test share the block
        first = BASE + BLOCK * _block()
        for _ in range(BLOCK):
            port = first + next(_next) % BLOCK
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u, socket.socket() as t:
                try:
                    u.bind((LOOPBACK, port))
                    t.bind((LOOPBACK, port))
                except OSError:
                    continue
            return port
    raise RuntimeError(f"no free port in {first}-{first + BLOCK - 1}")
