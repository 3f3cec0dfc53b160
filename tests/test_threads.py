"""Every process of ours runs BLAS on one thread (heli_common/threads.py): OpenBLAS's
spinning pool thread would take the core the partner process (plant, autopilot, the other
campaign worker, the other test worker) needs."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

PROBE = """
import {module}
import os
import numpy as np, scipy.linalg
a = np.random.default_rng(0).standard_normal((200, 200))
scipy.linalg.solve(a @ a.T + np.eye(200), a)  # both libraries' BLAS loaded and used
from heli_common.threads import blas_threads_limited
print(len(os.listdir("/proc/self/task")), blas_threads_limited(), os.environ["OPENBLAS_NUM_THREADS"])
"""


def _probe(module: str, **env: str) -> list[str]:
    base = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", PROBE.format(module=module)], env={**base, **env},
                         capture_output=True, text=True, timeout=120, check=True)  # fmt: skip
    return out.stdout.split()


@pytest.mark.parametrize("module", ["autopilot.cli", "heli_sitl.cli", "heli_plant.server", "ground.cli",
                                    "heli_sitl", "benchmarks"])  # fmt: skip
def test_each_entry_point_leaves_one_thread(module: str) -> None:
    assert _probe(module) == ["1", "True", "1"]


def test_numpy_alone_starts_a_pool_and_a_users_value_wins() -> None:
    """The control: without us first, OpenBLAS starts its pool (on a machine of 2 or more
    cores); and a value the user set is kept."""
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenBLAS starts no pool thread to compare with")
    count = "import numpy, os; print(len(os.listdir('/proc/self/task')))"
    out = subprocess.run([sys.executable, "-c", count],
                         env={k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")},
                         capture_output=True, text=True, timeout=60, check=True)  # fmt: skip
    assert int(out.stdout) >= 2
    assert _probe("autopilot.cli", OPENBLAS_NUM_THREADS="2")[2] == "2"
