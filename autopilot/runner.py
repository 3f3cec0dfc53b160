"""The fixed-rate loop: the only code in the autopilot that reads a clock (an injected
:class:`~autopilot.clock.Clock`, so tests can drive its scheduling on a fake one).

``lockstep``: each plant state is answered by exactly one command computed at the state's
simulation time (a re-sent state gets the same answer again). ``realtime``: ticks on the
monotonic clock with deadline scheduling (deadline k = start + k * period, so no drift),
using the newest state; it measures wake-up lateness, overruns and stale states.
"""

from __future__ import annotations

import csv
import dataclasses
import gc
import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Protocol

import numpy as np

from autopilot.clock import Clock, SystemClock
from autopilot.control import D_PHI_C, D_PSI_C, D_THETA_C, N_DIAG, OK
from autopilot.controllers import FlyingController
from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.log import N_EST_LOG
from autopilot.estimation.onboard import OnboardEstimator
from autopilot.flight.manager import FlightManager
from autopilot.flight.modes import Mode
from autopilot.metrics import CSV_HEADER, ROTOR_CSV, FlightRecord, rotor_record, unwrap_after, write_rows
from autopilot.reference import N_REF
from autopilot.tick_timer import CONTROL, FLUSH, NAVIGATE, RECORD, SEND, SERVICES, TickTimer
from heli_common.layout import Layout
from heli_common.state import N_PITCH, N_STATE, PHI, PSI, THETA, X_N, Y_W, Z_U, FloatArray
from heli_common.wire.links import ServoOutput, StateSource
from heli_common.wire.mavlink.sim_protocol import N_ROTOR_TRUTH, StateSample

log = logging.getLogger("autopilot.runner")
LOCKSTEP_SPIN_S = 0.002  # poll this long before sleeping (see MavlinkUdp.wait)
# real time: a gap longer than this between ticks is a stall (the process stopped, the
# plant went silent), not scheduling jitter, which the skip logic absorbs
RESUME_GAP_S = 0.25
# no state from the plant yet: say so after this long, and again every WAIT_REPEAT_S (a
# loop that does not tick must say why, not sit silent until it is killed)
WAIT_WARN_S = 5.0
WAIT_REPEAT_S = 30.0

Euler = tuple[float, float, float]


def _euler(x: FloatArray) -> Euler:
    return float(x[PHI]), float(x[THETA]), float(x[PSI])


class TickService(Protocol):
    """A service the runner drives around each control step (the ground-station link)."""

    def at_tick_start(self, t_s: float, x: FloatArray) -> None:
        """Apply what arrived since the last tick (commands, parameter changes)."""

    def after_tick(
        self, t_s: float, x: FloatArray, ref: FloatArray | None, u: FloatArray, att_cmd_rad: Euler
    ) -> None:
        """Report the tick (telemetry, events); runs after the command has been sent.
        ``att_cmd_rad``: the controller's roll, pitch and yaw commands (FLU), or the
        attitude itself while it commands none."""

    def between_ticks(self, t_s: float, x: FloatArray) -> None:
        """Receive and parse input, with a bounded budget; also runs while the plant is
        quiet. Nothing received here changes the vehicle before the next tick starts."""

    def warm_up(self, x: FloatArray) -> None:
        """Do once, sending nothing, what the first tick will (numba loads compiled code on
        a function's first call): runs before the loop's clock starts."""


@dataclass(frozen=True)
class RunnerConfig:
    mode: str = "lockstep"
    rate_hz: float = 100.0
    duration_s: float | None = None  # stop after this much flight time
    stale_timeout_s: float = 0.5  # plant silent after this long without a state
    skip_after_periods: int = 2  # realtime: more than this many periods late -> skip ticks


