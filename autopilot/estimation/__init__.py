"""State estimation for the autopilot: per-axis linear Kalman filters for position and
velocity with delayed-GPS fusion, AHRS attitude and gyro rates (docs/estimator.md)."""

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.kf import Estimator, Health, Innovations

__all__ = ["Estimator", "EstimatorConfig", "Health", "Innovations"]
