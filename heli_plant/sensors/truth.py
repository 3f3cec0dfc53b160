"""What the sensors' errors truly are at a time: for estimator diagnostics (NEES) in a
simulation that knows them; no autopilot reads this."""

from __future__ import annotations

import numpy as np

from heli_common.jit import njit
from heli_common.state import FloatArray
from heli_plant.sensors.model import (
    SNP_ACCEL_BIAS,
    SNP_ACCEL_STEP,
    SNP_GYRO_BIAS,
    SNP_GYRO_STEP,
    SNP_IMU_FAULT_T,
    SNS_ACCEL_WALK,
    SNS_GYRO_WALK,
)


@njit
def imu_bias_truth(t_s: float, params: FloatArray, state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The gyro and accelerometer biases (body FLU) of the IMU's latest sample at ``t_s``:
    the constant bias, the random walk so far, and the step after a fault's start."""
    gyro = np.empty(3)
    accel = np.empty(3)
    fault = t_s >= params[SNP_IMU_FAULT_T]
    for i in range(3):
        gyro[i] = params[SNP_GYRO_BIAS + i] + state[SNS_GYRO_WALK + i]
        accel[i] = params[SNP_ACCEL_BIAS + i] + state[SNS_ACCEL_WALK + i]
        if fault:
            gyro[i] += params[SNP_GYRO_STEP + i]
            accel[i] += params[SNP_ACCEL_STEP + i]
    return gyro, accel
