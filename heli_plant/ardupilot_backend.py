"""The plant as ArduPilot's external physics (the JSON SITL backend, docs/ardupilot-json.md).

ArduPilot's SITL (``--model JSON``) sends a servo frame and waits for the physics' answer;
each NEW frame is one step of ``1 / frame_rate`` s. Here a frame's PWMs go through the
swashplate (:class:`heli_common.vehicle.swashplate.Swashplate`: SERVO1-3 the plate, SERVO4 the tail,
channel 8 HeliRSC) to blade pitches, the plant steps with them held, and the answer is the
truth after the step: body rates and specific force (FRD), position and velocity (NED about
home) and the attitude quaternion. The firmware builds its own GPS, baro and compass from
these.

The rotor: ArduPilot's RSC output on channel 8 goes to the rotor through the head's
:class:`~heli_common.vehicle.swashplate.RotorSpeedInput` (an external governor). On Gavrilets' plant
it is the governor's set point: with the interlock off the engine stops and the rotor winds
down (it starts at rest when the plant starts on the ground), above it the governor follows
the firmware's ramp to the design speed, and the blades make thrust only as fast as the rotor
turns. On the paper plant, whose model has no rotor speed, the rotor turns at its constant
design speed whenever the interlock is on; with it off the blades are held at zero pitch, so
the rotor makes no thrust (``thrust_coeff`` is odd in the pitch). plant.csv records the rotor
speed on both.

With a :class:`~heli_plant.ardupilot_can.ArduPilotCanServos` (``--servo-link can``) the servos of
channels 1-4 and 8 come from the firmware's DroneCAN ArrayCommand instead, read before each
step (in flight the lockstep is slowed while the newest command is stale: ``CAN_MAX_STALE_S``);
the frame's PWMs are then only compared with them, frame by frame (:class:`CrossCheck`, in
the stats).

The clock is the firmware's: this loop only answers; but a ground station streaming on that
clock may join the lockstep through :mod:`heli_plant.pacer` (the physics waits for it).
A repeated frame is answered again by
:class:`~heli_plant.ardupilot_link.ArduPilotJsonLink` without a step; a frame count that
goes back (a new firmware process) restarts the plant from its initial state.
"""

from __future__ import annotations

import csv
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from heli_common.state import N_PITCH, PITCH_LABELS, STATE_NAMES, FloatArray
from heli_common.vehicle.swashplate import Swashplate
from heli_common.wire.ardupilot_json import json_state_from_plant
from heli_plant.ardupilot_can import CHANNELS as CAN_CHANNELS
from heli_plant.ardupilot_can import ArduPilotCanServos
from heli_plant.ardupilot_link import ArduPilotJsonLink
from heli_plant.model import Plant
from heli_plant.pacer import Pacer
from heli_plant.sensors.model import specific_force_over_step

RECORD_PERIOD_S = 0.01  # plant.csv: one row per 10 ms of physics time (the bench's 100 Hz)
CHANNEL_RSC = 8
N_SWASH_CHANNELS = 4  # SERVO1-3 the plate, SERVO4 the tail
# frames whose readings are remembered: in flight the servos dither over a few microseconds,
# so the same PWMs recur; emptied when full, which bounds the memory
READING_CACHE_SIZE = 1024
# --servo-link can: a bus PWM further than this from the JSON frame's counts as a disagreement
# (the firmware's pulse is an integer and the float16 command resolves 0.25 us: an equal pulse
# comes back equal); the larger threshold separates a lagging command from a wrong one
CROSSCHECK_TOLERANCE_US = 1
CROSSCHECK_LARGE_US = 25
# --servo-link can, in flight (the rotor's interlock on): while the newest bus command is more
# than CAN_MAX_STALE_S of physics time old, each frame waits up to CAN_WAIT_S of wall time for
# the next before it steps. The firmware asks for 200 Hz (CAN_D1_UC_SRV_RT, 5 ms) but sends
# from its DroneCAN thread, which needs the CPU, and physics time to pass (its
# CanardInterface::process(1) runs until 1 ms of the SITL clock has), so blocking until a
# command comes would deadlock: the lockstep is slowed (one frame per CAN_WAIT_S at most), not
# stopped. Unpaced, at --speedup 10 on 2 loaded cores, the commands came 75 Hz of physics time
# on average with gaps of up to 0.65 s, and one set the rotor plant's hover swinging.
CAN_MAX_STALE_S = 0.02
CAN_WAIT_S = 0.002