@dataclass
class LoopStats:
    ticks: int = 0
    lateness_s: list[float] = field(default_factory=list)
    overruns: int = 0  # a tick that started a whole period or more after its deadline
    skipped_ticks: int = 0
    stale_ticks: int = 0  # no new state since the previous tick (realtime)
    plant_stale_events: int = 0
    plant_stale: bool = False
    bad_outputs: int = 0
    plant_sessions: int = 0  # restarts of the plant seen (its clock went back)
    resumes: int = 0  # real time: ticks resumed after a gap (a stall or a silent plant)
    gap_max_s: float = 0.0
    work_s: list[float] = field(default_factory=list)  # real time: wall time of each tick's work
    timer: TickTimer | None = None  # where each tick's time went (set by the runner)

    def summary(self) -> dict[str, Any]:
        lat = np.array(self.lateness_s) if self.lateness_s else np.zeros(1)
        work = np.array(self.work_s) if self.work_s else np.zeros(1)
        return {
            "ticks": self.ticks,
            "jitter_p50_ms": float(np.percentile(lat, 50) * 1e3),
            "jitter_p99_ms": float(np.percentile(lat, 99) * 1e3),
            "jitter_max_ms": float(lat.max() * 1e3),
            "overruns": self.overruns,
            "skipped_ticks": self.skipped_ticks,
            "stale_ticks": self.stale_ticks,
            "plant_stale_events": self.plant_stale_events,
            "bad_outputs": self.bad_outputs,
            "plant_sessions": self.plant_sessions,
            "resumes": self.resumes,
            "gap_max_s": self.gap_max_s,
            "tick_work_p99_ms": float(np.percentile(work, 99) * 1e3),
            "tick_work_max_ms": float(work.max() * 1e3),
            **({} if self.timer is None else {"tick_sections": self.timer.summary()}),
        }


