"""What the sensors' errors truly are at a time: for estimator diagnostics (NEES) in a
simulation that knows them; no autopilot reads this."""

from __future__ import annotations

from heli_common.jit import njit
from heli_common.state import FloatArray
from heli_common.world.sensors import Vec3
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
def _bias3(params: FloatArray, state: FloatArray, at: int, walk: int, jump: int, fault: bool) -> Vec3:
    """One sensor's bias: constant + random walk (+ the fault's step)."""
    b0, b1, b2 = params[at] + state[walk], params[at + 1] + state[walk + 1], params[at + 2] + state[walk + 2]
    if fault:
        return b0 + params[jump], b1 + params[jump + 1], b2 + params[jump + 2]
    return b0, b1, b2


@njit
def imu_bias_truth(t_s: float, params: FloatArray, state: FloatArray) -> tuple[Vec3, Vec3]:
    """The gyro and accelerometer biases (body FLU) of the IMU's latest sample at ``t_s``:
    the constant bias, the random walk so far, and the step after a fault's start. Values,
    not arrays: a flight asks every tick."""
    fault = t_s >= params[SNP_IMU_FAULT_T]
    return (_bias3(params, state, SNP_GYRO_BIAS, SNS_GYRO_WALK, SNP_GYRO_STEP, fault),
            _bias3(params, state, SNP_ACCEL_BIAS, SNS_ACCEL_WALK, SNP_ACCEL_STEP, fault))  # fmt: skip
