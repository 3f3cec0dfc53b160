"""Trajectories: the contract (position and, where known, derivatives at time t) and its kinds."""

from autopilot.reference import Reference
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.csv_table import CsvTrajectory, trajectory_from_csv
from autopilot.trajectory.factory import trajectory_from_table

__all__ = ["CsvTrajectory", "Reference", "Trajectory", "trajectory_from_csv", "trajectory_from_table"]
