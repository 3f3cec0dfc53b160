"""Trajectories: the contract (position and, where known, derivatives at time t) and its kinds."""

from autopilot.reference import Reference
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.factory import trajectory_from_table

__all__ = ["Reference", "Trajectory", "trajectory_from_table"]
