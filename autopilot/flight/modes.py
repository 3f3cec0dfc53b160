"""Arming and flight modes: what reference the controller follows, and when it must not integrate.

Pure and clock-free: every method takes the time ``t_s`` the runner gives it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from autopilot.reference import N_REF, REF_DERIVATIVES, REF_POS, REF_VEL, position_reference
from autopilot.trajectory.base import Trajectory
from heli_common.state import POS, VEL, FloatArray

LANDED_ALT_M = 0.05
LANDED_SPEED_M_S = 0.2


class Mode(enum.Enum):
    IDLE = "IDLE"  # on the ground, waiting
    AUTO = "AUTO"  # following a trajectory (mission or uploaded trajectory)
    HOLD = "HOLD"  # holding a position
    GUIDED = "GUIDED"  # following streamed setpoints (offboard)
    LAND = "LAND"
    RTL = "RTL"
    TAKEOFF = "TAKEOFF"  # climbing to a take-off altitude (a ground station's take-off)


FOLLOWING = (Mode.AUTO, Mode.LAND, Mode.RTL, Mode.TAKEOFF)  # modes that fly the active trajectory


@dataclass
class FlightStatus:
    armed: bool
    mode: Mode
    landed: bool
    trajectory_t_s: float | None  # time along the active trajectory


def landed(x: FloatArray) -> bool:
    return bool(x[POS][2] < LANDED_ALT_M and np.linalg.norm(x[VEL]) < LANDED_SPEED_M_S)


@dataclass(frozen=True)
class Brake:
    """From the reference's position and velocity to rest at constant deceleration: the
    segment that makes every switch of reference continuous in position and velocity (a
    reference that stops dead asks the controller for an impossible deceleration)."""

    pos_nwu_m: FloatArray
    vel_nwu_m_s: FloatArray
    acc_m_s2: float

    @property
    def duration_s(self) -> float:
        return float(np.linalg.norm(self.vel_nwu_m_s)) / self.acc_m_s2

    @property
    def stop_nwu_m(self) -> FloatArray:
        return self.pos_nwu_m + 0.5 * self.vel_nwu_m_s * self.duration_s

    def row(self, tau_s: float) -> FloatArray:
        t = min(max(tau_s, 0.0), self.duration_s)
        speed = float(np.linalg.norm(self.vel_nwu_m_s))
        dec = self.vel_nwu_m_s * (self.acc_m_s2 / speed) if speed > 0.0 else np.zeros(3)
        ref = np.zeros(N_REF)
        ref[REF_POS] = self.pos_nwu_m + self.vel_nwu_m_s * t - 0.5 * dec * t * t
        if tau_s < self.duration_s:
            ref[REF_DERIVATIVES] = np.concatenate([self.vel_nwu_m_s - dec * t, -dec])
        return ref


BRAKE_ACC_M_S2 = 0.5  # gentle: about 0.05 rad of tilt


class FlightStateMachine:
    """The vehicle's flight state machine (arming, mode, active trajectory).

    Every switch of reference starts where the last reference was: a new trajectory or a
    hold begins with a :class:`Brake` from the last reference's position and velocity when
    it was moving, so the reference is continuous in position and velocity."""

    def __init__(self, brake_acc_m_s2: float = BRAKE_ACC_M_S2) -> None:
        self.armed = False
        self.mode = Mode.IDLE
        self.trajectory: Trajectory | None = None
        self.t0_s = 0.0
        self.hold_pos: FloatArray = np.zeros(3)
        self.guided_ref: FloatArray | None = None  # offboard setpoint (NaN where not given)
        self.brake_acc_m_s2 = brake_acc_m_s2
        self.last_ref: FloatArray | None = None  # the reference of the latest tick ...
        self.last_ref_t_s = 0.0  # ... and its time
        self.brake: Brake | None = None
        self.brake_t0_s = 0.0

    # -- transitions -----------------------------------------------------------------
    def arm(self) -> tuple[bool, str]:
        if self.armed:
            return True, "already armed"
        if self.trajectory is None and self.mode is not Mode.GUIDED:
            return False, "no trajectory or mission loaded"
        self.armed = True
        return True, "armed"

    def disarm(self, x: FloatArray, force: bool = False) -> tuple[bool, str]:
        if not force and not landed(x):
            return False, "refused: airborne (land first)"
        self.armed = False
        self.mode = Mode.IDLE
        self.last_ref = self.brake = None
        return True, "disarmed"

    def _start_brake(self, t_s: float) -> float:
        """Brake from the last reference if it was moving; the time until it is at rest."""
        ref = self.last_ref
        self.brake = None
        if ref is None:
            return 0.0
        vel = np.nan_to_num(ref[REF_VEL])
        if float(np.linalg.norm(vel)) < 1e-6:
            return 0.0
        self.brake = Brake(ref[REF_POS].copy(), vel, self.brake_acc_m_s2)
        self.brake_t0_s = self.last_ref_t_s  # the brake continues the last reference
        return self.brake.duration_s - (t_s - self.last_ref_t_s)

    def here(self, x: FloatArray) -> FloatArray:
        """Where a new reference should start: where the last one comes to rest (the
        measured position when there is none)."""
        ref = self.last_ref
        if ref is None:
            return x[POS].copy()
        vel = np.nan_to_num(ref[REF_VEL])
        if not np.any(vel):
            return ref[REF_POS].copy()
        return Brake(ref[REF_POS].copy(), vel, self.brake_acc_m_s2).stop_nwu_m

    def start(self, trajectory: Trajectory, t_s: float) -> None:
        """Follow ``trajectory`` from its time 0 at ``t_s``, after braking the last
        reference to rest (at :meth:`here`, where the trajectory should begin)."""
        self.trajectory = trajectory
        self.t0_s = t_s + self._start_brake(t_s)
        self.mode = Mode.AUTO

    def hold(self, x: FloatArray, t_s: float | None = None) -> None:
        """Hold where the last reference comes to rest (braking to it), else at ``x``."""
        self.hold_pos = self.here(x)
        if t_s is not None:
            self._start_brake(t_s)
        self.mode = Mode.HOLD

    # -- per tick --------------------------------------------------------------------
    def reference(self, t_s: float, x: FloatArray) -> FloatArray | None:
        """The reference for this tick, or None when the rotor must be idle (disarmed)."""
        ref = self._reference(t_s, x)
        self.last_ref = None if ref is None else ref.copy()
        self.last_ref_t_s = t_s
        return ref

    def _reference(self, t_s: float, x: FloatArray) -> FloatArray | None:
        if not self.armed:
            return None
        brake = self.brake
        if brake is not None and self.mode is not Mode.GUIDED:
            if t_s - self.brake_t0_s < brake.duration_s:
                return brake.row(t_s - self.brake_t0_s)
            self.brake = None
        if self.mode in FOLLOWING and self.trajectory is not None:
            tau = t_s - self.t0_s
            if tau <= self.trajectory.duration_s:
                return self.trajectory.evaluate_row(tau)
            end_s = self.trajectory.duration_s
            if self.mode is not Mode.LAND:  # a landing holds on the ground until disarmed
                # the trajectory may end moving: brake to rest from its end state
                self.last_ref = self.trajectory.evaluate_row(end_s)
                self.last_ref_t_s = self.t0_s + end_s
                self.hold(x, t_s)
                return self._reference(t_s, x)
            self.hold_pos = self.trajectory.evaluate_row(end_s)[REF_POS].copy()
        if self.mode is Mode.GUIDED and self.guided_ref is not None:
            ref = self.guided_ref.copy()
            ref[REF_DERIVATIVES] = np.where(np.isnan(ref[REF_DERIVATIVES]), 0.0, ref[REF_DERIVATIVES])
            return ref
        if self.mode is Mode.IDLE:
            self.hold(x)
        return position_reference(self.hold_pos)

    def hold_integrators(self, x: FloatArray, ref: FloatArray) -> bool:
        """On the ground with the command at or below it, integrating would only wind up."""
        return landed(x) and ref[REF_POS][2] <= LANDED_ALT_M

    def status(self, t_s: float, x: FloatArray) -> FlightStatus:
        tau = t_s - self.t0_s if self.mode in FOLLOWING else None
        return FlightStatus(self.armed, self.mode, landed(x), tau)
