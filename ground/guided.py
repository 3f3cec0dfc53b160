"""``heli-ground fly --guided``: a timed trajectory streamed to a vehicle as setpoints.

Where ``heli-ground fly`` uploads a trajectory as a mission for this bench's autopilot to
follow, ``--guided`` keeps the trajectory on the ground and streams it, as a companion
computer or an offboard program does: SET_POSITION_TARGET_LOCAL_NED with position, velocity,
acceleration and a constant yaw (MAV_FRAME_LOCAL_NED, type_mask 0x800: only the yaw rate
ignored), at ``rate_hz`` of the *vehicle's* clock (time_boot_ms of its LOCAL_POSITION_NED),
so a lockstep vehicle running faster or slower than the wall clock flies the same
trajectory. Any vehicle that takes such setpoints flies it:

* **ArduPilot** (HEARTBEAT autopilot MAV_AUTOPILOT_ARDUPILOTMEGA): GUIDED mode (custom mode 4);
  arming is retried while the firmware's pre-arm checks refuse (its EKF aligns first); a
  helicopter's motor interlock is switched on with MAV_CMD_DO_AUX_FUNCTION (218, function 32,
  high: the ground station's switch, which unlike an RC override does not lapse after 3 s),
  then MAV_CMD_NAV_TAKEOFF is retried until the rotor has run up and it is accepted; it
  climbs to the trajectory's start height before the first setpoint (a setpoint during
  the take-off would end it). The end is mode LAND (9); the firmware disarms on the ground.
* **This bench's autopilot**: OFFBOARD mode (the stream is started first, as PX4 requires),
  armed; the end is MAV_CMD_NAV_LAND and a disarm on the ground.

The flight: go to the trajectory's start and stay within ``settle_m`` for ``settle_s``;
then t = 0 is that moment of the vehicle's clock, and the trajectory is streamed to its
end; then the end point is held for ``hold_s`` and the vehicle lands. A trajectory that
starts on the ground (the paper's spiral starts at home) is lifted: every setpoint is
``lift_m`` higher (default: enough for the lowest point to be ``min_height_m`` above
home), which changes no tracking figure on a plant without ground effect.

A vehicle simulated faster than the wall clock (ArduPilot's ``--speedup``) does not wait for
a ground station that lost the CPU for a moment; with ``pace_port`` this one joins the
lockstep: after each batch received it tells the plant's pacer (:mod:`heli_plant.pacer`) how
far the physics may run (``pace_horizon_s`` past the newest vehicle time heard).

The tracking is measured from the vehicle's own LOCAL_POSITION_NED (its estimate; the truth
is the simulator's, plant.csv): RMS and maximum over a window of trajectory time.
"""

from __future__ import annotations

import contextlib
import csv
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.sampled import TimedSamples
from ground.client import PX4_MAIN_OFFBOARD, CommandRefusedError, GroundClient, GroundError, LinkTimeoutError
from heli_common.frames import flip_rows, nwu_to_ned
from heli_common.wire.ardupilot_json import encode_pace
from heli_common.wire.mavlink.udp import LOOPBACK, Message, mavlink2

m2 = mavlink2
ARDUPILOT_GUIDED, ARDUPILOT_LAND = 4, 9  # ArduCopter custom modes (Copter's mode numbers)
ON_GROUND_M = 0.5  # armed, but less than this above the origin: ArduPilot must still take off
# MAV_CMD_DO_AUX_FUNCTION (ardupilotmega.xml; not in the development dialect this bench uses)
MAV_CMD_DO_AUX_FUNCTION = 218
AUX_MOTOR_INTERLOCK = 32  # RC_Channel::AUX_FUNC::MOTOR_INTERLOCK
AUX_LOW, AUX_HIGH = 0, 2
TYPE_MASK = m2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE  # position, velocity, acceleration, yaw
# the streams asked of ArduPilot [Hz of vehicle time]: positions (LOCAL_POSITION_NED), the
# attitude (ATTITUDE: the heading held), the status (SYS_STATUS, EXTENDED_SYS_STATE)
STREAMS_HZ = ((m2.MAV_DATA_STREAM_POSITION, 25), (m2.MAV_DATA_STREAM_EXTRA1, 4),
              (m2.MAV_DATA_STREAM_EXTENDED_STATUS, 2))  # fmt: skip
PAPER_WINDOW_START_S = 45.0  # the paper's convention: tracking after the transient


