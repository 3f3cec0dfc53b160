"""Every long-running process stops on SIGTERM whatever its main thread is doing."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# The signal lands while the main thread holds the stop event's lock, as it does inside
# stop.wait() between two sleeps of a real-time loop: the handler runs right there, in
# that thread. A handler that called stop.set() itself waited for that lock forever.
SCRIPT = textwrap.dedent("""
    import os, signal, sys, threading
    from heli_common.process import stop_on_signals
    stop = threading.Event()
    stop_on_signals(stop)
    with stop._cond:
        os.kill(os.getpid(), signal.SIG{name})
        x = sum(range(1000))  # bytecodes: the handler has run by here
    sys.exit(0 if stop.wait(5.0) else 1)
""")


@pytest.mark.parametrize("name", ["TERM", "INT"])
def test_a_signal_inside_the_stop_events_lock_still_stops(name: str) -> None:
    try:
        done = subprocess.run([sys.executable, "-c", SCRIPT.replace("{name}", name)], timeout=30,
                              capture_output=True, text=True)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail(f"SIG{name} while the stop event's lock was held: the process hung")
    assert done.returncode == 0, done.stderr
