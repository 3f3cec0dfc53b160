"""What the view shows at one instant (:class:`ViewFrame`), whatever it came from: the live
MAVLink telemetry of a vehicle (:mod:`heli_sitl.view.mavlink_feed`) or a recorded flight
(:mod:`heli_sitl.view.recording`). Paper frames: earth NWU (z up), body FLU, ZYX Euler, SI."""

from __future__ import annotations

import math
from dataclasses import dataclass

Vec3 = tuple[float, float, float]
Pitches = tuple[float, float, float, float]


@dataclass(frozen=True)
class ViewFrame:
    """One instant of a flight as the view draws it; None where the source does not say."""

    t_s: float  # flight time (run.csv's t: 0 at arming where the source shows the arming)
    pos_nwu_m: Vec3
    euler_flu_rad: Vec3  # roll, pitch, yaw (ZYX)
    ref_nwu_m: Vec3 | None = None  # the reference point
    err_m: float | None = None  # |position - reference| of one and the same control tick
    err_t_s: float | None = None  # that tick's flight time (the reference may lag the pose)
    # the position was the tick's own (True), or interpolated between the two positions about
    # the target's tick (the vehicle's 10 Hz and 20 Hz telemetry grids part by a tick at times)
    err_exact: bool = True
    pitches_rad: Pitches | None = None  # theta_m, theta_t, eps, eta
    rotor_speed_rad_s: float | None = None
    flapping_rad: tuple[float, float] | None = None  # a1 (forward tilt), b1 (right tilt)
    wind_nwu_m_s: Vec3 | None = None
    mode: str = ""
    armed: bool | None = None


def tracking_error_m(pos: Vec3, ref: Vec3) -> float:
    """The 3-D distance between the vehicle and its reference point [m]."""
    return math.dist(pos, ref)