@dataclass(frozen=True)
class GuidedOptions:
    rate_hz: float = 20.0  # setpoints per second of vehicle time
    lift_m: float | None = None  # None: min_height_m above home at the trajectory's lowest
    min_height_m: float = 3.0
    settle_m: float = 0.3
    settle_s: float = 3.0  # vehicle time within settle_m of the start before t = 0
    start_timeout_s: float = 60.0  # vehicle time allowed to reach the start
    hold_s: float = 2.0  # the end point held before landing
    window_s: tuple[float, float] | None = None  # tracking window; None: [45, end] or all
    wall_factor: float = 10.0  # wall-clock limit of each phase = vehicle time x this + 30 s
    land: bool = True
    # the plant's pacer (heli_plant.pacer, UDP 9008 + 10 N under heli-sitl up --firmware
    # ardupilot): the physics waits for this ground station; None: it runs free
    pace_port: int | None = None
    # how far the physics may run ahead of the newest position heard (more than its 0.04 s
    # period: 0.1 s made the lockstep wait on the ground station's every round trip, 3x
    # slower on a loaded machine; 0.25 s of stale target is 0.2 m on the paper's circle)
    pace_horizon_s: float = 0.25


@dataclass(frozen=True)
class TrackingSummary:
    """Position error of the vehicle's estimate against the streamed trajectory."""

    window_s: tuple[float, float]
    rms_m: float
    max_m: float
    samples: int
    t0_vehicle_s: float  # the vehicle's clock at trajectory time 0
    lift_m: float
    # the longest stretch of vehicle time without a setpoint while following (NaN: not
    # known); ArduPilot stops following after GUID_TIMEOUT (3 s) without one
    max_setpoint_gap_s: float = math.nan

    def line(self) -> str:
        a, b = self.window_s
        gap = "" if math.isnan(self.max_setpoint_gap_s) else (
            f"; setpoints at most {self.max_setpoint_gap_s:.2f} s of vehicle time apart")
        return (f"tracking over [{a:g}, {b:g}] s: RMS {self.rms_m:.3f} m, "
                f"max {self.max_m:.3f} m ({self.samples} samples){gap}")  # fmt: skip


def lift_for(traj: Trajectory, min_height_m: float) -> float:
    """The height to add so the trajectory's lowest point is ``min_height_m`` above home."""
    t = np.linspace(0.0, traj.duration_s, max(2, int(traj.duration_s * 10.0) + 1))
    lowest = float(np.min(traj.sample(t)[:, 2]))  # NWU z: up
    return max(0.0, min_height_m - lowest)


def default_window(duration_s: float) -> tuple[float, float]:
    if duration_s > PAPER_WINDOW_START_S:
        return (PAPER_WINDOW_START_S, duration_s)
    return (0.0, duration_s)


Vec3 = tuple[float, float, float]
Target = tuple[Vec3, Vec3, Vec3, float]  # NED position, velocity, acceleration; yaw [rad]


