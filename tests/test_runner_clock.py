"""The real-time loop's scheduling on a fake clock: on time, overruns, skipped ticks, stall
recovery and a silent plant, each with exact counts (no real sleeping, no sockets)."""

from __future__ import annotations

import gc
import threading
from dataclasses import dataclass, field

import numpy as np
import pytest

from autopilot.flight.commands import Arm
from autopilot.flight.manager import FlightConfig, FlightManager
from autopilot.runner import RESUME_GAP_S, LoopStats, Runner, RunnerConfig
from autopilot.scenario import Scenario
from autopilot.tick_timer import CONTROL, TickTimer
from autopilot.tlc.controller import TLController
from heli_common.geo import GeoPoint
from heli_common.state import FloatArray
from heli_common.wire.mavlink.sim_protocol import StateSample

# a period that binary floating point holds exactly (1/128 s), from a start that it also
# holds: every deadline, sleep and lateness is then exact, so counts and zeros are exact too
RATE_HZ = 128.0
P = 1.0 / RATE_HZ
T0 = 1000.0
RUNAWAY_S = 60.0  # fake seconds: a loop that never stops fails instead of hanging


class FakeClock:
    """Time moves only when the loop sleeps or a test makes it jump (a stall, slow work)."""

    def __init__(self, stalls: dict[int, float] | None = None) -> None:
        self.now = T0
        # sleep number (1-based) -> seconds the process stays stopped after that sleep;
        # on schedule, sleep n is the wait before tick n (tick 0 needs none)
        self.stalls = stalls or {}
        self.sleeps = 0

    def monotonic(self) -> float:
        return self.now

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps += 1
        self.advance(seconds + self.stalls.get(self.sleeps, 0.0))

    def advance(self, seconds: float) -> None:
        assert seconds >= 0.0
        self.now += seconds
        assert self.now - T0 < RUNAWAY_S, "the loop did not stop"


class FakePlant:
    """A plant flying in real time on the fake clock: each read returns its state stamped
    with the clock's time, except while it is silent (``silent``: [from, to) fake seconds
    after T0), when a read gets nothing after waiting its timeout."""

    def __init__(self, clock: FakeClock, silent: tuple[float, float] | None = None) -> None:
        self.clock = clock
        self.silent = silent

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        t = self.clock.now - T0
        if self.silent is not None and self.silent[0] <= t < self.silent[1]:
            self.clock.advance(timeout_s)
            return None
        return StateSample(round(t * 1e6), np.zeros(12))


@dataclass
class Sent:
    t_us: int
    at_s: float  # fake seconds after T0


@dataclass
class FakeServos:
    """Records each command; stops the loop after ``n_stop`` of them, and makes the clock
    jump by ``work_s[n]`` while sending command n (0-based): that tick's work was slow."""

    clock: FakeClock
    stop: threading.Event
    n_stop: int
    work_s: dict[int, float] = field(default_factory=dict)
    sent: list[Sent] = field(default_factory=list)

    def send_pitches(self, t_us: int, pitches_rad: FloatArray, armed: bool) -> None:
        self.sent.append(Sent(t_us, self.clock.now - T0))
        self.clock.advance(self.work_s.get(len(self.sent) - 1, 0.0))
        if len(self.sent) >= self.n_stop:
            self.stop.set()


class TickTimes:
    """A tick service that keeps the time of each tick flown."""

    def __init__(self) -> None:
        self.t_s: list[float] = []

    def at_tick_start(self, t_s: float, x: FloatArray) -> None:
        self.t_s.append(t_s)

    def after_tick(self, t_s: float, x: FloatArray, ref: FloatArray | None, u: FloatArray,
                   att_cmd_rad: tuple[float, float, float]) -> None:  # fmt: skip
        pass

    def between_ticks(self, t_s: float, x: FloatArray) -> None:
        pass

    def warm_up(self, x: FloatArray) -> None:
        pass


@pytest.fixture(scope="module")
def paper() -> Scenario:
    return Scenario.load("paper")


@dataclass
class Bench:
    runner: Runner
    clock: FakeClock
    servos: FakeServos
    ticks: TickTimes
    stop: threading.Event

    def run(self) -> LoopStats:
        stats = self.runner.run(self.stop)
        assert stats.ticks == len(self.ticks.t_s)
        return stats


