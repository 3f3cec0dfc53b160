"""Gains of the cascaded PID baseline (``configs/gains_pid.toml``), per channel (N, W, U) in
the earth loops and (roll, pitch, yaw) about the body axes in the attitude and rate loops."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

from autopilot.design_point import DesignPoint
from heli_common.config import load, spec

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class PositionGains:
    kp: Vec3 = spec("1/s", 0.0, 50.0)  # velocity set point per metre of error
    max_speed_m_s: float = spec("m/s", 0.1, 50.0, default=10.0)


@dataclass(frozen=True)
class VelocityGains:
    kp: Vec3 = spec("1/s", 0.0, 50.0)  # acceleration per m/s of error
    ki: Vec3 = spec("1/s^2", 0.0, 50.0)
    i_max_m_s2: float = spec("m/s^2", 0.0, 20.0, default=3.0)  # integrator clamp (anti-windup)
    # the vertical acceleration set point's limit (ArduPilot's PSC_ACCZ limit): far below or
    # above its path the law would command the thrust to zero or below, where the cyclic's
    # moment (thrust times the hub's height in the design model) changes sign
    accel_max_z_m_s2: float = spec("m/s^2", 0.5, 100.0, default=100.0)


@dataclass(frozen=True)
class AttitudeGains:
    kp: Vec3 = spec("1/s", 0.0, 100.0)  # body-rate set point per rad of error
    max_rate_rad_s: Vec3 = spec("rad/s", 0.1, 20.0, default=(3.0, 3.0, 2.0))
    # added to the roll set point (ArduPilot's ATC_HOVR_ROL_TRM): the tail rotor's side force
    # is held by a constant bank that the law's force model (thrust along the mast) does not
    # know; left to the earth-frame velocity integrator, that body-fixed bias turns with the
    # heading and the integrator lags it on every turn
    hover_roll_trim_rad: float = spec("rad", -0.3, 0.3, default=0.0)


@dataclass(frozen=True)
class RateGains:
    kp: Vec3 = spec("1/s", 0.0, 500.0)  # angular acceleration per rad/s of error
    ki: Vec3 = spec("1/s^2", 0.0, 5000.0)
    kd: Vec3 = spec("", 0.0, 10.0)  # on the measured rate, filtered
    # feed-forward of the rate set point (ArduPilot's RAT_*_FF): on a rotor whose cyclic sets a
    # rate rather than an acceleration, the command that holds a rate without waiting for the
    # integrator; 0 on a rigid body (the paper's model)
    ff: Vec3 = spec("1/s", 0.0, 500.0, default=(0.0, 0.0, 0.0))
    d_filter_hz: float = spec("Hz", 1.0, 200.0, default=20.0)
    i_max_rad_s2: float = spec("rad/s^2", 0.0, 500.0, default=20.0)


@dataclass(frozen=True)
class PidLimits:
    tilt_max_rad: float = spec("rad", 0.01, 1.2, default=0.6)
    yaw_hold_speed_m_s: float = spec("m/s", 0.0, 10.0, default=0.5)


@dataclass(frozen=True)
class PidGains:
    name: str = spec()
    position: PositionGains = spec()
    velocity: VelocityGains = spec()
    attitude: AttitudeGains = spec()
    rate: RateGains = spec()
    limits: PidLimits = spec(default=PidLimits())
    # the plant and servos its margins are proven for (autopilot/design_point.py)
    design: DesignPoint = spec(default=DesignPoint())

    @classmethod
    def load(cls, path: str | Path = "gains_pid.toml") -> PidGains:
        return load(cls, path)


#: each section of PidGains by its field name
PID_SECTIONS: dict[str, type] = {
    "position": PositionGains,
    "velocity": VelocityGains,
    "attitude": AttitudeGains,
    "rate": RateGains,
    "limits": PidLimits,
}


@functools.cache
def default_pid_gains() -> PidGains:
    """configs/gains_pid.toml, read once (a campaign simulates thousands of flights)."""
    return PidGains.load()
