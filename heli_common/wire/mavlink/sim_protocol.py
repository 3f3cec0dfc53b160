"""The sim link's messages: plant state out, actuator command back (PX4-lockstep style).

Each plant step is one datagram of three standard messages sharing one time stamp:
HIL_STATE_QUATERNION (``time_usec``: simulation time [us], the lockstep key), ATTITUDE
(float Euler angles and body rates, NED/FRD) and LOCAL_POSITION_NED (float position and
earth-frame velocity). The autopilot answers with one HIL_ACTUATOR_CONTROLS whose
``time_usec`` echoes the state it answers; controls[0:4] are the pitches normalised by the
limits (:mod:`heli_common.wire.servo_map`), and ``mode`` carries MAV_MODE_FLAG_SAFETY_ARMED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from heli_common import frames
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import EULER, N_PITCH, OMEGA, POS, VEL, FloatArray
from heli_common.wire import servo_map
from heli_common.wire.mavlink.fast import Decoded, SimCodec, hil_alt_vel
from heli_common.wire.mavlink.udp import MavlinkUdp, Message, mavlink2


class StateFields(NamedTuple):
    """What the three state messages carry, in NED/FRD."""

    att: tuple[float, float, float, float, float, float]  # roll, pitch, yaw, p, q, r
    quat: tuple[float, float, float, float]
    alt_mm: int
    vel_ned_cm_s: tuple[int, int, int]
    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]


# The state's fields the autopilot reads back (ATTITUDE, LOCAL_POSITION_NED; float32 each)
WIRE_STATE = Layout("wire state", ("euler_frd", 3), ("rates_frd", 3), ("pos_ned", 3), ("vel_ned", 3))
WIRE_EULER = WIRE_STATE.offset("euler_frd")
WIRE_RATES = WIRE_STATE.offset("rates_frd")
WIRE_POS = WIRE_STATE.offset("pos_ned")
WIRE_VEL = WIRE_STATE.offset("vel_ned")
N_WIRE_STATE = WIRE_STATE.size


def state_fields(x: FloatArray) -> StateFields:
    f = frames.state_to_ned_fields(x).tolist()
    e, r, q = frames.NF_EULER, frames.NF_RATES, frames.NF_QUAT
    pos_ned = (f[frames.NF_POS], f[frames.NF_POS + 1], f[frames.NF_POS + 2])
    vel_ned = (f[frames.NF_VEL], f[frames.NF_VEL + 1], f[frames.NF_VEL + 2])
    alt_mm, vel_cm = hil_alt_vel(pos_ned, vel_ned)
    att = (f[e], f[e + 1], f[e + 2], f[r], f[r + 1], f[r + 2])
    return StateFields(att, (f[q], f[q + 1], f[q + 2], f[q + 3]), alt_mm, vel_cm, pos_ned, vel_ned)


def state_messages(t_us: int, x: FloatArray) -> list[Message]:
    """The state as pymavlink messages (telemetry, logs); the sim link uses :func:`encode_state`."""
    f = state_fields(x)
    t_ms = t_us // 1000
    hil = mavlink2.MAVLink_hil_state_quaternion_message(
        t_us, f.quat, *f.att[3:], 0, 0, f.alt_mm, *f.vel_ned_cm_s, 0, 0, 0, 0, 0
    )
    att = mavlink2.MAVLink_attitude_message(t_ms, *f.att)
    lpn = mavlink2.MAVLink_local_position_ned_message(t_ms, *f.pos_ned_m, *f.vel_ned_m_s)
    return [hil, att, lpn]


@njit
def state_as_received(x: FloatArray) -> FloatArray:
    """The state ``x`` as the autopilot decodes it from the sim link: ATTITUDE's and
    LOCAL_POSITION_NED's float32 fields (the yaw wrapped), back in the plant's layout. The
    in-process loop's controller flies on this, so that it sees the very numbers a
    lockstep autopilot sees (the link's rounding is the only thing the two flights would
    otherwise not share)."""
    f = frames.state_to_ned_fields(x)
    e, w, p, v = frames.NF_EULER, frames.NF_RATES, frames.NF_POS, frames.NF_VEL
    r = np.empty(N_WIRE_STATE)
    for k in range(3):
        r[WIRE_EULER + k] = np.float32(f[e + k])
        r[WIRE_RATES + k] = np.float32(f[w + k])
        r[WIRE_POS + k] = np.float32(f[p + k])
        r[WIRE_VEL + k] = np.float32(f[v + k])
    return frames.state_from_ned_fields(
        r[WIRE_EULER], r[WIRE_EULER + 1], r[WIRE_EULER + 2], r[WIRE_RATES], r[WIRE_RATES + 1],
        r[WIRE_RATES + 2], r[WIRE_POS], r[WIRE_POS + 1], r[WIRE_POS + 2], r[WIRE_VEL],
        r[WIRE_VEL + 1], r[WIRE_VEL + 2],
    )  # fmt: skip


def as_received(x: FloatArray) -> FloatArray:
    """The state ``x`` as the autopilot decodes it from the sim link (float32 fields, the
    yaw wrapped): what an in-process estimator starts from to start where the process one
    does."""
    return state_as_received(np.asarray(x, dtype=float))


# HIL_ACTUATOR_CONTROLS carries a pitch as a float32 normalised by the pitch limits; the
# plant refuses a command beyond them by more than this (decode_command)
MAX_ABS_NORMALIZED = 1.0 + 1e-6


@njit
def pitches_as_received(u: FloatArray, lo: FloatArray, hi: FloatArray, held: FloatArray) -> bool:
    """What the plant holds when the autopilot sends pitches ``u`` on the sim link
    (:meth:`SimLink.send_pitches` -> :func:`decode_command` -> ``accept_pitches``): each
    normalised by the limits [lo, hi] (servo_map.to_normalized), rounded to the float32 of
    HIL_ACTUATOR_CONTROLS.controls, mapped back (servo_map.from_normalized, the same
    operations in the same order) and clipped into ``held``. False, ``held`` kept, for a
    command the plant refuses (not finite, or beyond the limits)."""
    n = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        n[i] = np.float32(2.0 * (u[i] - lo[i]) / (hi[i] - lo[i]) - 1.0)
        if not math.isfinite(n[i]) or abs(n[i]) > MAX_ABS_NORMALIZED:
            return False
    for i in range(u.shape[0]):
        held[i] = min(max(lo[i] + (n[i] + 1.0) * 0.5 * (hi[i] - lo[i]), lo[i]), hi[i])
    return True


def receive(link: MavlinkUdp, codec: SimCodec, timeout_s: float = 0.0, spin_s: float = 0.0) -> list[Decoded]:
    """Decode every queued datagram with the fast codec; drop (and count in ``link.stats``)
    frames that fail their CRC or length, unknown messages, and foreign system ids."""
    bad0 = codec.bad_crc + codec.truncated + codec.garbage + codec.unknown + codec.unsupported
    out: list[Decoded] = []
    for data, _ in link.recv_datagrams(timeout_s, spin_s):
        for m in codec.decode(data):
            if link.accept_system is not None and m.sysid != link.accept_system:
                link.stats.rx_foreign += 1
                continue
            out.append(m)
    link.stats.rx_messages += len(out)
    link.stats.rx_bad += (
        codec.bad_crc + codec.truncated + codec.garbage + codec.unknown + codec.unsupported - bad0
    )
    return out


def encode_state(codec: SimCodec, t_us: int, x: FloatArray) -> bytes:
    """The same three messages, packed by the fast codec (byte-identical to pymavlink's)."""
    f = state_fields(x)
    return codec.encode_state(t_us, f.att, f.quat, 0, 0, f.alt_mm, f.vel_ned_cm_s, f.pos_ned_m,
                              f.vel_ned_m_s)  # fmt: skip


N_ROTOR_TRUTH = 4  # a1, b1, rotor speed, throttle
ROTOR_TRUTH_CHANNELS = 0xF0  # their bits in ACTUATOR_OUTPUT_STATUS.active


@dataclass(frozen=True)
class StateSample:
    t_us: int
    x: FloatArray  # NWU/FLU plant state layout
    session: int = 0  # bumps when the plant's clock restarts (a restarted plant)
    # a plant flying a world adds the truth the flight log shows (None in the ideal world):
    # the air at the vehicle (earth NWU, m/s) and the pitches the servos reached (rad)
    air_nwu_m_s: tuple[float, float, float] | None = None
    servo_rad: tuple[float, float, float, float] | None = None
    # the rotor plant adds its rotor's truth: flapping a1, b1 [rad], rotor speed [rad/s] and
    # the governor's throttle [0, 1] (ACTUATOR_OUTPUT_STATUS channels 4-7)
    rotor: tuple[float, float, float, float] | None = None
    # a plant whose sensors are on adds what they measured (heli_common.wire.measurements layout,
    # each sensor's latest sample), the mask of samples new since the last state handed
    # out, and the sensors' time [s] (vehicle time; it stands still while the vehicle is held)
    meas: FloatArray | None = None
    meas_mask: int = 0
    meas_t_s: float = 0.0


# What a state may hold: anything else is a corrupted or hostile datagram, never a vehicle.
MAX_ABS_POS_M = 1e5
MAX_ABS_VEL_M_S = 300.0
MAX_ABS_RATE_RAD_S = 100.0
MAX_ABS_ANGLE_RAD = 1e3  # Euler angles may be unwrapped (a spinning yaw)
# Consecutive states of one timeline are at most this far apart in simulation time (the
# plant steps 1-20 ms; a held or stalled peer can leave gaps of seconds, which arrive as a
# run of states that continue each other).
MAX_STEP_US = 5_000_000
# A jump in time (forward beyond MAX_STEP_US, or back: a restarted plant) is believed only
# after this many consecutive states that continue each other: one datagram cannot move it.
RESYNC_STATES = 3


def plausible_state(x: FloatArray) -> bool:
    """Finite and physically possible (positions, speeds, rates, angles)."""
    if not np.isfinite(x).all():
        return False
    return bool(
        np.abs(x[POS]).max() <= MAX_ABS_POS_M
        and np.abs(x[VEL]).max() <= MAX_ABS_VEL_M_S
        and np.abs(x[OMEGA]).max() <= MAX_ABS_RATE_RAD_S
        and np.abs(x[EULER]).max() <= MAX_ABS_ANGLE_RAD
    )


class SimMessage(Protocol):
    """A decoded sim-link message: pymavlink's, or the fast codec's (the same field names;
    read after ``get_type`` says which message it is)."""

    def get_type(self) -> str: ...


class StateAssembler:
    """Collects the three state messages of one step; yields a state when all three agree
    and the state is plausible and on the plant's timeline.

    The timeline: a state is accepted if its time equals the last one (a re-sent state) or
    advances it by at most MAX_STEP_US. Anything else (a far-future stamp, or time going
    back) is refused and counted, unless RESYNC_STATES consecutive states continue each
    other in the new timeline: then it is believed, as a restarted plant (time back: a new
    ``session``) or a resumed one (time forward)."""

    def __init__(self) -> None:
        self._t_us: int | None = None
        self._att: Any = None  # the ATTITUDE of the step being assembled
        self._lpn: Any = None
        self.last_t_us = -1
        self.session = 0
        self.out_of_order = 0  # refused: time went back (and was not a restart)
        self.time_jumps = 0  # refused: too far ahead
        self.implausible = 0  # refused: non-finite or physically impossible values
        self.resyncs = 0  # accepted jumps forward
        self._cand_t_us = -1
        self._cand_n = 0

    def feed(self, message: SimMessage) -> StateSample | None:
        kind = message.get_type()
        msg: Any = message  # its fields, by name
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
        x = frames.state_from_ned_fields(
            att.roll, att.pitch, att.yaw, att.rollspeed, att.pitchspeed, att.yawspeed,
            lpn.x, lpn.y, lpn.z, lpn.vx, lpn.vy, lpn.vz,
        )  # fmt: skip
        if not plausible_state(x):
            self.implausible += 1
            return None
        if not self._on_timeline(t_us):
            return None
        self.last_t_us = t_us
        return StateSample(t_us, x, self.session)

    def _on_timeline(self, t_us: int) -> bool:
        last = self.last_t_us
        if last < 0 or last <= t_us <= last + MAX_STEP_US:  # equal: a re-sent state
            self._cand_n = 0
            return True
        if self._cand_n and 0 <= t_us - self._cand_t_us <= MAX_STEP_US:  # equal: re-sent
            self._cand_n += 1
        else:
            self._cand_n = 1
        self._cand_t_us = t_us
        if self._cand_n < RESYNC_STATES:
            if t_us < last:
                self.out_of_order += 1
            else:
                self.time_jumps += 1
            return False
        self._cand_n = 0
        if t_us < last:
            self.session += 1
        else:
            self.resyncs += 1
        return True


MAV_MODE_FLAG_SAFETY_ARMED = int(mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)


def command_message(
    t_us: int, pitches_rad: FloatArray, limits: FloatArray | servo_map.ServoMap, armed: bool
) -> Message:
    controls = [0.0] * 16
    controls[:N_PITCH] = [float(v) for v in servo_map.as_map(limits).to_normalized(pitches_rad)]
    mode = MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    return mavlink2.MAVLink_hil_actuator_controls_message(t_us, controls, mode, 0)


def decode_command(
    message: SimMessage, limits: FloatArray | servo_map.ServoMap
) -> tuple[int, FloatArray] | None:
    """(time_usec, pitches [rad]) or None if it is not a usable command (NaN, |n| > 1);
    ``limits``: the airframe's (one channel per pitch) or a servo map (CCPM)."""
    if message.get_type() != "HIL_ACTUATOR_CONTROLS":
        return None
    msg: Any = message
    n = np.array(msg.controls[:N_PITCH], dtype=float)
    if not np.all(np.isfinite(n)) or np.any(np.abs(n) > MAX_ABS_NORMALIZED):
        return None
    return int(msg.time_usec), servo_map.as_map(limits).from_normalized(n)


def period_us(rate_hz: float) -> int:
    return int(round(1e6 / rate_hz))