@dataclass
class CrossCheck:
    """--servo-link can: the bus's PWMs (what the plant flies) against the JSON frame's (what
    the firmware says it output at the same frame), counted per frame."""

    frames: int = 0  # frames with a bus command held
    frames_before_command: int = 0  # frames before the first bus command (servos unpowered)
    disagree_frames: int = 0  # frames where any channel differed by more than the tolerance
    disagree_large_frames: int = 0  # ... by more than CROSSCHECK_LARGE_US
    disagree_by_channel: dict[int, int] = field(default_factory=lambda: dict.fromkeys(CAN_CHANNELS, 0))
    max_abs_diff_us: dict[int, int] = field(default_factory=lambda: dict.fromkeys(CAN_CHANNELS, 0))
    silent_frames: int = 0  # frames stepped while the bus was silent (the last command held)
    rotor_on_s: float = 0.0  # physics time with the rotor's interlock on (in flight) ...
    rotor_on_commands: int = 0  # ... and the bus commands applied in it
    rotor_on_max_stale_s: float = 0.0  # the oldest the held command was at a step, rotor on


@dataclass
class BackendStats:
    """What the backend did: frames stepped, servo readings refused or clipped (with the
    rotor engaged), the resets, the physics time reached, and the link's own counters at the end."""

    frames: int = 0
    refused_pwm: int = 0
    saturated: int = 0
    resets: int = 0
    interlock_changes: int = 0
    t_s: float = 0.0
    link: dict[str, object] = field(default_factory=dict)
    crosscheck: CrossCheck | None = None  # --servo-link can only
    can: dict[str, object] = field(default_factory=dict)  # the bus reader's counts at the end


