"""A soak of `heli-sitl up` starts, as a user makes them: N in a row on the default ports, then
N more as N/4 rounds of four vehicles at once (`--instance 0..3`). Each start counts once its first
heartbeat reaches the instance's ground-station port (14550 + 10 i); it is then stopped.
Any start that exits (a busy port, equal sim-link ports) or stays silent is printed. Not part
of ``make bench`` (a few minutes; bounded by N and a per-start limit). The ports it listens
on must be free: run it with no other vehicle up.

``python -m benchmarks.up_starts [N]`` (default 200)
"""

from __future__ import annotations

import signal
import sys
import time
from concurrent.futures import ThreadPoolExecutor

from heli_common.defaults import ports
from heli_common.wire.mavlink.udp import LOOPBACK, MavlinkUdp
from heli_sitl.launch.children import spawn

LIMIT_S = 90.0  # one start's bound: the first start may load the compiled code


def start(instance: int) -> str:
    """'' once `up --instance N` is heard, or what went wrong."""
    with MavlinkUdp((LOOPBACK, ports(instance).gcs), None) as gcs:
        up = spawn([sys.executable, "-m", "heli_sitl.cli", "up", "--instance", str(instance)])
        try:
            deadline = time.monotonic() + LIMIT_S
            while time.monotonic() < deadline:
                if up.poll() is not None:
                    return f"instance {instance}: up exited ({up.returncode}): {up.last_error_line()}"
                if any(m.get_type() == "HEARTBEAT" for m, _ in gcs.recv(0.2)):
                    return ""
            return f"instance {instance}: no heartbeat in {LIMIT_S:.0f} s"
        finally:
            up.send_signal(signal.SIGTERM)
            up.stop(grace_s=20.0, resend=False)


def main(argv: list[str]) -> int:
    n = int(argv[0]) if argv else 200
    t0 = time.monotonic()
    alone = [f for f in (start(0) for _ in range(n)) if f]
    print(f"{n} starts in a row: {n - len(alone)} heard, {len(alone)} failed ({time.monotonic() - t0:.0f} s)")
    t1 = time.monotonic()
    together: list[str] = []
    with ThreadPoolExecutor(4) as pool:
        for _ in range(n // 4):
            together += [f for f in pool.map(start, range(4)) if f]
    print(f"{n // 4} rounds of 4 at once: {4 * (n // 4) - len(together)} heard, {len(together)} failed "
          f"({time.monotonic() - t1:.0f} s)")  # fmt: skip
    for f in alone + together:
        print("  " + f)
    return 1 if alone or together else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