def _bench(
    paper: Scenario, n_stop: int, *, work_s: dict[int, float] | None = None,
    stalls: dict[int, float] | None = None, silent: tuple[float, float] | None = None,
    stale_timeout_s: float = 0.5, armed: bool = False,
) -> Bench:  # fmt: skip
    clock = FakeClock(stalls)
    stop = threading.Event()
    servos = FakeServos(clock, stop, n_stop, work_s or {})
    ticks = TickTimes()
    manager = FlightManager(FlightConfig(home=GeoPoint(47.4, 8.5, 488.0)))
    if armed:  # on the ground with nothing to fly: it holds, the control law runs each tick
        assert manager.execute(Arm(), 0.0, np.zeros(12)).accepted
    cfg = RunnerConfig(
        mode="realtime", rate_hz=RATE_HZ, stale_timeout_s=stale_timeout_s, skip_after_periods=2
    )
    ctrl = TLController(paper.airframe, paper.gains, RATE_HZ)
    runner = Runner(ctrl, manager, FakePlant(clock, silent), servos, cfg, [ticks], clock=clock)
    return Bench(runner, clock, servos, ticks, stop)


def _grid(ks: range | list[int]) -> list[float]:
    return [k * P for k in ks]


def test_on_time_ticks_every_period_and_is_never_late(paper: Scenario) -> None:
    n = 50
    b = _bench(paper, n)
    stats = b.run()
    assert stats.ticks == n and len(b.servos.sent) == n
    assert stats.overruns == 0 and stats.skipped_ticks == 0 and stats.stale_ticks == 0
    assert stats.lateness_s == [0.0] * n
    assert stats.work_s == [0.0] * n
    assert b.ticks.t_s == _grid(range(n))
    assert [s.at_s for s in b.servos.sent] == _grid(range(n))
    assert b.clock.sleeps == n - 1  # tick 0 starts at once
    assert stats.resumes == 0 and stats.plant_stale_events == 0


@pytest.mark.parametrize(("work_periods", "overruns", "stale"), [(1.5, 0, 0), (2.5, 1, 1)])
def test_slow_tick_makes_the_next_late_then_the_schedule_holds(
    paper: Scenario, work_periods: float, overruns: int, stale: int
) -> None:
    """Tick 4's work takes ``work_periods``: the ticks after it start at once, each a period
    less late (an overrun: one that starts a whole period or more late), until one is on its
    deadline again: the deadlines never moved. With 2.5 periods, ticks 5 and 6 start at the
    same instant, so tick 6 finds no new state."""
    n = 12
    b = _bench(paper, n, work_s={4: work_periods * P})
    stats = b.run()
    busy_until = 4 + work_periods  # in periods
    starts = [max(k, busy_until) if k > 4 else k for k in range(n)]
    assert stats.ticks == n
    assert stats.overruns == overruns and stats.skipped_ticks == 0 and stats.stale_ticks == stale
    assert stats.lateness_s == [(start - k) * P for k, start in enumerate(starts)]
    assert stats.lateness_s[5] == (work_periods - 1.0) * P and stats.lateness_s[8:] == [0.0] * (n - 8)
    assert b.ticks.t_s == _grid(range(n))
    assert [s.at_s for s in b.servos.sent] == [start * P for start in starts]
    assert stats.work_s[4] == work_periods * P
    assert stats.resumes == 0


def test_far_behind_skips_whole_periods_and_stays_on_the_grid(paper: Scenario) -> None:
    """Tick 4's work takes 5.5 periods: at deadline 5 the loop is 4.5 periods late, more than
    ``skip_after_periods``, so it skips the 4 whole periods and flies tick 9, half a period
    late; ticks never leave the k * period grid."""
    n = 10
    b = _bench(paper, n, work_s={4: 5.5 * P})
    stats = b.run()
    assert stats.skipped_ticks == 4 and stats.overruns == 1
    assert stats.ticks == n
    assert b.ticks.t_s == _grid([*range(5), *range(9, 14)])
    assert [s.at_s for s in b.servos.sent] == _grid(range(5)) + [9.5 * P] + _grid(range(10, 14))
    assert stats.lateness_s == [0.0] * 5 + [0.5 * P] + [0.0] * 4  # the skipping pass is no tick
    assert stats.resumes == 0 and stats.stale_ticks == 0
    # the tick timer names the cause: the send section of tick 4 (where the work was), the
    # skip a tick that overran (awake, not asleep past its deadline)
    sections = stats.summary()["tick_sections"]
    assert sections["section_max_ms"]["send"] == 5.5 * P * 1e3
    assert max(v for k, v in sections["section_max_ms"].items() if k != "send") == 0.0
    worst = sections["worst_ticks"][0]
    assert worst["t_s"] == 4 * P and worst["total_ms"] == worst["send_ms"] == 5.5 * P * 1e3
    assert sections["skips"] == [{"t_s": 5 * P, "late_ms": 4.5 * P * 1e3, "overslept_ms": 0.0,
                                  "prev_work_ms": 5.5 * P * 1e3}]  # fmt: skip