class ArduPilotBackend:
    """Answers ArduPilot's servo frames with the plant's state (one step per new frame).

    ``make_plant`` builds the plant at its initial state (called again on a firmware reset);
    ``record`` (optional) receives ``plant.csv`` rows: time, the 12 states, the held
    pitches and the interlock."""

    def __init__(
        self,
        make_plant: Callable[[], Plant],
        swash: Swashplate,
        link: ArduPilotJsonLink,
        record: IO[str] | None = None,
        pacer: Pacer | None = None,
        can: ArduPilotCanServos | None = None,
        can_max_stale_s: float | None = CAN_MAX_STALE_S,
    ) -> None:
        self._make_plant = make_plant
        self.plant: Plant = make_plant()
        self.swash = swash
        self.link = link
        self.pacer = pacer  # a ground station in the lockstep (heli_plant.pacer), if any
        self.stats = BackendStats()
        # --servo-link can: the servos come from the bus, the JSON frame's PWMs are only checked
        self.can = can
        self.can_max_stale_s = can_max_stale_s  # None: never wait for the bus
        self._applied_before = 0
        self._last_dt_s = 0.0
        if can is not None:
            self.stats.crosscheck = CrossCheck()
            # before the first command the servos are unpowered: at trim, the rotor's at its minimum
            self._unpowered = {ch: round(r.min_us if ch == CHANNEL_RSC else r.trim_us)
                               for ch, r in can.ranges.items() if ch in CAN_CHANNELS}  # fmt: skip
        self.t_s = 0.0  # the physics time the firmware was last told
        self._interlock = False
        self._writer = None if record is None else csv.writer(record)
        if self._writer is not None:
            # the bench's one schema (run.csv, the API's tables): SI units last in each name
            self._writer.writerow(["t_s", *STATE_NAMES, *PITCH_LABELS, "interlock", "rotor_rad_s"])
        self._next_record_s = 0.0
        # (pitches, refused, saturated, interlock, speed fraction) by a frame's channels 1-4 and 8
        self._readings: dict[tuple[int, ...], tuple[FloatArray, int, int, bool, float]] = {}

    def _reset(self) -> None:
        self.plant = self._make_plant()
        self.t_s = 0.0
        self._next_record_s = 0.0
        self.stats.resets += 1

    def pitches_for(self, pwm_us: tuple[int, ...]) -> FloatArray:
        """The blade pitches a frame's PWMs set (zero while the rotor's interlock is off); the
        rotor plant's governor takes its set point from channel 8."""
        key = (*pwm_us[:N_SWASH_CHANNELS], pwm_us[CHANNEL_RSC - 1])
        known = self._readings.get(key)
        if known is None:  # the firmware's outputs change at its 400 Hz loop, frames come at
            # 1200 Hz: two frames in three repeat the last PWMs, and in flight they recur
            reading = self.swash.pitches_from_pwm(np.asarray(pwm_us[:N_SWASH_CHANNELS], dtype=float))
            speed, interlock, rsc_refused = self.swash.rsc.speed_fraction(float(pwm_us[CHANNEL_RSC - 1]))
            pitches = reading.as_array() if interlock else np.zeros(N_PITCH)
            if len(self._readings) >= READING_CACHE_SIZE:
                self._readings.clear()
            known = self._readings[key] = (pitches, reading.refused + rsc_refused, reading.saturated,
                                           interlock, speed)  # fmt: skip
        pitches, refused, saturated, interlock, speed = known
        self.plant.set_rotor_speed_command(speed * self.plant.rotor_design_speed_rad_s)
        self.stats.refused_pwm += refused
        if interlock:  # disarmed, the firmware parks the collective 1 us below the head's stop
            self.stats.saturated += saturated
        if interlock != self._interlock:
            self.stats.interlock_changes += 1
            self._interlock = interlock
        return pitches

    def servo_pwm(self, frame_pwm_us: tuple[int, ...]) -> tuple[int, ...]:
        """The PWMs the plant's servos fly: the frame's, or (--servo-link can) the bus's for
        the channels it carries, the frame's then only checked against them."""
        if self.can is None:
            return frame_pwm_us
        can = self.can
        bus = can.poll(self.t_s)
        last = can.stats.last_command_s
        # paced only while the rotor is engaged (flying): on the ground, disarmed, the firmware's
        # start-up (EKF, arming) runs at the pace it has over JSON
        if bus is not None and last is not None and self.can_max_stale_s is not None and self._interlock:
            stale = self.t_s - last
            if self.can_max_stale_s < stale <= can.timeout_s:  # past the timeout: a silent bus, step on
                can.wait_for_command(self.t_s, CAN_WAIT_S)
                bus = can.pwm_us()
        cc = self.stats.crosscheck
        assert cc is not None
        out = list(frame_pwm_us)
        if bus is None:
            cc.frames_before_command += 1
            for ch, v in self._unpowered.items():
                out[ch - 1] = v
            return tuple(out)
        cc.frames += 1
        cc.silent_frames += can.silent(self.t_s)
        applied = can.stats.counts["commands_applied"]
        if self._interlock:
            cc.rotor_on_s += self._last_dt_s
            cc.rotor_on_commands += applied - self._applied_before
            held_since = can.stats.last_command_s
            if held_since is not None:
                cc.rotor_on_max_stale_s = max(cc.rotor_on_max_stale_s, self.t_s - held_since)
        self._applied_before = applied
        worst = 0
        for ch, v in bus.items():
            diff = abs(v - frame_pwm_us[ch - 1])
            if diff > CROSSCHECK_TOLERANCE_US:
                cc.disagree_by_channel[ch] += 1
            if diff > cc.max_abs_diff_us[ch]:
                cc.max_abs_diff_us[ch] = diff
            worst = max(worst, diff)
            out[ch - 1] = v
        cc.disagree_frames += worst > CROSSCHECK_TOLERANCE_US
        cc.disagree_large_frames += worst > CROSSCHECK_LARGE_US
        return tuple(out)

    def step(self, pwm_us: tuple[int, ...], dt_s: float) -> bytes:
        """One frame: hold the pitches, step ``dt_s``, return the answer."""
        p = self.plant
        self._last_dt_s = dt_s
        p.set_pitches(self.pitches_for(self.servo_pwm(pwm_us)))
        x0 = p.x.copy()
        x1 = p.step(dt_s)
        f = specific_force_over_step(x0, x1, dt_s, p.constants.gravity_m_s2)
        self.stats.frames += 1
        # the firmware's clock is the sum of the frame periods; the plant keeps its own on the
        # sim link's microsecond grid (1/1200 s is not on it: 0.04 % slow, for the world's timing)
        self.t_s += dt_s
        self.stats.t_s = self.t_s
        if self._writer is not None and self.t_s >= self._next_record_s - 1e-9:
            self._writer.writerow([f"{self.t_s:.6f}", *(f"{v:.6g}" for v in x1),
                                   *(f"{v:.6g}" for v in p.u), int(self._interlock),
                                   f"{p.rotor_speed_rad_s:.6g}"])  # fmt: skip
            self._next_record_s += RECORD_PERIOD_S
        return json_state_from_plant(self.t_s, x1, f)

    def run(
        self, stop: threading.Event, duration_s: float | None = None, poll_s: float = 0.2
    ) -> BackendStats:
        """Answer frames until ``stop`` is set or the physics time reaches ``duration_s``."""
        while not stop.is_set():
            frame = self.link.poll(poll_s)
            if frame is None:
                continue
            if self.link.last_frame_was_reset and self.stats.frames:
                self._reset()
            if self.pacer is not None:
                self.pacer.wait_until(self.t_s + frame.dt_s)
            self.link.answer(self.step(frame.pwm_us, frame.dt_s))
            if duration_s is not None and self.t_s >= duration_s - 1e-9:
                break
        self.stats.link = dict(vars(self.link.counters))
        self.stats.link["refused"] = dict(vars(self.link.counters.refused))
        if self.pacer is not None:
            self.stats.link["pacer"] = dict(vars(self.pacer.counts))
        if self.can is not None:
            self.stats.can = self.can.stats.as_dict()
        return self.stats


def open_record(out_dir: Path | None) -> IO[str] | None:
    if out_dir is None:
        return None
    out_dir.mkdir(parents=True, exist_ok=True)
    return (out_dir / "plant.csv").open("w", newline="")