class Recorder:
    """The flight as the controller saw it, one row per tick, for run.csv and summary.json.

    Rows go into preallocated blocks of ``capacity`` rows, a new block when one is full:
    no Python object per tick (the garbage collector has nothing growing to rescan), and
    no copy of the record during the flight (doubling one array copies megabytes in one
    tick: 22 ms at 16384 rows, four skipped ticks at 400 Hz)."""

    # t, state, reference, pitches, diagnostics, trajectory time, landing flag, the
    # world's truth when the plant flies one (air NWU, servo positions; NaN otherwise),
    # flying from sensors the estimate and the estimator's log (NaN otherwise), and the
    # rotor plant's truth (a1, b1, rotor speed, throttle; NaN otherwise)
    ROW = Layout(
        "recorder row", ("t", 1), ("x", N_STATE), ("ref", N_REF), ("u", N_PITCH), ("diag", N_DIAG),
        ("traj_t", 1), ("landing", 1), ("air", 3), ("servo", N_PITCH), ("x_hat", N_STATE),
        ("est", N_EST_LOG), ("rotor", N_ROTOR_TRUTH),
    )  # fmt: skip
    WIDTH = ROW.end

    def __init__(self, capacity: int = 4096, stream_csv: Path | None = None, flush_every: int = 100) -> None:
        self._block = capacity
        self._blocks = [np.empty((capacity, self.WIDTH))]
        self.n = 0
        # run.csv as it flies, flushed every ``flush_every`` rows: a killed process loses
        # about a second of its record, not all of it
        self.flush_every = flush_every
        self._flushed = 0
        self._psi_before: float | None = None
        self._header_written = False
        self._csv_cols: list[int] | None = None  # run.csv's columns in a row, set at the first flush
        self._fh: IO[str] | None = None
        self._csv: Any = None
        if stream_csv is not None:
            stream_csv.parent.mkdir(parents=True, exist_ok=True)
            self._fh = stream_csv.open("w", newline="")
            self._csv = csv.writer(self._fh)
            self._header_written = False

    def flush_if_due(self) -> None:
        if self._fh is not None and self.n - self._flushed >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        """Append the rows recorded since the last flush to the streamed run.csv: run.csv's
        columns gathered from the block in one take (the same numbers as
        :meth:`FlightRecord.rows`, tested), with no record built."""
        if self._fh is None or self.n == self._flushed:
            return
        b = self.rows_array(self._flushed)
        if self._csv_cols is None:  # the rotor plant's columns where its plant reports them
            rotor = bool(np.isfinite(b[:, _COLS["rotor"]]).any())
            self._csv_cols = _CSV_COLS_ROTOR if rotor else _CSV_COLS
            self._csv.writerow(CSV_HEADER + ROTOR_CSV if rotor else CSV_HEADER)
            self._header_written = True
        rows = b[:, self._csv_cols]
        rows[:, _CSV_PSI] = unwrap_after(rows[:, _CSV_PSI], self._psi_before)
        write_rows(self._fh, rows)
        self._fh.flush()
        self._flushed = self.n
        self._psi_before = float(rows[-1, _CSV_PSI])

    def close(self) -> None:
        if self._fh is not None:
            if not self._header_written:  # nothing flown: the header alone
                self._csv.writerow(CSV_HEADER)
                self._header_written = True
            self.flush()
            self._fh.close()
            self._fh = None

    def add(
        self, t: float, x: FloatArray, ref: FloatArray, u: FloatArray, diag: FloatArray,
        traj_t: float = math.nan, landing: bool = False, truth: StateSample | None = None,
        x_hat: FloatArray | None = None, est_row: FloatArray | None = None,
    ) -> None:  # fmt: skip
        i = self.n - (len(self._blocks) - 1) * self._block
        if i == self._block:
            self._blocks.append(np.empty((self._block, self.WIDTH)))
            i = 0
        row = self._blocks[-1][i]
        c = _COLS
        row[c["t"]] = t
        row[c["x"]] = x
        row[c["ref"]] = ref
        row[c["u"]] = u
        row[c["diag"]] = diag
        row[c["traj_t"]] = traj_t
        row[c["landing"]] = landing
        air = None if truth is None else truth.air_nwu_m_s
        servo = None if truth is None else truth.servo_rad
        rotor = None if truth is None else truth.rotor
        row[c["air"]] = math.nan if air is None else air
        row[c["servo"]] = math.nan if servo is None else servo
        row[c["x_hat"]] = math.nan if x_hat is None else x_hat
        row[c["est"]] = math.nan if est_row is None else est_row
        row[c["rotor"]] = math.nan if rotor is None else rotor
        self.n += 1

    def rows_array(self, start: int = 0) -> FloatArray:
        """Rows ``start``.. as one array (a copy where they span blocks)."""
        if start >= self.n:
            return np.empty((0, self.WIDTH))
        first, last = start // self._block, max(start, self.n - 1) // self._block
        i0 = start - first * self._block
        if first == last:
            return self._blocks[first][i0 : i0 + self.n - start]
        # the rows wanted of each block, not the blocks: a flush that spans two blocks copied
        # 6.6 MB for its 100 rows (2.5 ms, measured; a skipped tick at 400 Hz)
        i1 = self.n - last * self._block
        parts = [self._blocks[first][i0:], *self._blocks[first + 1 : last], self._blocks[last][:i1]]
        return np.concatenate(parts)

    def record(
        self, wall_s: float, extra: dict[str, Any], pitches: FloatArray | None = None, start: int = 0
    ) -> FlightRecord:
        """The flight so far (from row ``start``); ``pitches`` replaces the commanded ones
        (e.g. the pitches a servo actually applied, one row per tick)."""
        b = self.rows_array(start)
        c = _COLS
        u = b[:, c["u"]].copy() if pitches is None else np.asarray(pitches, dtype=float)
        rec = FlightRecord.from_ticks(
            b[:, c["t"]].copy(), b[:, c["x"]].copy(), b[:, c["ref"]].copy(), u, b[:, c["diag"]], wall_s,
            extra, traj_t_s=b[:, c["traj_t"]].copy(), landing=b[:, c["landing"]] != 0,
        )  # fmt: skip
        air, servo = b[:, c["air"]], b[:, c["servo"]]
        if np.isfinite(air).any():
            rec = dataclasses.replace(rec, air_nwu_m_s=air.copy(), servo_rad=servo.copy())
        x_hat = b[:, c["x_hat"]]
        if np.isfinite(x_hat).any():
            rec = dataclasses.replace(rec, x_hat=x_hat.copy(), est_log=b[:, c["est"]].copy())
        rotor = b[:, c["rotor"]]
        if np.isfinite(rotor).any():
            rec = dataclasses.replace(rec, rotor=rotor_record(rotor))
        return rec


