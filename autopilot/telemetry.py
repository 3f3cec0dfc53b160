"""Telemetry messages built from the autopilot's view (state, reference, pitches), in NED/FRD."""

from __future__ import annotations

import math

import numpy as np

from autopilot.reference import REF_ACC, REF_POS, REF_VEL
from heli_common import frames
from heli_common.state import FloatArray
from heli_common.wire import servo_map
from heli_common.wire.mavlink.sim_protocol import state_fields
from heli_common.wire.mavlink.udp import Message, mavlink2
from heli_common.world.config import World
from heli_common.world.gusts import gust_factor, mean_wind_nwu

# POSITION_TARGET_LOCAL_NED type_mask: position, velocity, acceleration and yaw used; yaw rate not
TYPE_MASK_PVA_YAW = mavlink2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE


def attitude_and_position(t_us: int, x: FloatArray) -> list[Message]:
    """ATTITUDE and LOCAL_POSITION_NED (the same fields the plant publishes)."""
    f = state_fields(x)
    t_ms = t_us // 1000
    return [
        mavlink2.MAVLink_attitude_message(t_ms, *f.att),
        mavlink2.MAVLink_local_position_ned_message(t_ms, *f.pos_ned_m, *f.vel_ned_m_s),
    ]


def position_target(t_us: int, ref: FloatArray, psi_cmd_rad: float) -> Message:
    """The reference (NWU -> NED) and the controller's yaw command (FLU -> FRD)."""
    pos = frames.nwu_to_ned(ref[REF_POS])
    vel = frames.nwu_to_ned(ref[REF_VEL])
    acc = frames.nwu_to_ned(ref[REF_ACC])
    vals = [v if v == v else 0.0 for v in (*pos, *vel, *acc)]  # NaN (unknown) -> 0
    yaw_frd = frames.euler_flu_to_frd((0.0, 0.0, psi_cmd_rad))[2]
    return mavlink2.MAVLink_position_target_local_ned_message(
        t_us // 1000, mavlink2.MAV_FRAME_LOCAL_NED, TYPE_MASK_PVA_YAW, *vals, yaw_frd, 0.0
    )


def attitude_target(t_us: int, att_cmd_flu_rad: tuple[float, float, float]) -> Message:
    """The controller's attitude command (FLU Euler -> FRD quaternion), as PX4 reports its
    attitude set point; rates and thrust are not commanded by the TLC's outer loops."""
    roll, pitch, yaw = frames.euler_flu_to_frd(att_cmd_flu_rad)
    mask = (
        mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
        | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
        | mavlink2.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE
        | mavlink2.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
    )
    q = frames.euler_to_quaternion(roll, pitch, yaw)
    return mavlink2.MAVLink_attitude_target_message(t_us // 1000, mask, q, 0.0, 0.0, 0.0, 0.0)


def wind_cov(t_us: int, world: World, air_nwu_m_s: tuple[float, float, float] | None = None) -> Message:
    """The air at vehicle time ``t_us``, NED: the plant's (turbulence included) where it
    reports it, else the world's steady wind + gust. The variances are the Dryden vertical
    intensity's, sigma_w^2 = (0.1 W20)^2 (the horizontal is at least that), 0 in calm."""
    if air_nwu_m_s is None:
        w, g = world.wind, world.gust
        t_s = t_us / 1e6
        k = gust_factor(t_s, g.start_s, g.rise_s, math.inf if g.hold_s < 0.0 else g.hold_s, g.fall_s)
        air = mean_wind_nwu(w.speed_m_s, w.from_deg, w.elevation_deg) + k * mean_wind_nwu(
            g.amplitude_m_s, g.from_deg, g.elevation_deg)  # fmt: skip
    else:
        air = np.asarray(air_nwu_m_s)
    n, e, d = frames.nwu_to_ned(air)
    var = (0.1 * world.turbulence.w20_m_s) ** 2
    return mavlink2.MAVLink_wind_cov_message(t_us, n, e, d, var, var, math.nan, math.nan, math.nan)


def servo_output(t_us: int, pitches_rad: FloatArray, limits: FloatArray | servo_map.ServoMap) -> Message:
    """SERVO_OUTPUT_RAW: the four channels' PWM (blade pitches, or the CCPM servos)."""
    pwm = [int(p) for p in servo_map.to_pwm_us(pitches_rad, limits)] + [0] * 4
    return mavlink2.MAVLink_servo_output_raw_message(t_us & 0xFFFFFFFF, 0, *pwm)