def test_waiting_for_the_first_state_misses_no_deadline(paper: Scenario) -> None:
    """The plant is silent for the first 0.1 s (13 periods): the loop waits for it, 10 ms a
    time round, with its clock not started; the waits are counted as no overrun and no
    skipped tick (each was one overrun before), and the first tick is on time."""
    n = 5
    b = _bench(paper, n, silent=(0.0, 0.1))
    stats = b.run()
    assert stats.ticks == n and stats.overruns == 0 and stats.skipped_ticks == 0
    assert stats.lateness_s == [0.0] * n and stats.summary()["tick_sections"]["skips"] == []


def test_stall_longer_than_resume_gap_resumes_once_with_the_gap(paper: Scenario) -> None:
    """The process is stopped for 0.3 s in the sleep before tick 5: the loop skips the missed
    periods, then resumes (filters re-initialised, the flight's clock paused) once, the gap
    being the time between the ticks beyond one period."""
    stall_s = 0.3
    assert stall_s > RESUME_GAP_S
    n = 10
    b = _bench(paper, n, stalls={5: stall_s})
    stats = b.run()
    skipped = int(stall_s / P)  # 38 whole periods late at deadline 5
    assert stats.resumes == 1
    assert stats.gap_max_s == pytest.approx(stall_s, abs=1e-9)
    assert stats.skipped_ticks == skipped and stats.overruns == 1
    assert b.ticks.t_s == _grid([*range(5), *range(5 + skipped, 5 + skipped + n - 5)])
    assert stats.lateness_s[5] == pytest.approx(stall_s - skipped * P, abs=1e-9)
    # the tick timer: asleep past the deadline (the OS, here the stop), no tick overran
    (skip,) = stats.summary()["tick_sections"]["skips"]
    assert skip["overslept_ms"] == skip["late_ms"] == pytest.approx(stall_s * 1e3, abs=1e-6)
    assert skip["prev_work_ms"] == 0.0


def test_silent_plant_sends_nothing_while_stale_then_resumes(paper: Scenario) -> None:
    """The plant says nothing from tick 10 until tick 106: the loop flies on its last state
    (tick 9's) until more than the stale timeout of 32 periods has passed, then sends
    nothing, and flies again from the first state after the plant is back."""
    timeout, back, after = 32 * P, 106, 5
    first_stale = 9 + 32 + 1  # tick 41 is exactly the timeout after tick 9: not yet stale
    b = _bench(paper, first_stale + after, silent=(10 * P, back * P), stale_timeout_s=timeout)
    stats = b.run()
    assert stats.plant_stale_events == 1 and not stats.plant_stale
    flown = [*range(first_stale), *range(back, back + after)]
    assert [s.at_s for s in b.servos.sent] == _grid(flown)
    assert b.ticks.t_s == _grid(flown)
    # the ticks on tick 9's state (10-41) were sent with its stamp again
    assert [s.t_us for s in b.servos.sent[9:first_stale]] == [b.servos.sent[9].t_us] * (first_stale - 9)
    assert stats.stale_ticks == back - 10  # every deadline without a new state, sent or not
    assert len(stats.lateness_s) == back + after and stats.overruns == stats.skipped_ticks == 0
    # silent 0.5 s since the last tick sent (41): a resume, the gap beyond one period
    assert stats.resumes == 1 and stats.gap_max_s == (back - (first_stale - 1) - 1) * P


