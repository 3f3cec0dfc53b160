"""The plant process: owns the 6-DOF model and steps it, lockstep or on the wall clock.

Lockstep (as PX4's): the plant publishes the state at sim time t and advances one period
only when it holds the command answering that state (HIL_ACTUATOR_CONTROLS with
``time_usec == t``). If none comes it re-sends the state every ``resend_s`` (UDP may drop)
and flags the autopilot silent after ``timeout_s``. Real time: the plant steps every
``1/rate`` seconds of wall clock, applies the newest command and holds it otherwise.
"""

from __future__ import annotations

import gc
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from heli_common import frames
from heli_common.wire.links import ServoCommand, ServoInput
from heli_common.wire.mavlink.fast import ParamSet, SimCodec
from heli_common.wire.mavlink.sim_protocol import (
    ROTOR_TRUTH_CHANNELS,
    encode_state,
    period_us,
    plausible_state,
    receive,
)
from heli_common.wire.mavlink.udp import MavlinkUdp, mavlink2
from heli_common.wire.servo_map import limits_array
from heli_plant.model import Plant
from heli_plant.sensors.sensing import encode_measurements
from heli_plant.servo_inputs import MavlinkServoInput

log = logging.getLogger("heli_plant.server")
LOCKSTEP_SPIN_S = 0.002  # poll this long before sleeping (see MavlinkUdp.wait)
WAIT_WARN_S = 5.0  # no command yet: say so after this long, and again every WAIT_REPEAT_S
WAIT_REPEAT_S = 30.0


class WaitingForAutopilot:
    """Before the first command: say in the log, after WAIT_WARN_S and then every
    WAIT_REPEAT_S, that the plant is waiting (a loop that does not step says why)."""

    def __init__(self, since: float) -> None:
        self.since = since
        self.due_s = WAIT_WARN_S

    def check(self, now: float) -> None:
        waited = now - self.since
        if waited >= self.due_s:
            self.due_s = waited + WAIT_REPEAT_S
            log.warning("no command from the autopilot in %.0f s: the plant has not stepped (is the "
                        "autopilot running, and sending to this process's port?)", waited)  # fmt: skip


@dataclass(frozen=True)
class SimConfig:
    mode: str = "lockstep"  # or "realtime"
    rate_hz: float = 100.0  # lockstep: the control rate; realtime: the physics rate
    duration_s: float | None = None  # None: until stopped
    timeout_s: float = 1.0  # autopilot silent after this long without a command
    resend_s: float = 0.2  # lockstep: re-send the state after this long without an answer
    # in-air start: the vehicle is held in place (time runs at wall-clock pace, nothing is
    # integrated) until the first armed command; then the dynamics start
    hold_until_armed: bool = False


@dataclass
class SimStats:
    steps: int = 0
    commands: int = 0
    stale_commands: int = 0  # time stamp not the current step's (lockstep) or older (realtime)
    bad_commands: int = 0  # NaN, out of range
    future_commands: int = 0  # stamped later than the plant's own clock: refused
    world_settings: int = 0  # SIM_ parameters taken (PARAM_SET on the sim link)
    world_settings_refused: int = 0
    resent_states: int = 0
    silent_events: int = 0
    autopilot_silent: bool = False
    # the vehicle left the range a state may hold (heli_common.wire.mavlink.sim_protocol): no
    # autopilot would accept it, so the run ends here, saying so (a lockstep run would
    # otherwise wait for an answer that never comes)
    lost: str = ""
    extra: dict[str, Any] = field(default_factory=dict)


