"""Arming and flight modes: what reference the controller follows, and when it must not integrate.

Pure and clock-free: every method takes the time ``t_s`` the runner gives it.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from autopilot.reference import REF_DERIVATIVES, REF_POS, position_reference
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


FOLLOWING = (Mode.AUTO, Mode.LAND, Mode.RTL)  # modes that fly the active trajectory


@dataclass
class FlightStatus:
    armed: bool
    mode: Mode
    landed: bool
    trajectory_t_s: float | None  # time along the active trajectory


def landed(x: FloatArray) -> bool:
    return bool(x[POS][2] < LANDED_ALT_M and np.linalg.norm(x[VEL]) < LANDED_SPEED_M_S)


class Flight:
    """The vehicle's flight state machine (arming, mode, active trajectory)."""

    def __init__(self) -> None:
        self.armed = False
        self.mode = Mode.IDLE
        self.trajectory: Trajectory | None = None
        self.t0_s = 0.0
        self.hold_pos: FloatArray = np.zeros(3)
        self.guided_ref: FloatArray | None = None  # offboard setpoint (NaN where not given)

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
        return True, "disarmed"

    def start(self, trajectory: Trajectory, t_s: float) -> None:
        """Follow ``trajectory`` from its time 0 at ``t_s``."""
        self.trajectory = trajectory
        self.t0_s = t_s
        self.mode = Mode.AUTO

    def hold(self, x: FloatArray) -> None:
        self.hold_pos = x[POS].copy()
        self.mode = Mode.HOLD

    # -- per tick --------------------------------------------------------------------
    def reference(self, t_s: float, x: FloatArray) -> FloatArray | None:
        """The reference for this tick, or None when the rotor must be idle (disarmed)."""
        if not self.armed:
            return None
        if self.mode in FOLLOWING and self.trajectory is not None:
            tau = t_s - self.t0_s
            if tau <= self.trajectory.duration_s:
                return self.trajectory.evaluate_row(tau)
            end = self.trajectory.evaluate_row(self.trajectory.duration_s)
            self.hold_pos = end[REF_POS].copy()
            if self.mode is not Mode.LAND:  # a landing holds on the ground until disarmed
                self.mode = Mode.HOLD
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
