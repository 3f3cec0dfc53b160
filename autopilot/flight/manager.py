"""The vehicle's flight logic in one place: arming, modes, take-off, landing, return,
missions, offboard setpoints and the failsafes with their timeouts.

Driven by typed commands (:mod:`autopilot.flight.commands`) from any link, and by the
runner's ticks: :meth:`FlightManager.pre_tick` before the control law (failsafes that
change the reference), :meth:`FlightManager.post_tick` after it (mission progress,
disarm after landing). Clock-free: every call takes the runner's time ``t_s``. What the
operator should hear about is queued as events (:meth:`take_events`) for whichever link
reports it.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from autopilot.flight import commands as c
from autopilot.flight.modes import LANDED_ALT_M, FlightStateMachine, Mode, landed
from autopilot.reference import N_REF, REF_POS
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.waypoints import FlightLimits, WaypointTrajectory
from autopilot.trajectory_codec import mission_to_trajectory
from heli_common import frames
from heli_common.geo import GeoPoint
from heli_common.state import Z_U, FloatArray
from heli_common.wire.mavlink import mission_items as ms
from heli_common.wire.mavlink.mission_items import MissionItem

DEFAULT_TAKEOFF_ALT_M = 2.5
TAKEOFF_ALT_RANGE_M = (0.5, 500.0)
EVENT_QUEUE = 256
TOUCHDOWN_S = 0.5  # landing: this long with the estimate on the ground, then disarm


class MissionState(enum.Enum):
    NONE = "none"  # no mission flown since start-up (or a new one not started)
    ACTIVE = "active"
    COMPLETE = "complete"


class LandedState(enum.Enum):
    ON_GROUND = "on_ground"
    IN_AIR = "in_air"
    LANDING = "landing"


@dataclass(frozen=True)
class FlightConfig:
    home: GeoPoint
    limits: FlightLimits = FlightLimits()
    offboard_timeout_s: float = 1.0  # no setpoint for this long in offboard -> hold
    # flying from sensors: GPS lost -> hold (on the dead-reckoned estimate), and after this
    # long without GPS -> land, as PX4's and ArduPilot's position-loss failsafes do
    gps_loss_land_after_s: float = 10.0


@dataclass
class _Offboard:
    ref_nwu: FloatArray  # pos, vel, acc (NaN where not given)
    received_t_s: float


class FlightManager:
    """See the module docstring. ``mission()`` returns the stored (accepted) mission."""

    def __init__(self, cfg: FlightConfig, mission: Callable[[], tuple[MissionItem, ...]] = tuple) -> None:
        self.cfg = cfg
        self.flight = FlightStateMachine()
        self._mission = mission
        self.offboard_timeout_s = cfg.offboard_timeout_s
        self.mission_on_arm = False  # mission mode selected while disarmed
        self.plant_lost = False
        self._primary: object = None  # the mission or timed trajectory being flown
        self._offboard: _Offboard | None = None
        self._mission_traj: WaypointTrajectory | None = None
        self._mission_done = False
        self._prev_tau: float | None = None
        self._current_seq = 0
        # bounded: with no link draining it, the oldest events are dropped
        self._events: deque[c.Event] = deque(maxlen=EVENT_QUEUE)
        self._t = 0.0
        self._x: FloatArray = np.zeros(12)
        self.gps_lost_since: float | None = None  # flight time the GPS was declared lost
        self.nav_diverged = False  # the navigation filter said it diverged (latched: it lands)
        self._nav_seen = (0, 0)  # rejected fixes and estimator resets already reported
        self._low_since: float | None = None  # landing: since when the estimate is on the ground

    def set_mission_source(self, mission: Callable[[], tuple[MissionItem, ...]]) -> None:
        """Where the stored mission lives (the link that runs the mission protocol)."""
        self._mission = mission

    # -- what the links read -----------------------------------------------------------
    @property
    def armed(self) -> bool:
        return self.flight.armed

    @property
    def mode(self) -> Mode:
        """The mode to report: mission mode selected while disarmed shows as AUTO."""
        return Mode.AUTO if self.mission_on_arm else self.flight.mode

    def armable(self) -> bool:
        """Whether arming would be accepted now (it always is: see ``_arm``)."""
        return True

    def trajectory_time(self, t_s: float) -> float:
        """Time along the flown trajectory (a mission or a timed trajectory), NaN while
        holding, taking off, returning or landing: the error windows' time base."""
        f = self.flight
        if f.mode is not Mode.AUTO or f.trajectory is None or f.trajectory is not self._primary:
            return math.nan
        tau = t_s - f.t0_s
        return tau if 0.0 <= tau <= f.trajectory.duration_s else math.nan

    def flew_duration(self, duration_s: float) -> bool:
        """Whether the trajectory flown last lasts ``duration_s`` (the scenario's own, when
        a ground station uploaded it): the scenario's extra error windows then apply."""
        traj = self._primary
        return isinstance(traj, Trajectory) and abs(traj.duration_s - duration_s) < 1e-6

    def mission_state(self) -> MissionState:
        if self._mission_traj is not None:
            return MissionState.ACTIVE
        return MissionState.COMPLETE if self._mission_done else MissionState.NONE

    def landed_state(self, x: FloatArray) -> LandedState:
        if not self.flight.armed or landed(x):
            return LandedState.ON_GROUND
        return LandedState.LANDING if self.flight.mode is Mode.LAND else LandedState.IN_AIR

    def take_events(self) -> list[c.Event]:
        out = list(self._events)
        self._events.clear()
        return out

    def _say(self, severity: c.Severity, text: str) -> None:
        self._events.append(c.Text(severity, text))

    # -- commands ----------------------------------------------------------------------
    def execute(self, cmd: c.Command, t_s: float, x: FloatArray) -> c.Reply:
        """Apply one command at time ``t_s`` with the vehicle at ``x`` (between two ticks)."""
        self._t, self._x = t_s, x
        handler = self._HANDLERS.get(type(cmd))
        if handler is None:
            return c.Reply(c.Result.UNSUPPORTED)
        reply: c.Reply = handler(self, cmd)
        return reply

    def _arm(self, cmd: c.Arm) -> c.Reply:
        # Arming needs no plan: an armed vehicle with nothing to fly holds where it is (on
        # the ground its integrators are held), so a take-off can follow (MAVSDK, QGC).
        f = self.flight
        mission = self._mission()
        f.armed = True
        if self.mission_on_arm and mission:
            # mission mode was selected while disarmed (as PX4): it starts now, so the
            # trajectory's t = 0 is this tick
            self.mission_on_arm = False
            reply = self._start_items(list(mission), Mode.AUTO, mission=True)
            if not reply.accepted:
                f.armed = False
                return reply
            return c.Reply(c.Result.ACCEPTED, "Armed: mission started")
        if f.mode in (Mode.IDLE, Mode.HOLD):  # hold here; a started trajectory or the
            f.hold(self._x, self._t)  # offboard setpoints are followed from this tick
        return c.Reply(c.Result.ACCEPTED, "Armed")

    def _disarm(self, cmd: c.Disarm) -> c.Reply:
        ok, why = self.flight.disarm(self._x, force=cmd.force)
        if ok:
            self.mission_on_arm = False
        return c.Reply(c.Result.ACCEPTED if ok else c.Result.DENIED, f"Disarm: {why}")

    def _start_items(
        self, items: list[MissionItem], mode: Mode, start_seq: int = 0, mission: bool = False
    ) -> c.Reply:
        """Fly ``items`` from here; ``mission``: they are the stored mission, whose progress
        (current item, items reached) is reported."""
        try:
            # from where the current reference comes to rest: the switch is continuous
            start = self.flight.here(self._x).tolist()
            traj = mission_to_trajectory(items, self.cfg.home, start, self.cfg.limits, start_seq)
        except ValueError as exc:
            return c.Reply(c.Result.DENIED, f"Refused: {exc}"[:50])
        self.flight.start(traj, self._t)
        self.flight.mode = mode
        self._prev_tau = None
        self._current_seq = start_seq
        self._mission_traj = traj if mission and isinstance(traj, WaypointTrajectory) else None
        if mission:  # the trajectory the error windows measure (not a take-off or landing)
            self._primary = traj
        self._mission_done = False
        return c.Reply(c.Result.ACCEPTED)

    def _start_mission(self, cmd: c.StartMission) -> c.Reply:
        if not self.flight.armed:
            return c.Reply(c.Result.DENIED, "Mission start refused: disarmed")
        mission = self._mission()
        if not mission:
            return c.Reply(c.Result.DENIED, "Mission start refused: no mission")
        first = cmd.first_seq if 0 < cmd.first_seq < len(mission) else 0
        self._events.append(c.CurrentItem(first))
        reply = self._start_items(list(mission), Mode.AUTO, first, mission=True)
        return reply if reply.text else c.Reply(reply.result, "Mission started")

    def _select_mission(self, cmd: c.SelectMission) -> c.Reply:
        if self.flight.armed:
            return self._start_mission(c.StartMission())
        if not self._mission():
            return c.Reply(c.Result.DENIED, "Mission mode refused: no mission")
        self.mission_on_arm = True
        return c.Reply(c.Result.ACCEPTED, "Mission mode: starts when armed")

    def _local_item(self, command: int, z_up_m: float | None = None) -> MissionItem:
        """An item here (where the reference comes to rest) in MAV_FRAME_LOCAL_NED."""
        pos = self.flight.here(self._x)
        north, east, down = frames.nwu_to_ned((pos[0], pos[1], pos[2] if z_up_m is None else z_up_m))
        return MissionItem(0, ms.FRAME_LOCAL_NED, command, x=int(round(north * ms.LOCAL_E4)),
                           y=int(round(east * ms.LOCAL_E4)), z=down)  # fmt: skip

    def _takeoff(self, cmd: c.Takeoff) -> c.Reply:
        if not self.flight.armed:
            return c.Reply(c.Result.DENIED, "Takeoff refused: disarmed")
        alt = DEFAULT_TAKEOFF_ALT_M if cmd.alt_above_home_m is None else cmd.alt_above_home_m
        lo, hi = TAKEOFF_ALT_RANGE_M
        if not (math.isfinite(alt) and lo <= alt <= hi):
            return c.Reply(c.Result.DENIED, f"Takeoff refused: altitude {alt:.1f} m")
        reply = self._start_items([self._local_item(ms.CMD_TAKEOFF, alt)], Mode.TAKEOFF)
        return reply if reply.text else c.Reply(reply.result, f"Takeoff to {alt:.1f} m")

    def _land(self, cmd: c.Land) -> c.Reply:
        if not self.flight.armed:
            return c.Reply(c.Result.DENIED, "Land refused: disarmed")
        reply = self._start_items([self._local_item(ms.CMD_LAND, 0.0)], Mode.LAND)
        return reply if reply.text else c.Reply(reply.result, "Landing")

    def _rtl(self, cmd: c.ReturnToLaunch) -> c.Reply:
        if not self.flight.armed:
            return c.Reply(c.Result.DENIED, "RTL refused: disarmed")
        item = MissionItem(0, ms.FRAME_MISSION, ms.CMD_RTL)
        reply = self._start_items([item], Mode.RTL)
        return reply if reply.text else c.Reply(reply.result, "Returning to launch")

    def _hold(self, cmd: c.Hold) -> c.Reply:
        self.mission_on_arm = False
        self.flight.hold(self._x, self._t)
        return c.Reply(c.Result.ACCEPTED, "Hold")

    def _start_offboard(self, cmd: c.StartOffboard) -> c.Reply:
        ob = self._offboard
        if ob is None or self._t - ob.received_t_s > self.offboard_timeout_s:
            return c.Reply(c.Result.DENIED, "Offboard refused: no setpoint stream")
        self.mission_on_arm = False
        self.flight.mode = Mode.GUIDED
        return c.Reply(c.Result.ACCEPTED, "Offboard")

    def _setpoint(self, cmd: c.Setpoint) -> c.Reply:
        ref = np.asarray(cmd.ref_nwu, dtype=float)
        if ref.shape != (N_REF,) or np.all(np.isnan(ref[REF_POS])):
            # this vehicle follows positions; velocity-only setpoints are not flown
            return c.Reply(c.Result.DENIED)
        self._offboard = _Offboard(ref.copy(), self._t)
        return c.Reply(c.Result.ACCEPTED)

    def _fly_trajectory(self, cmd: c.FlyTrajectory) -> c.Reply:
        self.flight.start(cmd.trajectory, self._t)
        self._primary = cmd.trajectory
        return c.Reply(c.Result.ACCEPTED)

    _HANDLERS: dict[type, Callable[[FlightManager, c.Command], c.Reply]] = {
        c.Arm: _arm,  # type: ignore[dict-item]
        c.Disarm: _disarm,  # type: ignore[dict-item]
        c.StartMission: _start_mission,  # type: ignore[dict-item]
        c.SelectMission: _select_mission,  # type: ignore[dict-item]
        c.Takeoff: _takeoff,  # type: ignore[dict-item]
        c.Land: _land,  # type: ignore[dict-item]
        c.ReturnToLaunch: _rtl,  # type: ignore[dict-item]
        c.Hold: _hold,  # type: ignore[dict-item]
        c.StartOffboard: _start_offboard,  # type: ignore[dict-item]
        c.Setpoint: _setpoint,  # type: ignore[dict-item]
        c.FlyTrajectory: _fly_trajectory,  # type: ignore[dict-item]
    }

    def plant_link(self, lost: bool) -> None:
        """The plant went silent (``lost``) or spoke again: the operator is told."""
        self.plant_lost = lost
        if lost:
            self._say(c.Severity.WARNING, "Plant link lost: no control sent")
        else:
            self._say(c.Severity.INFO, "Plant link back")

    def plant_restarted(self, t_s: float, x: FloatArray) -> None:
        """A new plant session (its clock went back): whatever was flying is gone. The
        vehicle is disarmed, as after a reboot; the operator is told."""
        self._t, self._x = t_s, x
        was_armed = self.flight.armed
        self.flight.disarm(x, force=True)
        self.mission_on_arm = False
        self._mission_traj = None
        self._say(c.Severity.WARNING, "Plant restarted: disarmed" if was_armed else "Plant restarted")

    def resume_after_gap(self, gap_s: float, t_s: float) -> None:
        """The control loop did not run for ``gap_s`` (a stall of this process or of the
        plant link): the flight's clock is paused by the gap, so the reference continues
        from where it was instead of jumping ahead along the path."""
        f = self.flight
        f.t0_s += gap_s
        if self._offboard is not None:
            self._offboard.received_t_s += gap_s
        self._say(c.Severity.WARNING, f"Control resumed after a {gap_s:.1f} s gap"[:50])

    def navigation(self, t_s: float, x: FloatArray, gps_lost: bool, n_rejected: int, n_resets: int,
                   diverged: bool = False) -> None:  # fmt: skip
        """The estimator's health, before each tick when flying from sensors. GPS lost in
        flight: hold where the estimate is (it dead-reckons on the IMU), and land after
        ``gps_loss_land_after_s`` without a fix; the operator is told each step, and of
        rejected fixes (a glitch, a frozen or biased receiver) and estimator resets. A
        diverged navigation filter (its innovations out of their gates for its
        ``divergence_s``): land at once, said once; nothing better is known of where it is."""
        self._t, self._x = t_s, x
        if diverged and not self.nav_diverged:
            self.nav_diverged = True
            self._say(c.Severity.CRITICAL, "Navigation filter diverged: landing")
            if self.flight.armed and self.flight.mode is not Mode.LAND and not landed(x):
                self.mission_on_arm = False
                self._offboard = None
                self._land(c.Land())
        rej, res = self._nav_seen
        if n_resets > res:
            self._say(c.Severity.WARNING, "GPS jump: position estimate reset")
        elif n_rejected > rej and (n_rejected == 1 or n_rejected % 25 == 0):
            self._say(c.Severity.WARNING, f"GPS fix rejected ({n_rejected} so far)")
        self._nav_seen = (n_rejected, n_resets)
        f = self.flight
        if not gps_lost:
            if self.gps_lost_since is not None:
                self.gps_lost_since = None
                self._say(c.Severity.INFO, "GPS back")
            return
        if self.gps_lost_since is None:
            self.gps_lost_since = t_s
            if f.armed and f.mode is not Mode.LAND and not landed(x):
                self.mission_on_arm = False
                self._offboard = None
                f.hold(x, t_s)
                self._say(c.Severity.CRITICAL, "GPS lost: holding position")
            else:
                self._say(c.Severity.WARNING, "GPS lost")
            return
        if f.armed and f.mode is Mode.HOLD and t_s - self.gps_lost_since >= self.cfg.gps_loss_land_after_s:
            self._t, self._x = t_s, x
            self._land(c.Land())
            self._say(c.Severity.CRITICAL, f"GPS lost {self.cfg.gps_loss_land_after_s:.0f} s: landing")

    # -- the runner's ticks ------------------------------------------------------------
    def pre_tick(self, t_s: float, x: FloatArray) -> None:
        """Before the control law: the offboard failsafe (no setpoint -> hold)."""
        self._t, self._x = t_s, x
        f = self.flight
        if f.mode is not Mode.GUIDED:
            return
        ob = self._offboard
        if ob is None or t_s - ob.received_t_s > self.offboard_timeout_s:
            f.hold(x, t_s)
            self._offboard = None
            self._say(c.Severity.WARNING, "Offboard setpoints lost: holding position")
            return
        f.guided_ref = ob.ref_nwu

    def post_tick(self, t_s: float, x: FloatArray) -> None:
        """After the control law: mission progress, and disarm once a landing is done."""
        self._t, self._x = t_s, x
        self._mission_progress(t_s)
        f = self.flight
        if f.armed and f.mode is Mode.LAND and f.trajectory is not None:
            tau = t_s - f.t0_s
            low = bool(x[Z_U] < LANDED_ALT_M)
            self._low_since = (self._low_since if self._low_since is not None else t_s) if low else None
            on_ground_s = 0.0 if self._low_since is None else t_s - self._low_since
            # landed: at rest on the ground; or, the descent over, on the ground for a while
            # whatever the horizontal velocity: without a GPS the estimate's velocity can run
            # away at touchdown (seen: 5 m/s^2 of dead reckoning), and a vehicle that waits for
            # it to settle flies after it (it took off again and flew 9 m)
            if tau > f.trajectory.duration_s and (landed(x) or on_ground_s >= TOUCHDOWN_S):
                f.disarm(x, force=True)  # (its own check is landed(x), which is what failed)
                self._low_since = None
                self._say(c.Severity.INFO, "Landed: disarmed")

    def _mission_progress(self, t_s: float) -> None:
        """Report the stored mission's progress while its trajectory is the one flown, up to
        and including the tick it ends on (the flight has switched to HOLD by then)."""
        traj = self._mission_traj
        f = self.flight
        if traj is None or f.trajectory is not traj:
            return
        tau = t_s - f.t0_s
        prev = self._prev_tau if self._prev_tau is not None else -1e-9
        self._prev_tau = tau
        for seq in traj.reached_between(prev, tau):
            self._events.append(c.ItemReached(seq))
        active = traj.active_seq(tau)
        if active is not None and active != self._current_seq:
            self._current_seq = active
            self._events.append(c.CurrentItem(active))
        if tau > traj.duration_s:
            self._mission_traj = None  # done: every item was reached by now
            self._mission_done = True