class PlantServer:
    """The state goes out on the MAVLink sim link ``link``; commands come from ``servo_in``
    (the same link's HIL_ACTUATOR_CONTROLS by default, or DroneCAN). A medium without time
    stamps stamps a command with the current state's time: in lockstep the first command
    applied after a state is published answers that state."""

    def __init__(
        self, plant: Plant, link: MavlinkUdp, cfg: SimConfig, servo_in: ServoInput | None = None
    ) -> None:
        self.codec = SimCodec(system_id=1, component_id=51)
        self.limits = limits_array(plant.airframe.limits.as_tuple())
        self.servo_in: ServoInput = servo_in or MavlinkServoInput(link, self.codec, self.limits)
        # world settings come on the MAVLink sim link: the MAVLink servo input hands them
        # over; with another servo medium (CAN) nothing else reads that link, so we do
        self._reads_settings = not isinstance(self.servo_in, MavlinkServoInput)
        if isinstance(self.servo_in, MavlinkServoInput) and self.servo_in.on_setting is None:
            self.servo_in.on_setting = self._setting
        if cfg.hold_until_armed and not self.servo_in.carries_arming:
            raise ValueError("hold_until_armed needs a servo link that carries the arming state")
        self.plant = plant
        self.link = link
        self.cfg = cfg
        self.stats = SimStats()
        self.period_us = period_us(cfg.rate_hz)
        self.t_us = 0
        self._last_cmd_us = -1
        self._waiting_for_arm = cfg.hold_until_armed

    def _publish(self) -> None:
        data = encode_state(self.codec, self.t_us, self.plant.x)
        n = 3
        if self.plant.world is not None:
            data += self._world_truth()
            n += 2
        if self.plant.sensing is not None:
            data += encode_measurements(self.codec, self.plant.t_s, self.plant.sensing)
            n += 1
        self.link.send_bytes(data)
        self.link.stats.tx_messages += n

    def _world_truth(self) -> bytes:
        """In a world, the state's datagram also carries what the autopilot cannot measure
        and the flight log shows: the air at the vehicle (WIND_COV, NED, turbulence
        included) and the blade pitches the servos reached (ACTUATOR_OUTPUT_STATUS [rad]),
        both of the hold that led to this state (NaN before the first)."""
        w = self.plant.world
        assert w is not None
        nan = math.nan
        if w.h_s == 0.0:  # no hold yet: nothing to report of the air or the servos
            n = e = d = nan
            servo = [nan] * 4 + [0.0] * 28
        else:
            n, e, d = frames.nwu_to_ned(w.air_nwu_m_s)
            servo = [float(v) for v in w.pitches_rad] + [0.0] * 28
        active = 0xF
        if w.rotor.on:  # the rotor's truth in channels 4-7 (its state is known from the start)
            servo[4:8] = w.rotor_truth
            active |= ROTOR_TRUTH_CHANNELS
        air = mavlink2.MAVLink_wind_cov_message(self.t_us, n, e, d, nan, nan, nan, nan, nan)
        pitches = mavlink2.MAVLink_actuator_output_status_message(self.t_us, active, servo)
        self.link.mav.seq = self.codec.seq  # one sequence on the link: the codec's frames, then these
        data = self.link.pack(air) + self.link.pack(pitches)
        self.codec.seq = self.link.mav.seq
        return data

    def _end_reached(self) -> bool:
        """Stepped past the end (the state at t = duration is published and answered), or
        the vehicle is lost."""
        x = self.plant.x
        # every field within 100 (and none NaN) is plausible: one cheap test per tick
        if not self.stats.lost and not float(np.abs(x).max()) <= 100.0 and not plausible_state(x):
            t = self.t_us / 1e6
            self.stats.lost = f"vehicle lost at t = {t:.2f} s: its state left the range a state may hold"
            log.error("%s (%s)", self.stats.lost, np.array2string(x, precision=3))
        d = self.cfg.duration_s
        return bool(self.stats.lost) or (d is not None and self.t_us > round(d * 1e6))

    def _mark_silent(self, silent: bool) -> None:
        if silent and not self.stats.autopilot_silent:
            self.stats.silent_events += 1
            # the usual cause is benign (the autopilot ended its flight first); say both
            log.warning("no command from the autopilot for %.2f s (it has ended its flight, or its link "
                        "is down): holding the last command", self.cfg.timeout_s)  # fmt: skip
        elif not silent and self.stats.autopilot_silent:
            log.info("autopilot back")
        self.stats.autopilot_silent = silent

    def _frozen(self, armed: bool) -> bool:
        """While held for an armed autopilot, the state does not change."""
        if self._waiting_for_arm and armed:
            self._waiting_for_arm = False
            log.info("autopilot armed: the vehicle is released")
        return self._waiting_for_arm

    def _setting(self, name: str, value: float) -> None:
        if self.plant.set_sim_param(name, value):
            self.stats.world_settings += 1
            log.info("world: %s = %g from t = %.3f s", name, value, self.t_us / 1e6)
        else:
            self.stats.world_settings_refused += 1
            log.warning("world: refused %s = %g (unknown or out of range)", name, value)

    def _poll_settings(self) -> None:
        for msg in receive(self.link, self.codec):
            if isinstance(msg, ParamSet) and msg.target_component == self.codec.compid:
                self._setting(msg.param_id, msg.param_value)

    def _advance(self, dt: float) -> None:
        if self._reads_settings:
            self._poll_settings()
        if self._waiting_for_arm:
            # held: time passes at wall-clock pace so that ground stations see a live
            # vehicle and the mission protocol's timeouts mean what they say
            time.sleep(dt)
        else:
            self.plant.step(dt)
        self.stats.steps += 1
        self.t_us += self.period_us

    def _in_window(self, cmd: ServoCommand) -> bool:
        """Real time: a command answers a state this plant published, no older than the
        last one applied and no newer than its own clock (a far-future stamp would
        otherwise make every real command look old)."""
        if cmd.t_us > self.t_us:
            self.stats.future_commands += 1
            return False
        if cmd.t_us < self._last_cmd_us:
            self.stats.stale_commands += 1
            return False
        return True

    def run(self, stop: threading.Event) -> SimStats:
        gc.freeze()  # start-up objects never need rescanning while the plant runs
        if self.cfg.mode == "lockstep":
            self._run_lockstep(stop)
        else:
            self._run_realtime(stop)
        self.stats.bad_commands += self.servo_in.refused
        return self.stats

    def _run_lockstep(self, stop: threading.Event) -> None:
        dt = self.period_us / 1e6
        self._publish()
        sent_at = last_cmd = time.monotonic()
        waiting = WaitingForAutopilot(sent_at)
        while not stop.is_set() and not self._end_reached():
            applied = False
            for cmd in self.servo_in.receive(self.t_us, min(self.cfg.resend_s, 0.05)):
                if cmd.t_us != self.t_us:
                    self.stats.stale_commands += 1
                    continue
                self.stats.commands += 1
                if not self._frozen(cmd.armed) and not self.plant.set_pitches(cmd.pitches_rad):
                    self.stats.bad_commands += 1
                applied = True
            now = time.monotonic()
            if applied:
                self._mark_silent(False)
                self._advance(dt)
                self._publish()
                # the autopilot's silence counts from the state it was sent: a slow step here
                # (code compiled on first use, a busy core) is the plant's own time, not its
                sent_at = last_cmd = time.monotonic()
                continue
            if now - last_cmd > self.cfg.timeout_s:
                self._mark_silent(True)
            if self.stats.commands == 0:
                waiting.check(now)
            if now - sent_at > self.cfg.resend_s:
                self._publish()
                self.stats.resent_states += 1
                sent_at = now
        self._publish()

    def _run_realtime(self, stop: threading.Event) -> None:
        dt = self.period_us / 1e6
        # The clock starts with the first command, so a vehicle in the air does not fall
        # while the autopilot is starting; until then the state is published at 20 Hz.
        waiting = WaitingForAutopilot(time.monotonic())
        while not stop.is_set():
            self._publish()
            cmds = [c for c in self.servo_in.receive(self.t_us, 0.05) if self._in_window(c)]
            if cmds:
                first = cmds[-1]
                self._last_cmd_us = first.t_us
                self.stats.commands += 1
                if not self._frozen(first.armed):
                    self.plant.set_pitches(first.pitches_rad)
                break
            waiting.check(time.monotonic())
        start = time.monotonic()
        last_cmd = start
        k = 0
        while not stop.is_set() and not self._end_reached():
            for cmd in self.servo_in.receive(self.t_us):
                if not self._in_window(cmd):
                    continue
                self._last_cmd_us = cmd.t_us
                self.stats.commands += 1
                if not self._frozen(cmd.armed) and not self.plant.set_pitches(cmd.pitches_rad):
                    self.stats.bad_commands += 1
                last_cmd = time.monotonic()
            self._mark_silent(time.monotonic() - last_cmd > self.cfg.timeout_s)
            if self._waiting_for_arm:
                self.stats.steps += 1  # held: the clock runs, the state does not change
                self.t_us += self.period_us
            else:
                self._advance(dt)
            self._publish()
            k += 1
            delay = start + k * dt - time.monotonic()  # deadline scheduling: no drift
            if delay > 0:
                stop.wait(delay)