class GuidedFlight:
    """One guided flight of ``traj`` on the vehicle behind ``gc`` (already connected)."""

    def __init__(
        self,
        gc: GroundClient,
        traj: Trajectory,
        opts: GuidedOptions = GuidedOptions(),
        *,
        track_csv: Path | None = None,
        say: Callable[[str], None] = print,
    ) -> None:
        self.gc = gc
        self.traj = traj
        self.opts = opts
        self.say = say
        self.track_csv = track_csv
        self.lift_m = lift_for(traj, opts.min_height_m) if opts.lift_m is None else opts.lift_m
        hb = gc.latest.get("HEARTBEAT")
        self.ardupilot = hb is not None and hb.autopilot == m2.MAV_AUTOPILOT_ARDUPILOTMEGA
        self._target: Callable[[float], Target] | None = None
        self._yaw_ned_rad = 0.0
        self._next_send_s = -math.inf
        self._next_keepalive = 0.0
        self.t_vehicle_s: float | None = None  # the newest vehicle time heard
        self._last_send_s: float | None = None
        self.max_gap_s = 0.0  # the longest stretch of vehicle time between two setpoints
        self._pace: socket.socket | None = None
        if opts.pace_port is not None:
            self._pace = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.pos_ned_m: tuple[float, float, float] | None = None

    # ------------------------------------------------------------------ the stream

    def _row(self, t_traj_s: float) -> Target:
        r = self.traj.evaluate_row(min(max(t_traj_s, 0.0), self.traj.duration_s))
        if t_traj_s > self.traj.duration_s or t_traj_s < 0.0:
            r = np.concatenate([r[:3], np.zeros(6)])  # before the start / after the end: hold
        r = np.nan_to_num(r)  # an unknown derivative is sent as zero (no feed-forward)
        pos = nwu_to_ned((r[0], r[1], r[2] + self.lift_m))
        yaw = self._yaw_ned_rad
        if isinstance(self.traj, TimedSamples) and self.traj.has_yaw:  # the file's yaw column
            yaw = -float(self.traj.yaw_nwu_rad(min(max(t_traj_s, 0.0), self.traj.duration_s))[0])
        return pos, nwu_to_ned(r[3:6]), nwu_to_ned(r[6:9]), yaw

    def _setpoint(self, t_vehicle_s: float, tgt: Target) -> Message:
        (n, e, d), (vn, ve, vd), (an, ae, ad), yaw = tgt
        msg: Message = m2.MAVLink_set_position_target_local_ned_message(
            int(t_vehicle_s * 1e3) & 0xFFFFFFFF, self.gc.target_system, self.gc.target_component,
            m2.MAV_FRAME_LOCAL_NED, TYPE_MASK, n, e, d, vn, ve, vd, an, ae, ad, yaw, 0.0,
        )  # fmt: skip
        return msg

    def _on_message(self, m: Message) -> None:
        if not self.gc.from_vehicle(m) or m.get_type() != "LOCAL_POSITION_NED":
            return
        t = m.time_boot_ms / 1e3
        if self.t_vehicle_s is None or t >= self.t_vehicle_s:
            self.t_vehicle_s = t
            self.pos_ned_m = (float(m.x), float(m.y), float(m.z))

    def _pace_to(self, until_s: float) -> None:
        if self._pace is not None and self.opts.pace_port is not None:
            with contextlib.suppress(OSError):  # no plant listening: nothing waits
                self._pace.sendto(encode_pace(until_s), (LOOPBACK, self.opts.pace_port))

    def _after_batch(self) -> None:
        if self.t_vehicle_s is not None:
            self._pace_to(self.t_vehicle_s + self.opts.pace_horizon_s)
        self._maybe_send()

    def _maybe_send(self) -> None:
        """Once per received batch: the setpoint for the NEWEST vehicle time heard (a batch
        queued while this process waited holds stale times: answering each would stream a
        target seconds behind a vehicle running faster than the wall clock), when due; and
        every 0.5 s of wall time anyway, so a paused vehicle still hears a live stream."""
        t = self.t_vehicle_s
        if self._target is None or t is None:
            return
        now = time.monotonic()
        if t < self._next_send_s and now < self._next_keepalive:
            return
        if self._last_send_s is not None:
            self.max_gap_s = max(self.max_gap_s, t - self._last_send_s)
        self.gc.send(self._setpoint(t, self._target(t)))
        self._last_send_s = t
        self._next_send_s = t + 0.75 / self.opts.rate_hz  # (positions come at their own rate)
        self._next_keepalive = now + 0.5

    def _pump(self, until: Callable[[], bool], vehicle_s: float, what: str) -> None:
        """Receive (and stream) until ``until()``; LinkTimeoutError after ``vehicle_s`` of
        vehicle time or its wall-clock allowance."""
        t_start = self.t_vehicle_s
        wall_end = time.monotonic() + vehicle_s * self.opts.wall_factor + 30.0
        late = f"{what}: not done in {vehicle_s:g} s of vehicle time"
        while not until():
            if time.monotonic() > wall_end:
                raise LinkTimeoutError(late + " (its wall-clock limit)")
            t = self.t_vehicle_s
            if t_start is not None and t is not None and t - t_start > vehicle_s:
                raise LinkTimeoutError(late)
            self.gc.poll(0.05)

    def _retry(self, what: str, action: Callable[[], None], vehicle_s: float) -> None:
        """``action`` until the vehicle accepts it (a refusal is retried once a second of
        wall time: pre-arm checks and the rotor run-up clear by themselves)."""
        last: GroundError | None = None

        def accepted() -> bool:
            nonlocal last
            try:
                action()
                return True
            except CommandRefusedError as exc:
                last = exc
                self.gc.spin(1.0)
                return False

        try:
            self._pump(accepted, vehicle_s, what)
        except LinkTimeoutError as exc:
            raise GroundError(f"{exc}; last refusal: {last}") from None

    # ------------------------------------------------------------------ the flight

    def _start_point(self) -> tuple[float, float, float]:
        return self._row(0.0)[0]

    def _distance_to(self, p: tuple[float, float, float]) -> float:
        return math.inf if self.pos_ned_m is None else math.dist(self.pos_ned_m, p)

    def _distance_up(self, p: Vec3) -> float:
        """How far below ``p`` the vehicle is [m] (inf before its first position)."""
        return math.inf if self.pos_ned_m is None else self.pos_ned_m[2] - p[2]

    def _hold(self, t: float) -> Target:
        return self._row(-1.0)  # before the start: the start point, at rest

    def _in_guided(self) -> None:
        """GUIDED, asked for again whenever the vehicle's heartbeat shows another mode: the
        firmware reads its flight-mode switch when RC input first appears, which can put it
        back in STABILIZE after a ground station set GUIDED (seen: it then armed in STABILIZE
        and refused the take-off)."""
        hb = self.gc.latest.get("HEARTBEAT")
        if hb is None or not self.gc.from_vehicle(hb) or int(hb.custom_mode) != ARDUPILOT_GUIDED:
            self.gc.set_mode(ARDUPILOT_GUIDED)

    def _take_off(self) -> None:
        """GUIDED, armed (unless it is already), the interlock on, take-off to the start's height."""
        gc, start = self.gc, self._start_point()
        self._retry("GUIDED mode", self._in_guided, 60.0)
        if not gc.armed():
            gc.command_ok(MAV_CMD_DO_AUX_FUNCTION, [AUX_MOTOR_INTERLOCK, AUX_LOW])  # it arms with it low

            def arm() -> None:
                self._in_guided()
                gc.arm()

            self._retry("arming", arm, 120.0)
            self.say("armed (GUIDED); motor interlock on, rotor run-up")
        gc.command_ok(MAV_CMD_DO_AUX_FUNCTION, [AUX_MOTOR_INTERLOCK, AUX_HIGH])
        height, nan = -start[2], math.nan
        takeoff = [0.0, 0.0, 0.0, nan, nan, nan, height]

        def take_off() -> None:
            self._in_guided()
            gc.command_ok(m2.MAV_CMD_NAV_TAKEOFF, takeoff)

        self._retry("take-off", take_off, 60.0)
        self.say(f"taking off to {height:.1f} m")
        self._pump(lambda: self._distance_up(start) < 0.5, 60.0, "take-off")

    def _offboard(self) -> None:
        self._target = self._hold
        self.gc.spin(0.5)  # a live stream before the mode switch
        self.gc.set_mode(PX4_MAIN_OFFBOARD)
        self.gc.arm()
        self.say("armed (OFFBOARD)")

    def _settle(self) -> None:
        start = self._start_point()
        since: list[float] = []

        def settled() -> bool:
            if self._distance_to(start) > self.opts.settle_m or self.t_vehicle_s is None:
                since.clear()
                return False
            since.append(self.t_vehicle_s)
            return since[-1] - since[0] >= self.opts.settle_s

        self._pump(settled, self.opts.start_timeout_s, f"reaching the start within {self.opts.settle_m:g} m")

    def _follow(self, out: TextIO | None) -> TrackingSummary:
        assert self.t_vehicle_s is not None
        t0 = self.t_vehicle_s
        self._target = lambda t: self._row(t - t0)
        self.max_gap_s = 0.0
        rows: list[tuple[float, float]] = []  # (t_traj, error)
        writer = csv.writer(out) if out is not None else None
        if writer is not None:
            writer.writerow(["t_vehicle_s", "t_traj_s", "target_n_m", "target_e_m", "target_d_m",
                             "est_n_m", "est_e_m", "est_d_m"])  # fmt: skip

        def record(m: Message) -> None:
            if not self.gc.from_vehicle(m) or m.get_type() != "LOCAL_POSITION_NED":
                return
            tv = m.time_boot_ms / 1e3
            tgt = self._row(tv - t0)[0]
            est = (float(m.x), float(m.y), float(m.z))
            rows.append((tv - t0, math.dist(tgt, est)))
            if writer is not None:
                writer.writerow([f"{tv:.3f}", f"{tv - t0:.3f}", *(f"{v:.4f}" for v in (*tgt, *est))])

        self.gc.listeners.append(record)
        try:
            end = self.traj.duration_s
            self._pump(lambda: self.t_vehicle_s is not None and self.t_vehicle_s - t0 >= end, end + 10.0,
                       "following the trajectory")  # fmt: skip
        finally:
            self.gc.listeners.remove(record)
        w = self.opts.window_s or default_window(self.traj.duration_s)
        err = np.array([e for t, e in rows if w[0] <= t <= w[1]])
        if err.size == 0:
            raise GroundError(f"no LOCAL_POSITION_NED from the vehicle in the window [{w[0]:g}, {w[1]:g}] s")
        return TrackingSummary(w, float(np.sqrt(np.mean(err**2))), float(err.max()), int(err.size), t0,
                               self.lift_m, self.max_gap_s)  # fmt: skip

    def _land(self) -> None:
        gc = self.gc
        self._target = lambda t: self._row(self.traj.duration_s + 1.0)  # after the end: at rest
        t_hold = self.t_vehicle_s or 0.0
        self._pump(lambda: (self.t_vehicle_s or 0.0) - t_hold >= self.opts.hold_s, self.opts.hold_s + 5.0,
                   "holding the end point")  # fmt: skip
        self._target = None
        if self.ardupilot:
            gc.set_mode(ARDUPILOT_LAND)
        else:
            gc.land()
        self.say("landing")
        self._pump(lambda: gc.armed() is False, 120.0, "landing and disarming")

    def run(self) -> TrackingSummary:
        gc = self.gc
        gc.listeners.append(self._on_message)
        gc.after_poll.append(self._after_batch)
        try:
            # ArduPilot streams nothing on a link until asked (this bench's vehicle ignores the
            # request). Only what the stream needs: a vehicle running 10x faster than the wall
            # clock multiplies every rate, and a flood to parse would delay the setpoints.
            for stream, hz in STREAMS_HZ:
                gc.send(m2.MAVLink_request_data_stream_message(gc.target_system, gc.target_component,
                                                               stream, hz, 1))  # fmt: skip
            self._pump(lambda: self.t_vehicle_s is not None, 30.0, "waiting for LOCAL_POSITION_NED")
            att = gc.latest.get("ATTITUDE")
            self._yaw_ned_rad = float(att.yaw) if att is not None else 0.0  # hold the heading
            lifted = f", flown {self.lift_m:.1f} m higher" if self.lift_m else ""
            self.say(f"trajectory of {self.traj.duration_s:.1f} s{lifted}; yaw held at "
                     f"{math.degrees(self._yaw_ned_rad):.1f} deg")  # fmt: skip
            on_ground = self.pos_ned_m is not None and self.pos_ned_m[2] > -ON_GROUND_M
            if gc.armed() and not (self.ardupilot and on_ground):  # already flying: to the start
                self._target = self._hold
                gc.set_mode(ARDUPILOT_GUIDED if self.ardupilot else PX4_MAIN_OFFBOARD)
                self.say("already armed: on to the start")
            elif self.ardupilot:
                self._take_off()
                self._target = self._hold
            else:
                self._offboard()
            self._settle()
            self.say("at the start: t = 0")
            if self.track_csv is not None:
                with self.track_csv.open("w", newline="") as out:
                    summary = self._follow(out)
            else:
                summary = self._follow(None)
            self.say(f"{summary.line()}; of the vehicle's own estimate")
            if self.opts.land:
                self._land()
                self.say("landed and disarmed")
            return summary
        finally:
            gc.listeners.remove(self._on_message)
            gc.after_poll.remove(self._after_batch)
            self._pace_to(math.inf)  # the physics runs free again
            if self._pace is not None:
                self._pace.close()