class Runner:
    def __init__(
        self,
        ctrl: FlyingController,
        flight: FlightManager,
        state_in: StateSource | None,
        servo_out: ServoOutput,
        cfg: RunnerConfig,
        services: Sequence[TickService] = (),
        recorder: Recorder | None = None,
        estimator: EstimatorConfig | None = None,
        *,
        clock: Clock | None = None,
    ) -> None:
        self.ctrl = ctrl
        self.clock: Clock = SystemClock() if clock is None else clock  # every time read and sleep of the loop
        self.estimator = estimator or EstimatorConfig()
        # flying from sensors (the plant sends measurements): the estimate the tick flies on
        self.nav: OnboardEstimator | None = None
        self.manager = flight
        self.flight = flight.flight
        self.state_in = state_in
        self.servo_out = servo_out
        self.cfg = cfg
        self.services = list(services)
        self._last_t_s = 0.0
        self._last_x: FloatArray | None = None
        self.recorder = recorder
        self.timer = TickTimer(self.clock.perf_counter)
        self.stats = LoopStats(timer=self.timer)
        self.u = np.zeros(N_PITCH)
        self.wall_s = 0.0
        self._wall0: float | None = None
        self._t_arm_s = 0.0
        self._session = 0
        self.sample: StateSample | None = None  # the state the tick runs on (with any world truth)
        self._wait0: float | None = None  # when the wait for the plant's first state began
        self._wait_warned_s = 0.0  # how long the wait had lasted at its last warning

    def verdict(self) -> str | None:
        """Why the run failed, or None: a loop that ran no tick, or that lost its plant in
        flight and never heard it again, did not do its job (the command exits non-zero)."""
        if self.stats.ticks == 0:
            return ("ran no control tick: no state ever came from the plant (is it running, and "
                    "sending to this process's sim-link port?)")  # fmt: skip
        if self.stats.plant_stale and self.flight.armed:
            return (f"lost the plant in flight at t = {self._last_t_s:.2f} s: it went silent and never "
                    "came back")  # fmt: skip
        return None

    def _waiting_for_plant(self, now: float) -> None:
        """Before the first state: say, in the log, that the loop is waiting and for what."""
        if self._wait0 is None:
            self._wait0 = now
        waited = now - self._wait0
        due = WAIT_WARN_S if self._wait_warned_s == 0.0 else self._wait_warned_s + WAIT_REPEAT_S
        if waited >= due:
            self._wait_warned_s = waited
            log.warning("no state from the plant in %.0f s: no control tick yet (is the plant running, "
                        "and sending to this process's sim-link port?)", waited)  # fmt: skip

    def service(self, t_s: float, x: FloatArray) -> None:
        """The services' input, between ticks; also run while the plant is quiet."""
        for s in self.services:
            s.between_ticks(t_s, x)

    def _navigate(self, t_s: float, truth: FloatArray) -> FloatArray:
        """The state the tick flies on: the plant's state as sent, or, when the plant sends
        measurements, the estimate from them (started at the first such state's truth, as
        an estimator aligned at its known spawn point), its health fed to the failsafes."""
        s = self.sample
        if s is None or s.meas is None:
            return truth
        if self.nav is None:
            self.nav = OnboardEstimator(self.estimator, self.cfg.rate_hz, truth, self.manager.cfg.home)
        x_hat = self.nav.update(s.meas_t_s, s.meas, s.meas_mask)
        h = self.nav.health
        self.manager.navigation(t_s, x_hat, h.gps_lost, h.n_rejected, h.n_resets, h.diverged)
        return x_hat

    def tick(self, t_s: float, x: FloatArray, t_us: int | None = None) -> FloatArray:
        """One control step at ``t_s``; the command goes out (answering the state stamped
        ``t_us``) before the tick hooks run. ``t_us`` None: compute only, send nothing.
        ``x`` is the plant's state; flying from sensors, the tick runs on the estimate and
        ``x`` goes to the record only (the truth beside it)."""
        sec = self.timer
        sec.begin()
        truth = x
        x = self._navigate(t_s, truth)
        self._last_t_s, self._last_x = t_s, x
        for s in self.services:
            s.at_tick_start(t_s, x)
        self.manager.pre_tick(t_s, x)
        if self._wall0 is None and self.flight.armed:
            self._wall0 = self.clock.perf_counter()
            self._t_arm_s = t_s
        sec.lap(NAVIGATE)
        ref = self.flight.reference(t_s, x)
        if ref is None:  # disarmed: rotor idle at zero pitch, nothing integrates
            self.ctrl.reset()
            self.u = np.zeros(N_PITCH)
            sec.lap(CONTROL)
        else:
            hold = self.flight.hold_integrators(x, ref)
            u = self.ctrl.update(t_s, x, ref, hold_integrators=hold)
            if self.ctrl.status != OK:
                self.stats.bad_outputs += 1
            self.u = u
            sec.lap(CONTROL)
            if self.recorder is not None:  # flight time: since arming
                landing = self.flight.mode is Mode.LAND
                est = None if self.nav is None else self.nav.log_row
                self.recorder.add(t_s - self._t_arm_s, truth, ref, u, self.ctrl.diag,
                                  self.manager.trajectory_time(t_s), landing, self.sample,
                                  None if est is None else x, est)  # fmt: skip
                sec.lap(RECORD)
        self.stats.ticks += 1
        if t_us is not None:
            self.servo_out.send_pitches(t_us, self.u, self.flight.armed)
        sec.lap(SEND)
        self.manager.post_tick(t_s, x)
        d = self.ctrl.diag
        att_cmd = (float(d[D_PHI_C]), float(d[D_THETA_C]), float(d[D_PSI_C]))
        if ref is None or not all(math.isfinite(a) for a in att_cmd):  # a user's law commands none
            att_cmd = _euler(x)
        for s in self.services:
            s.after_tick(t_s, x, ref, self.u, att_cmd)
        self.service(t_s, x)
        sec.lap(SERVICES)
        if self.recorder is not None:  # after the command went out
            self.recorder.flush_if_due()
        sec.lap(FLUSH)
        sec.end(t_s)
        return self.u

    def _done(self, t_s: float) -> bool:
        """Past the end: the tick at t = duration itself is flown, as in-process."""
        d = self.cfg.duration_s
        return d is not None and t_s > d + 1e-9

    def _idle(self, t_s: float) -> None:
        """No tick (the plant is silent): the services still run, so the ground station
        keeps its heartbeat and hears what happened."""
        if self._last_x is None:
            return
        for s in self.services:
            s.between_ticks(t_s, self._last_x)
            s.after_tick(t_s, self._last_x, None, self.u, _euler(self._last_x))

    def _new_plant_session(self, s: StateSample) -> None:
        """The plant's clock went back: a restarted plant. Start over with it."""
        self._session = s.session
        self.stats.plant_sessions += 1
        log.warning("new plant session (clock restarted at %.3f s): disarmed, control reset", s.t_us / 1e6)
        self.manager.plant_restarted(s.t_us / 1e6, s.x)
        self.nav = None  # a new vehicle: the estimator starts again on its first state
        self.ctrl.reset()
        self.u = np.zeros(N_PITCH)

    def _resume_after_gap(self, gap_s: float, t_s: float) -> None:
        """Real time, after a stall (of this process, or a silent plant): pause the flight's
        clock by the gap and re-initialise the controller's filters on the current state,
        so no pseudo-differentiator sees the gap as a step."""
        self.stats.resumes += 1
        self.stats.gap_max_s = max(self.stats.gap_max_s, gap_s)
        log.warning("control loop resumed after a %.2f s gap: filters re-initialised", gap_s)
        self.manager.resume_after_gap(gap_s, t_s)
        if self.flight.armed:
            self.ctrl.reset()

    def warm_up(self, x: FloatArray) -> None:
        """Load the compiled code of the first tick (controller, services) before the clock
        starts: tens of milliseconds that would otherwise make the first ticks late."""
        self.ctrl.warm_up(x)
        OnboardEstimator(self.estimator, self.cfg.rate_hz, x, self.manager.cfg.home).warm_up()
        for s in self.services:
            s.warm_up(x)

    def _stale(self, stale: bool) -> None:
        if stale and not self.stats.plant_stale:
            self.stats.plant_stale_events += 1
            log.warning("plant silent for %.2f s: sending nothing until it is back", self.cfg.stale_timeout_s)
            self.manager.plant_link(lost=True)
        elif not stale and self.stats.plant_stale:
            self.manager.plant_link(lost=False)
        self.stats.plant_stale = stale

    def run(self, stop: threading.Event) -> LoopStats:
        """Fly until stopped or the duration is over; ``wall_s`` counts from the first tick
        (not the wait for a starting plant). Without a state source (an in-process loop
        that calls :meth:`tick` itself) there is nothing to run."""
        if self.state_in is None:
            raise ValueError("Runner.run needs a state source")
        gc.freeze()  # start-up objects (numba, scipy) never need rescanning during the flight
        with self.timer:  # the collector's pauses, timed while the loop runs
            if self.cfg.mode == "lockstep":
                self._run_lockstep(stop, self.state_in)
            else:
                self._run_realtime(stop, self.state_in)
        if self._wall0 is not None:
            self.wall_s = self.clock.perf_counter() - self._wall0
        return self.stats

    def _run_lockstep(self, stop: threading.Event, src: StateSource) -> None:
        last_t_us = -1
        last_state = self.clock.monotonic()
        while not stop.is_set():
            s = src.latest_state(0.05, spin_s=LOCKSTEP_SPIN_S)
            now = self.clock.monotonic()
            if s is None:
                if self._last_x is None:
                    self._waiting_for_plant(now)
                self._stale(now - last_state > self.cfg.stale_timeout_s)
                if self._last_x is not None:  # vehicle time stands still; the GCS's does not
                    self._idle(self._last_t_s + (now - last_state))
                continue
            last_state = now
            self._stale(False)
            if s.session != self._session:
                self._new_plant_session(s)
                last_t_us = -1
            if s.t_us == last_t_us:  # re-sent by the plant: our answer was lost, send it again
                self.servo_out.send_pitches(s.t_us, self.u, self.flight.armed)
                continue
            t_s = s.t_us / 1e6
            if self._done(t_s):
                break
            self.sample = s
            self.tick(t_s, s.x, s.t_us)
            last_t_us = s.t_us

    def _run_realtime(self, stop: threading.Event, src: StateSource) -> None:
        period = 1.0 / self.cfg.rate_hz
        latest: StateSample | None = None
        latest_at = 0.0
        start = self.clock.monotonic()
        last_tick_wall: float | None = None
        k = 0
        while not stop.is_set():
            deadline = start + k * period
            delay = deadline - self.clock.monotonic()
            if delay > 0:
                self.clock.sleep(delay)
            wake = self.clock.monotonic()
            late = wake - deadline
            if late > self.cfg.skip_after_periods * period:
                skip = int(late / period)
                # asleep past the deadline: the OS woke us late; awake: the tick before overran
                self.timer.skipped(k * period, late, late if delay > 0 else 0.0,
                                   self.stats.work_s[-1] if self.stats.work_s else 0.0)  # fmt: skip
                self.stats.skipped_ticks += skip
                self.stats.overruns += 1
                k += skip
                continue
            if late >= period:
                self.stats.overruns += 1
            s = src.latest_state(0.0)
            if latest is None:  # the plant has not spoken yet: wait for it, clock not started
                # the first state, from this poll or from the wait, is the one to start on: a
                # plant waiting for its first command publishes at 20 Hz, and a loop that
                # dropped the wait's state and polled again found nothing every time round
                # (a light first tick: it never ticked); one that started on this poll's
                # state skipped the warm-up, and its cold first tick read as a stall
                s = s or src.latest_state(0.01)
                self._waiting_for_plant(self.clock.monotonic())
                # the schedule starts after the wait: a wait is no deadline missed (it was
                # counted as four skipped ticks each time round)
                start = self.clock.monotonic()
                k = 0
                if s is None:
                    continue
                self.warm_up(s.x)
                latest = src.latest_state(0.0) or s  # the plant went on meanwhile
                latest_at = start = wake = self.clock.monotonic()  # tick 0 now, on time
                late = 0.0
            elif s is not None and s.session != latest.session:
                self._new_plant_session(s)
                latest, latest_at = s, wake
            elif s is not None and s.t_us > latest.t_us:
                latest, latest_at = s, wake
            else:
                self.stats.stale_ticks += 1
            self.stats.lateness_s.append(late)
            self._stale(wake - latest_at > self.cfg.stale_timeout_s)
            t_s = k * period
            if self._done(t_s):
                break
            if self.stats.plant_stale:  # nothing is sent that a plant (a new one?) would act on
                self._idle(t_s)
                k += 1  # and on to the next deadline: never a busy loop while the plant is silent
                continue
            if last_tick_wall is not None and wake - last_tick_wall > max(RESUME_GAP_S, 10 * period):
                self._resume_after_gap(wake - last_tick_wall - period, t_s)
            last_tick_wall = wake
            self.sample = latest
            self.tick(t_s, latest.x, latest.t_us)
            self.stats.work_s.append(self.clock.monotonic() - wake)
            k += 1


