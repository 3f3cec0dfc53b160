"""Manoeuvres for held-out scenarios: a figure-eight, a turn between two straight lines and
a position step (configs/scenario_figure_eight.toml, _aggressive_turn, _position_step).

Every one starts at rest and gets up to speed with the waypoint missions' own shaping
(:mod:`autopilot.trajectory.waypoints`: the quintic :func:`smootherstep` ramp, and for the
step the whole rest-to-rest leg, :func:`leg_profile` and :func:`rest_to_rest`), so the
reference starts with zero velocity and acceleration and is continuous in position and
velocity everywhere (in acceleration too, except at the turn's arc ends, see
:class:`ArcTurn`). Position, velocity and acceleration are closed-form (exact feedforward,
never NaN); earth NWU, SI units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import ellipj, ellipk

from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.waypoints import FlightLimits, Profile, leg_profile, rest_to_rest, smootherstep
from heli_common.config import spec
from heli_common.state import FloatArray

MISSION_LIMITS = FlightLimits()  # the waypoint missions' default speed and acceleration


def ramp_then_cruise(t_s: FloatArray, speed_m_s: float, ramp_s: float) -> Profile:
    """Distance [m], speed [m/s] and tangential acceleration [m/s^2] along a path flown
    from rest: the missions' :func:`smootherstep` ramp to ``speed_m_s`` over ``ramp_s``
    (peak acceleration 1.875 V / T_ramp), then a constant speed; rest before t = 0."""
    t = np.maximum(t_s, 0.0)
    up = t < ramp_s
    s_up, v_up, a_up = smootherstep(np.minimum(t, ramp_s) / ramp_s, speed_m_s, ramp_s)
    s = np.where(up, s_up, 0.5 * speed_m_s * ramp_s + speed_m_s * (t - ramp_s))
    v = np.where(up, v_up, speed_m_s)
    a = np.where(up, a_up, 0.0)
    return s, v, a


# ------------------------------------------------------------------------------ figure-eight


def _lemniscate(u: FloatArray) -> tuple[FloatArray, ...]:
    """The unit lemniscate of Bernoulli p(u) = (sin u, sin u cos u) / (1 + cos^2 u) and its
    first and second derivatives in u: (x, y, x', y', x'', y'')."""
    su, cu, s2, c2 = np.sin(u), np.cos(u), np.sin(2.0 * u), np.cos(2.0 * u)
    d, d1, d2 = 1.0 + cu * cu, -s2, -2.0 * c2  # the denominator and its derivatives

    def quotient(g: FloatArray, g1: FloatArray, g2: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        # (g/d), (g/d)', (g/d)''
        return (g / d, (g1 * d - g * d1) / (d * d),
                (g2 * d * d - 2.0 * g1 * d1 * d - g * d2 * d + 2.0 * g * d1 * d1) / (d * d * d))  # fmt: skip

    x, x1, x2 = quotient(su, cu, -su)
    y, y1, y2 = quotient(0.5 * s2, c2, -2.0 * s2)
    return x, y, x1, y1, x2, y2


def lemniscate_parameter(s_unit: FloatArray) -> FloatArray:
    """The parameter u of :func:`_lemniscate` at arc length ``s_unit`` from the crossing
    (unit lemniscate, any number of laps). Along this parametrisation ds/du =
    1 / sqrt(1 + cos^2 u), so s = F(u | 1/2) / sqrt 2 (the incomplete elliptic integral of
    the first kind, parameter m = 1/2) and u = am(sqrt(2) s | 1/2), Jacobi's amplitude:
    closed-form, no table. One lap is 4 K(1/2) / sqrt 2 = 5.2441 (twice the lemniscate
    constant)."""
    return np.asarray(ellipj(math.sqrt(2.0) * np.asarray(s_unit, dtype=float), 0.5)[3], dtype=float)


LEMNISCATE_LAP = 4.0 * float(ellipk(0.5)) / math.sqrt(2.0)  # one lap of the unit lemniscate


@dataclass(frozen=True)
class FigureEight(Trajectory):
    """A horizontal figure-eight flown at constant path speed: the lemniscate of Bernoulli
    (x^2 + y^2)^2 = a^2 (x^2 - y^2) about ``center_nwu_m``, its long axis north.

    Tips at +-a north, half-width a / (2 sqrt 2) = 0.354 a west and east; one lap is
    5.2441 a long. It starts at the centre (the crossing) heading north-west (45 deg, NWU
    yaw pi/4), turns clockwise (seen from above) round the northern lobe, crosses heading
    south-west, and anticlockwise round the southern lobe. Curvature 3 r / a^2 at
    distance r from the centre: zero at the crossing, the tightest turn (radius a/3) at
    the tips, lateral acceleration 3 V^2 / a there (30 m, 5 m/s: 2.5 m/s^2, 14 deg of tilt).

    The path speed ramps from hover to ``speed_m_s`` with the missions' smootherstep over
    ``ramp_s`` (:func:`ramp_then_cruise`), so position, velocity and acceleration are
    continuous. The arc-length parametrisation is closed-form (:func:`lemniscate_parameter`,
    Jacobi's amplitude), so the path speed is exactly the ramp's: velocity is the unit
    tangent times the speed, acceleration the tangential plus the centripetal part.
    """

    center_nwu_m: tuple[float, float, float] = spec("m", -1e6, 1e6, default=(0.0, 0.0, 20.0))
    half_length_m: float = spec("m", 0.0, 1e4, lo_open=True, default=30.0)
    speed_m_s: float = spec("m/s", 0.0, 50.0, lo_open=True, default=5.0)
    ramp_s: float = spec("s", 0.0, 1e3, lo_open=True, default=5.0)
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True, default=70.0)

    @property
    def lap_length_m(self) -> float:
        return LEMNISCATE_LAP * self.half_length_m

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        a = self.half_length_m
        s, v, at = ramp_then_cruise(t, self.speed_m_s, self.ramp_s)
        x, y, x1, y1, x2, y2 = _lemniscate(lemniscate_parameter(s / a))
        speed_u = np.hypot(x1, y1)  # |dp/du| of the unit curve
        tx, ty = x1 / speed_u, y1 / speed_u  # unit tangent
        # curvature vector d2p/ds2 = (p'' - T (T . p'')) / |p'|^2, scaled by 1/a
        along = tx * x2 + ty * y2
        kx = (x2 - tx * along) / (speed_u * speed_u * a)
        ky = (y2 - ty * along) / (speed_u * speed_u * a)
        c = self.center_nwu_m
        out = np.zeros((t.size, 9))
        out[:, 0] = c[0] + a * x
        out[:, 1] = c[1] + a * y
        out[:, 2] = c[2]
        out[:, 3] = tx * v
        out[:, 4] = ty * v
        out[:, 6] = tx * at + kx * v * v
        out[:, 7] = ty * at + ky * v * v
        return out


# ------------------------------------------------------------------------------------- turn


@dataclass(frozen=True)
class ArcTurn(Trajectory):
    """Level flight along a straight line, a circular arc that turns the course by
    ``turn_rad``, and a straight line again, at ``speed_m_s`` after a ramp from hover.

    From ``start_nwu_m`` on the course ``heading_rad`` (NWU: 0 north, pi/2 west), the speed
    ramps up with the missions' smootherstep over ``ramp_s`` (:func:`ramp_then_cruise`);
    the arc (radius ``radius_m``, ``turn_rad`` > 0 to the left: anticlockwise seen from
    above, as NWU yaw) starts at ``turn_start_s``, at full speed, and lasts
    ``radius |turn| / speed``. In the arc the lateral acceleration is V^2 / R; it steps
    from and back to zero at the arc's ends (a line joined to a circle has a curvature
    step), the test of how fast a controller banks into a turn: position and velocity are
    continuous, the acceleration jumps there only.

    A controller can bank only to its tilt limit (``tilt_max_rad``, 0.35 rad in every gain
    set: g tan 0.35 = 3.6 m/s^2, less the hover trim's 0.04 rad of roll on a left turn);
    the aggressive_turn scenario's 8 m/s on a 25 m radius asks 2.56 m/s^2 (0.26 g, 0.255
    rad of bank) for 4.9 s. On 20 m the bank and the trim's roll together pass the limit.
    """

    start_nwu_m: tuple[float, float, float] = spec("m", -1e6, 1e6, default=(0.0, 0.0, 20.0))
    heading_rad: float = spec("rad", -7.0, 7.0, default=0.0)
    speed_m_s: float = spec("m/s", 0.0, 50.0, lo_open=True, default=8.0)
    ramp_s: float = spec("s", 0.0, 1e3, lo_open=True, default=8.0)
    turn_start_s: float = spec("s", 0.0, 1e5, default=20.0)
    radius_m: float = spec("m", 0.0, 1e4, lo_open=True, default=25.0)
    turn_rad: float = spec("rad", -7.0, 7.0, default=math.pi / 2.0)
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True, default=50.0)

    def __post_init__(self) -> None:
        if self.turn_start_s < self.ramp_s:
            raise ValueError(
                f"turn_start_s ({self.turn_start_s} s) must not come before the end of the speed "
                f"ramp (ramp_s = {self.ramp_s} s): the arc is flown at constant speed"
            )

    @property
    def turn_end_s(self) -> float:
        return self.turn_start_s + self.radius_m * abs(self.turn_rad) / self.speed_m_s

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        v_cruise, r, turn = self.speed_m_s, self.radius_m, self.turn_rad
        s, v, at = ramp_then_cruise(t, v_cruise, self.ramp_s)
        s_turn = float(ramp_then_cruise(np.array([self.turn_start_s]), v_cruise, self.ramp_s)[0][0])
        arc = r * abs(turn)
        side = math.copysign(1.0, turn)  # +1: left (anticlockwise), -1: right
        psi0 = self.heading_rad
        psi1 = psi0 + turn
        # along the arc: course psi(s) = psi0 + side (s - s_turn) / R about the centre
        # c = p_turn + side R n(psi0), n the left normal (-sin, cos)
        p0 = np.asarray(self.start_nwu_m[:2], dtype=float)
        p_turn = p0 + s_turn * np.array([math.cos(psi0), math.sin(psi0)])
        centre = p_turn + side * r * np.array([-math.sin(psi0), math.cos(psi0)])
        p_exit = centre - side * r * np.array([-math.sin(psi1), math.cos(psi1)])
        before, after = s < s_turn, s > s_turn + arc
        psi = np.where(before, psi0, np.where(after, psi1, psi0 + side * (s - s_turn) / r))
        tx, ty, nx, ny = np.cos(psi), np.sin(psi), -np.sin(psi), np.cos(psi)
        # the first line from the start, the arc about its centre, the second line from its exit
        x = np.where(before, p0[0] + s * tx, np.where(after, p_exit[0] + (s - s_turn - arc) * tx,
                                                       centre[0] - side * r * nx))  # fmt: skip
        y = np.where(before, p0[1] + s * ty, np.where(after, p_exit[1] + (s - s_turn - arc) * ty,
                                                       centre[1] - side * r * ny))  # fmt: skip
        in_arc = ~(before | after)
        lateral = np.where(in_arc, side * v * v / r, 0.0)  # along the left normal
        out = np.zeros((t.size, 9))
        out[:, 0] = x
        out[:, 1] = y
        out[:, 2] = self.start_nwu_m[2]
        out[:, 3] = tx * v
        out[:, 4] = ty * v
        out[:, 6] = tx * at + nx * lateral
        out[:, 7] = ty * at + ny * lateral
        return out


# ---------------------------------------------------------------------------- position step


@dataclass(frozen=True)
class PositionStep(Trajectory):
    """Hover at ``start_nwu_m``, then at ``step_time_s`` move by ``step_nwu_m`` and hover
    there: the step shaped exactly as a waypoint mission shapes the switch from one
    waypoint to the next (:func:`leg_profile`, :func:`rest_to_rest`: a rest-to-rest leg
    with the smootherstep velocity ramp, capped at ``speed_m_s``, peak acceleration
    ``max_acc_m_s2``; the defaults are the missions' cruise speed and acceleration).

    A 5 m step at the defaults (2 m/s, 1 m/s^2) is too short to cruise: it peaks at
    1.63 m/s and takes 6.1 s. The missions' separate climb and descent caps are not
    applied: give a lower ``speed_m_s`` for a vertical step.
    """

    start_nwu_m: tuple[float, float, float] = spec("m", -1e6, 1e6, default=(0.0, 0.0, 20.0))
    step_nwu_m: tuple[float, float, float] = spec("m", -1e4, 1e4, default=(5.0, 0.0, 0.0))
    step_time_s: float = spec("s", 0.0, 1e5, default=10.0)
    speed_m_s: float = spec("m/s", 0.0, 50.0, lo_open=True, default=MISSION_LIMITS.cruise_speed_m_s)
    max_acc_m_s2: float = spec("m/s^2", 0.0, 50.0, lo_open=True, default=MISSION_LIMITS.max_acc_m_s2)
    duration_s: float = spec("s", 0.0, 1e5, lo_open=True, default=40.0)

    @property
    def step_duration_s(self) -> float:
        """How long the move takes (the leg's duration)."""
        return leg_profile(float(np.linalg.norm(self.step_nwu_m)), self.speed_m_s, self.max_acc_m_s2)[2]

    def sample(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=float).reshape(-1)
        step = np.asarray(self.step_nwu_m, dtype=float)
        length = float(np.linalg.norm(step))
        direction = step / length if length > 0.0 else np.zeros(3)
        v, ramp, dur = leg_profile(length, self.speed_m_s, self.max_acc_m_s2)
        s, vel, acc = rest_to_rest(t - self.step_time_s, dur, ramp, v, length)
        out = np.zeros((t.size, 9))
        out[:, 0:3] = np.asarray(self.start_nwu_m) + s[:, None] * direction
        out[:, 3:6] = vel[:, None] * direction
        out[:, 6:9] = acc[:, None] * direction
        return out
