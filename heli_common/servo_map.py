"""Blade pitch [rad] <-> normalised actuator value [-1, 1] <-> PWM [us].

HIL_ACTUATOR_CONTROLS carries each pitch normalised by its configured limits:
n = 2 (theta - lo) / (hi - lo) - 1, so lo -> -1 and hi -> +1 (the centre of travel -> 0);
channels 0..3 are theta_m, theta_t, eps, eta. SERVO_OUTPUT_RAW reports PWM = 1500 + 500 n
(1000..2000 us), the usual hobby-servo calibration.
"""

from __future__ import annotations

import numpy as np

from heli_common.state import FloatArray

PWM_CENTRE_US = 1500.0
PWM_HALF_RANGE_US = 500.0


def limits_array(limits: tuple[tuple[float, float], ...]) -> FloatArray:
    return np.array(limits, dtype=float)


def to_normalized(pitches_rad: FloatArray, limits: FloatArray) -> FloatArray:
    lo, hi = limits[:, 0], limits[:, 1]
    return np.asarray(2.0 * (pitches_rad - lo) / (hi - lo) - 1.0)


def from_normalized(n: FloatArray, limits: FloatArray) -> FloatArray:
    lo, hi = limits[:, 0], limits[:, 1]
    return np.asarray(lo + (np.asarray(n) + 1.0) * 0.5 * (hi - lo))


def to_pwm_us(pitches_rad: FloatArray, limits: FloatArray) -> FloatArray:
    n = np.clip(to_normalized(pitches_rad, limits), -1.0, 1.0)
    return np.asarray(np.round(PWM_CENTRE_US + PWM_HALF_RANGE_US * n))
