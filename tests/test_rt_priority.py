"""``--rt-priority``: the real-time loops under SCHED_FIFO where the OS permits it, a clear
refusal where it does not, never in lockstep (heli_common.rt_priority)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from heli_common.rt_priority import current_policy, request_fifo
from heli_sitl.launch.demo import DemoOptions, run_demo

ROOT = Path(__file__).resolve().parent.parent
PROBE = ("from heli_common.rt_priority import request_fifo, current_policy; "
         "print(request_fifo(10)); print(current_policy())")
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
NO_PRIVILEGE = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--inh-caps=-all",
                "--bounding-set=-all"]  # nobody, without capabilities  # fmt: skip


LOOP_PROBE = ("import logging; from heli_common.rt_priority import rt_priority_loop, current_policy\n"
              "with rt_priority_loop(10, 'realtime', logging.getLogger()) as p:\n"
              "    print(p, '|', current_policy())\n"
              "print(current_policy())")


def _probe(prefix: list[str], code: str = PROBE) -> list[str]:
    """request_fifo(10) in a child (the test process keeps its own policy). Without the
    compiler: nobody may not write the compile cache, and nothing here is compiled."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_DISABLE_JIT": "1"}
    done = subprocess.run([*prefix, sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          cwd=ROOT, env=env)  # fmt: skip
    assert done.returncode == 0, done.stderr[-800:]
    return done.stdout.strip().splitlines()


def test_zero_leaves_the_policy_and_out_of_range_is_refused() -> None:
    before = current_policy()
    assert request_fifo(0) is None
    assert current_policy() == before
    for bad in (-1, 100):
        with pytest.raises(ValueError, match="0 \\(off\\) to 99"):
            request_fifo(bad)


@pytest.mark.skipif(not IS_ROOT, reason="SCHED_FIFO needs root here (CAP_SYS_NICE a test cannot tell)")
def test_a_permitted_request_runs_the_thread_under_fifo() -> None:
    assert _probe([]) == ["None", "fifo 10"]


@pytest.mark.skipif(not IS_ROOT, reason="SCHED_FIFO needs root here")
def test_the_loop_alone_runs_under_fifo_and_what_follows_it_does_not() -> None:
    """A flight's record is written after its loop: under SCHED_FIFO it would hold a core from
    every other real-time loop at the priority (two at once: both cores of a small machine)."""
    assert _probe([], LOOP_PROBE) == ["fifo 10 | fifo 10", "other"]
    # a thread already under FIFO (`chrt -f 5 heli-sitl ...`) gets its own policy back
    assert _probe([], "from heli_common.rt_priority import request_fifo; request_fifo(5)\n" + LOOP_PROBE) == [
        "fifo 10 | fifo 10", "fifo 5"]


@pytest.mark.skipif(not (IS_ROOT and shutil.which("setpriv")), reason="needs root and setpriv to drop rights")
def test_a_refused_request_says_why_and_changes_nothing() -> None:
    out = _probe(NO_PRIVILEGE)  # the kernel refuses: no capability, RLIMIT_RTPRIO 0
    assert out[0].startswith("not permitted"), out
    assert out[1] == "other"


def test_lockstep_refuses_the_option_before_anything_starts() -> None:
    cmd = [sys.executable, "-m", "autopilot.cli", "--mode", "lockstep", "--rt-priority", "10"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 2
    assert "--rt-priority is for --mode realtime" in done.stderr


@pytest.mark.skipif(not IS_ROOT, reason="SCHED_FIFO needs root here")
def test_a_real_time_flight_runs_its_loops_under_fifo(tmp_path: Path) -> None:
    """Both processes of a real-time flight with ``rt_priority``: the autopilot's summary
    names the policy its loop ran under, the flight is whole."""
    opts = DemoOptions(mode="realtime", rate_hz=100.0, out=tmp_path, timeout_s=120, via_ground=False,
                       duration_s=3.0, rt_priority=10)
    summary = run_demo(opts)
    assert summary["scheduling"] == "fifo 10"
    loop = summary["loop"]
    assert isinstance(loop, dict)
    assert loop["ticks"] >= 250  # 3 s at 100 Hz, from the plant's first state
    assert loop["bad_outputs"] == 0
    assert json.loads((tmp_path / "summary.json").read_text())["scheduling"] == "fifo 10"