def test_flight_wall_time_is_read_on_the_injected_clock(paper: Scenario) -> None:
    """Armed from the first tick: ``wall_s`` counts fake seconds from it to the end."""
    n = 20
    b = _bench(paper, n, armed=True)
    stats = b.run()
    assert stats.ticks == n
    assert b.runner.wall_s == (n - 1) * P


class TickingClock:
    """Each read is one millisecond after the one before."""

    def __init__(self) -> None:
        self.reads = 0

    def perf_counter(self) -> float:
        self.reads += 1
        return (self.reads - 1) * 1e-3


def test_the_tick_timer_times_the_collector_inside_a_tick() -> None:
    """A full collection inside a tick: counted as generation 2, its pause (two clock reads,
    1 ms apart) in the tick's row; none counted once the timer is closed."""
    clock = TickingClock()
    timer = TickTimer(clock.perf_counter)
    enabled = gc.isenabled()
    gc.disable()  # no automatic collection between the reads below
    try:
        with timer:
            timer.begin()  # read 0 ms
            gc.collect()  # reads 1 and 2 ms
            timer.lap(CONTROL)  # read 3 ms
            timer.end(0.5)
        gc.collect()
    finally:
        if enabled:
            gc.enable()
    s = timer.summary()
    assert s["gc_collections"] == [0, 0, 1] and s["gc_max_ms"][2] == pytest.approx(1.0)
    assert s["section_max_ms"]["control"] == pytest.approx(3.0)
    assert s["worst_ticks"] == [pytest.approx({"t_s": 0.5, "total_ms": 3.0, "gc_ms": 1.0, "navigate_ms": 0.0,
                                               "control_ms": 3.0, "record_ms": 0.0, "send_ms": 0.0,
                                               "services_ms": 0.0, "flush_ms": 0.0})]  # fmt: skip


class WaitingPlant(FakePlant):
    """A plant waiting for its first command publishes at 20 Hz: a poll (no timeout) then
    finds nothing, a wait finds the next publication. Once commanded it flies as FakePlant.
    ``never``: it never speaks, and stops the loop after ``never`` fake seconds."""

    def __init__(self, clock: FakeClock, servos: list[Sent], stop: threading.Event,
                 never: float | None = None) -> None:  # fmt: skip
        super().__init__(clock)
        self.servos, self.stop, self.never = servos, stop, never

    def latest_state(self, timeout_s: float = 0.0, spin_s: float = 0.0) -> StateSample | None:
        if self.never is not None:
            self.clock.advance(timeout_s)
            if self.clock.now - T0 >= self.never:
                self.stop.set()
            return None
        if self.servos:
            return super().latest_state(timeout_s, spin_s)
        if timeout_s <= 0.0:
            return None
        self.clock.advance(min(timeout_s, 0.005))  # the next 20 Hz publication, within the wait
        return StateSample(0, np.zeros(12))


def test_a_plant_that_publishes_only_between_polls_is_flown(paper: Scenario) -> None:
    """The state the wait for the plant returns is the one the loop starts on (it was dropped,
    and the poll after the wait found nothing, every time round: a user's controller never
    flew in real time); the compiled code is warmed up once, before the first tick."""
    n = 20
    b = _bench(paper, n)
    b.runner.state_in = WaitingPlant(b.clock, b.servos.sent, b.stop)
    warm: list[int] = []
    b.runner.warm_up = lambda x: warm.append(1)  # type: ignore[method-assign]
    stats = b.run()
    assert stats.ticks == n and len(warm) == 1
    assert stats.resumes == 0 and stats.skipped_ticks == 0
    assert b.runner.verdict() is None


def test_a_loop_that_never_ticks_says_why(paper: Scenario, caplog: pytest.LogCaptureFixture) -> None:
    """No state ever: a warning at 5 s and again 30 s later, and a verdict (the command exits
    non-zero with it), never "a clean run"."""
    b = _bench(paper, 1)
    b.runner.state_in = WaitingPlant(b.clock, b.servos.sent, b.stop, never=40.0)
    with caplog.at_level("WARNING", logger="autopilot.runner"):
        stats = b.run()
    assert stats.ticks == 0
    waits = [r.getMessage() for r in caplog.records if "no state from the plant" in r.getMessage()]
    assert [w.split(" s:")[0] for w in waits] == [f"no state from the plant in {s}" for s in (5, 35)]
    verdict = b.runner.verdict()
    assert verdict is not None and verdict.startswith("ran no control tick")
