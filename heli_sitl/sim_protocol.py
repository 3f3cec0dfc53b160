"""The sim link's messages: plant state out, actuator command back (PX4-lockstep style).

Each plant step is one datagram of three standard messages sharing one time stamp:
HIL_STATE_QUATERNION (``time_usec``: simulation time [us], the lockstep key), ATTITUDE
(float Euler angles and body rates, NED/FRD) and LOCAL_POSITION_NED (float position and
earth-frame velocity). The autopilot answers with one HIL_ACTUATOR_CONTROLS whose
``time_usec`` echoes the state it answers; controls[0:4] are the pitches normalised by the
limits (:mod:`heli_sitl.servo_map`), and ``mode`` carries MAV_MODE_FLAG_SAFETY_ARMED.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heli_sitl import frames, servo_map
from heli_sitl.kinematics import rot_body_to_earth
from heli_sitl.mavlink_link import Message, mavlink2
from heli_sitl.state import EULER, N_PITCH, N_STATE, OMEGA, POS, VEL, FloatArray


def state_messages(t_us: int, x: FloatArray, g_m_s2: float = 9.81) -> list[Message]:
    pos_ned, _, euler_frd, omega_frd = frames.state_nwu_to_ned(x)
    rt = rot_body_to_earth(x[EULER][0], x[EULER][1], x[EULER][2])
    vel_ned = frames.nwu_to_ned(rt @ x[VEL])
    q = frames.euler_to_quaternion(*euler_frd)
    t_ms = t_us // 1000
    hil = mavlink2.MAVLink_hil_state_quaternion_message(
        t_us, q, omega_frd[0], omega_frd[1], omega_frd[2],
        0, 0, int(round(-pos_ned[2] * 1000)),
        _i16(vel_ned[0] * 100), _i16(vel_ned[1] * 100), _i16(vel_ned[2] * 100),
        0, 0, 0, 0, 0,
    )  # fmt: skip
    att = mavlink2.MAVLink_attitude_message(t_ms, *euler_frd, *omega_frd)
    lpn = mavlink2.MAVLink_local_position_ned_message(t_ms, *pos_ned, *vel_ned)
    return [hil, att, lpn]


def _i16(v: float) -> int:
    return int(max(-32768, min(32767, round(v))))


@dataclass(frozen=True)
class StateSample:
    t_us: int
    x: FloatArray  # NWU/FLU plant state layout


class StateAssembler:
    """Collects the three state messages of one step; yields a state when all three agree."""

    def __init__(self) -> None:
        self._t_us: int | None = None
        self._att: Message | None = None
        self._lpn: Message | None = None
        self.last_t_us = -1
        self.out_of_order = 0

    def feed(self, msg: Message) -> StateSample | None:
        kind = msg.get_type()
        if kind == "HIL_STATE_QUATERNION":
            self._t_us = int(msg.time_usec)
        elif kind == "ATTITUDE":
            self._att = msg
        elif kind == "LOCAL_POSITION_NED":
            self._lpn = msg
        else:
            return None
        t_us, att, lpn = self._t_us, self._att, self._lpn
        if t_us is None or att is None or lpn is None:
            return None
        t_ms = t_us // 1000
        if att.time_boot_ms != t_ms or lpn.time_boot_ms != t_ms:
            return None
        self._t_us = self._att = self._lpn = None
        if t_us < self.last_t_us:  # equal: a re-sent state, whose answer may have been lost
            self.out_of_order += 1
            return None
        x = np.empty(N_STATE)
        euler_flu = frames.euler_frd_to_flu((att.roll, att.pitch, att.yaw))
        x[POS] = frames.ned_to_nwu((lpn.x, lpn.y, lpn.z))
        x[EULER] = euler_flu
        x[OMEGA] = frames.frd_to_flu((att.rollspeed, att.pitchspeed, att.yawspeed))
        rt = rot_body_to_earth(euler_flu[0], euler_flu[1], euler_flu[2])
        x[VEL] = rt.T @ np.array(frames.ned_to_nwu((lpn.vx, lpn.vy, lpn.vz)))
        if not np.all(np.isfinite(x)):
            return None
        self.last_t_us = t_us
        return StateSample(t_us, x)


def command_message(t_us: int, pitches_rad: FloatArray, limits: FloatArray, armed: bool) -> Message:
    controls = [0.0] * 16
    controls[:N_PITCH] = [float(v) for v in servo_map.to_normalized(pitches_rad, limits)]
    mode = mavlink2.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return mavlink2.MAVLink_hil_actuator_controls_message(t_us, controls, mode, 0)


def decode_command(msg: Message, limits: FloatArray) -> tuple[int, FloatArray] | None:
    """(time_usec, pitches [rad]) or None if it is not a usable command (NaN, |n| > 1)."""
    if msg.get_type() != "HIL_ACTUATOR_CONTROLS":
        return None
    n = np.array(msg.controls[:N_PITCH], dtype=float)
    if not np.all(np.isfinite(n)) or np.any(np.abs(n) > 1.0 + 1e-6):
        return None
    return int(msg.time_usec), servo_map.from_normalized(n, limits)


def period_us(rate_hz: float) -> int:
    return int(round(1e6 / rate_hz))
