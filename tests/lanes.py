"""Two lanes of pytest-xdist workers: real-time flights beside CPU-bound tests, not behind them.

A third of the suite's worker time is a flight on the wall clock (`--mode realtime`, a ground
station on a live vehicle, ArduPilot's paced SITL), mostly asleep: with a worker per core the
cores sat idle 25 % of the time (2 cores: 150 % CPU, 618 s). One more worker filled them (177 %,
560 s) but then put two CPU-bound files beside a real-time flight, which starved it: a vehicle
resumed after a 2 s stall 5.2 m off its track (limit 1 m, 0.4 m measured alone). So the workers
come in two lanes, a pair per core at most four: the real-time lane runs the files that fly on
the wall clock (then any other), at normal priority; the CPU lane runs only the others, niced,
so that the scheduler hands a core to a real-time process the moment it wakes. Nothing here
changes what a test checks; it only decides where and at what priority a file runs.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from xdist.remote import Producer
from xdist.scheduler import LoadFileScheduling
from xdist.workermanage import WorkerController

# the files that start processes on the host's loopback (marked `processes` by conftest)
PROCESS_MODULES = frozenset({
    "test_cli_and_records", "test_gcs_requests", "test_ground_client",
    "test_interop_mavproxy", "test_interop_mavsdk", "test_mavlogdump", "test_port_handoff",
    "test_process_faults", "test_processes", "test_user_controller_realtime", "test_world_processes",
    "test_view",
})  # fmt: skip
# the files that fly on the wall clock or wait on live processes (each file is one unit)
REALTIME_MODULES = PROCESS_MODULES | {
    "test_ardupilot_sitl", "test_ardupilot_compare", "test_ardupilot_backend", "test_ardupilot_json",
    "test_rt_priority", "test_runner_clock", "test_can_servo", "test_gcs_adversary", "test_pid",
    "test_ardupilot_can", "test_plant_server",
}  # fmt: skip
CPU_LANE_NICE = 10  # CFS weight 110 against 1024: a waking real-time process preempts at once


def workers(cores: int) -> int:
    """`-n auto`: a real-time and a CPU worker per core (`--maxprocesses` caps it)."""
    return 2 * max(cores, 1)


def is_realtime_lane(worker_id: str, n_workers: int) -> bool:
    """The first half of the workers (gw0, gw1, ... of ``n_workers``) are the real-time lane;
    a single worker is both lanes."""
    index = int(worker_id.removeprefix("gw"))
    return n_workers < 2 or index < (n_workers + 1) // 2


def enter_lane(worker_id: str | None, n_workers: int) -> None:
    """In a worker process: a CPU-lane worker lowers its priority (its children inherit it).
    Raising one's niceness needs no privilege."""
    if worker_id is not None and not is_realtime_lane(worker_id, n_workers):
        os.nice(CPU_LANE_NICE)


def _realtime(scope: str) -> bool:
    return Path(scope.split("::", 1)[0]).stem in REALTIME_MODULES


class LaneScheduling(LoadFileScheduling):
    """`--dist loadfile` (a file is a unit, most tests first) with the two lanes above: a
    real-time worker takes a real-time file first, else any; a CPU worker only the others, and
    stops when none is left."""

    def __init__(self, config: pytest.Config, log: Producer | None = None) -> None:
        super().__init__(config, log)
        self.n_workers = len(config.option.tx)  # fixed: self.nodes shrinks as workers finish

    def _lane_is_realtime(self, node: WorkerController) -> bool:
        return is_realtime_lane(node.gateway.id, self.n_workers)

    def _next_scope(self, node: WorkerController) -> str | None:
        rt = self._lane_is_realtime(node)
        if rt:
            for scope in self.workqueue:
                if _realtime(scope):
                    return str(scope)
        for scope in self.workqueue:
            if not _realtime(scope):
                return str(scope)
        return None

    def _assign_work_unit(self, node: WorkerController) -> None:
        scope = self._next_scope(node)
        if scope is None:
            return
        work_unit = self.workqueue.pop(scope)
        self.assigned_work.setdefault(node, {})[scope] = work_unit
        collection = self.registered_collections[node]
        node.send_runtest_some([collection.index(nodeid) for nodeid, done in work_unit.items() if not done])

    def _reschedule(self, node: WorkerController) -> None:
        if node.shutting_down:
            return
        if self._next_scope(node) is None:
            node.shutdown()  # it finishes what it holds first
            return
        if self._pending_of(self.assigned_work.get(node, {})) > 2:
            return
        self._assign_work_unit(node)