def truth_tracking(
    track_csv: Path, plant_csv: Path, window_s: tuple[float, float], lift_m: float = 0.0
) -> TrackingSummary:
    """The same figures from the simulator's truth: plant.csv (``t_s`` on the vehicle's clock,
    as the lockstep backends keep it; ``x_m, y_m, z_m`` NWU about home) against the targets streamed
    (``track_csv`` of :class:`GuidedFlight`), interpolated to the plant's rows."""
    from ground.plots import read_csv_columns

    tr, pl = read_csv_columns(track_csv), read_csv_columns(plant_csv)
    if tr["t_vehicle_s"].size < 2:
        raise GroundError(f"{track_csv}: fewer than two rows")
    t0 = float(tr["t_vehicle_s"][0] - tr["t_traj_s"][0])
    m = (pl["t_s"] - t0 >= window_s[0]) & (pl["t_s"] - t0 <= window_s[1])
    if not m.any():
        raise GroundError(f"{plant_csv}: no row in the window [{window_s[0]:g}, {window_s[1]:g}] s")
    t = pl["t_s"][m]
    target_ned = np.column_stack([np.interp(t, tr["t_vehicle_s"], tr[f"target_{k}_m"]) for k in "ned"])
    truth_ned = flip_rows(np.column_stack([pl["x_m"][m], pl["y_m"][m], pl["z_m"][m]]))
    err = np.linalg.norm(truth_ned - target_ned, axis=1)
    rms = float(np.sqrt(np.mean(err**2)))
    return TrackingSummary(window_s, rms, float(err.max()), int(err.size), t0, lift_m)