# each block's columns of a row: an index for a single value, a slice for a vector
_COLS: dict[str, Any] = {
    name: Recorder.ROW.offset(name) if Recorder.ROW.size_of(name) == 1
    else slice(Recorder.ROW.offset(name), Recorder.ROW.offset(name) + Recorder.ROW.size_of(name))
    for name in Recorder.ROW.names
}  # fmt: skip

# run.csv's columns (autopilot.metrics.CSV_HEADER, then ROTOR_CSV on the rotor plant) as
# positions in a recorder row, for the streamed flush
_X0, _REF0, _U0, _DIAG0 = (Recorder.ROW.offset(k) for k in ("x", "ref", "u", "diag"))
_CSV_COLS = [
    _COLS["t"], *(_X0 + i for i in (X_N, Y_W, Z_U, PHI, THETA, PSI)), *(_REF0 + i for i in range(3)),
    _DIAG0 + D_PSI_C, *(_U0 + i for i in range(N_PITCH)), _DIAG0 + D_PHI_C, _DIAG0 + D_THETA_C,
]  # fmt: skip
_ROTOR0 = Recorder.ROW.offset("rotor")
_CSV_COLS_ROTOR = [*_CSV_COLS, *range(_ROTOR0, _ROTOR0 + N_ROTOR_TRUTH)]
_CSV_PSI = CSV_HEADER.index("psi_rad")
