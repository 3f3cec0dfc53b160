"""Real-time scheduling for the real-time loops, where the operating system permits it.

A real-time process sleeps to each deadline (2.5 ms apart at 400 Hz). Under the default
time-sharing policy a wake-up waits for whatever else holds the core, another process's
computation or a campaign's flights, and a wait of two periods is a skipped tick. Under
``SCHED_FIFO`` the woken loop takes the core at once, as PX4's Linux work queues do. The
kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default)
keeps a runaway loop from freezing the machine.

Linux only, and only as root or with ``CAP_SYS_NICE`` (``setcap cap_sys_nice+ep`` on the
interpreter, or ``ulimit -r``): anywhere else the request is refused with the reason, and
the loop runs as before. Never in lockstep: its waits spin.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
from collections.abc import Iterator

from heli_common.cli_args import in_range
from heli_common.process import UsageError

#: the priority the command lines mean by ``--rt-priority`` without a value: above the
#: kernel's threaded interrupts' 50 would starve the network stack the loops talk over
DEFAULT_PRIORITY = 10


def request_fifo(priority: int) -> str | None:
    """Put the calling thread (and the threads it starts later) under ``SCHED_FIFO`` at
    ``priority`` (1-99; 0: leave the policy alone). None when done (or 0), else why not.
    ValueError: a priority outside 0-99."""
    if not 0 <= priority <= 99:
        raise ValueError(f"real-time priority must be 0 (off) to 99, got {priority}")
    if priority == 0:
        return None
    if not hasattr(os, "sched_setscheduler"):
        return "SCHED_FIFO is not available on this operating system"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return "not permitted: run as root or give the interpreter CAP_SYS_NICE"
    except OSError as exc:
        return f"refused by the kernel ({exc.strerror})"
    return None


def current_policy() -> str:
    """The calling thread's scheduling policy and priority, for the logs ("fifo 10", "other")."""
    if not hasattr(os, "sched_getscheduler"):
        return "unknown"
    policy = os.sched_getscheduler(0)
    if policy == os.SCHED_FIFO:
        return f"fifo {os.sched_getparam(0).sched_priority}"
    if policy == os.SCHED_RR:
        return f"rr {os.sched_getparam(0).sched_priority}"
    return "other"


def add_rt_priority_arg(p: argparse._ActionsContainer) -> None:
    """``--rt-priority [N]``: SCHED_FIFO at N (default 10 when given bare) in real time."""
    p.add_argument("--rt-priority", type=in_range(0, 99, int), nargs="?", const=DEFAULT_PRIORITY, default=0,
                   metavar="N", help="real time: the loop under SCHED_FIFO at priority N (1-99, bare: "
                   f"{DEFAULT_PRIORITY}; Linux, root or CAP_SYS_NICE; else a warning, the default policy)")


def check_rt_priority(priority: int, mode: str) -> None:
    """UsageError for ``--rt-priority`` in lockstep, whose waits spin and would hold the core:
    said at once, before anything starts."""
    if priority != 0 and mode != "realtime":
        raise UsageError(f"--rt-priority is for --mode realtime (lockstep's waits spin), got --mode {mode}")


@contextlib.contextmanager
def rt_priority_loop(priority: int, mode: str, log: logging.Logger) -> Iterator[str]:
    """The process's ``--rt-priority`` for the loop inside the ``with`` only (then the policy
    the thread had again); yields the policy the loop runs under ("fifo 10", "other"). A
    refusal is a warning (the loop runs as before); UsageError in lockstep. Enter it from the
    loop's thread just before the loop: the start-up (imports, loading compiled code,
    building the controller) runs under the default policy,
    and so does what follows the loop: writing a flight's record is seconds of computation,
    and under SCHED_FIFO it would hold a core from every other real-time loop at the same
    priority on the machine (a FIFO task is never preempted by its equals; two records written
    at once hold both cores of a small machine)."""
    if priority == 0:
        yield current_policy()
        return
    check_rt_priority(priority, mode)
    before = (os.sched_getscheduler(0), os.sched_getparam(0)) if hasattr(os, "sched_getscheduler") else None
    reason = request_fifo(priority)
    if reason is None:
        log.info("scheduling: SCHED_FIFO at priority %d", priority)
    else:
        log.warning("--rt-priority %d: %s; running under the default policy", priority, reason)
    try:
        yield current_policy()
    finally:
        if before is not None and reason is None:  # the policy it had (lowering needs no privilege)
            os.sched_setscheduler(0, *before)
