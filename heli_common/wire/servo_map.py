"""Blade pitch [rad] <-> normalised actuator value [-1, 1] <-> PWM [us].

HIL_ACTUATOR_CONTROLS carries each pitch normalised by its configured limits:
n = 2 (theta - lo) / (hi - lo) - 1, so lo -> -1 and hi -> +1 (the centre of travel -> 0);
channels 0..3 are theta_m, theta_t, eps, eta. SERVO_OUTPUT_RAW reports PWM = 1500 + 500 n
(1000..2000 us), the usual hobby-servo calibration.

That is :class:`DirectMap`: one channel per blade pitch, as the paper's model takes them. With
a swashplate (:class:`CcpmMap`, CCPM mixing), channels 0..3 are instead the servos a real head
has: swash servos 1-3 and the tail servo, n = (PWM - 1500) / 500, mixed by the autopilot and
read back to blade pitches by the plant through the same
:class:`heli_common.vehicle.swashplate.Swashplate` that ArduPilot's servo frames go through.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from heli_common.state import FloatArray
from heli_common.vehicle.swashplate import Swashplate

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


def to_pwm_us(pitches_rad: FloatArray, limits: FloatArray | ServoMap) -> FloatArray:
    n = np.clip(as_map(limits).to_normalized(pitches_rad), -1.0, 1.0)
    return np.asarray(np.round(PWM_CENTRE_US + PWM_HALF_RANGE_US * n))


class ServoMap(Protocol):
    """Blade pitches [rad] <-> the normalised values of the four actuator channels."""

    def to_normalized(self, pitches_rad: FloatArray) -> FloatArray: ...

    def from_normalized(self, n: FloatArray) -> FloatArray: ...


@dataclass(frozen=True)
class DirectMap:
    """One channel per blade pitch, normalised by the airframe's limits (the default)."""

    limits: FloatArray

    def to_normalized(self, pitches_rad: FloatArray) -> FloatArray:
        return to_normalized(pitches_rad, self.limits)

    def from_normalized(self, n: FloatArray) -> FloatArray:
        return from_normalized(n, self.limits)


@dataclass(frozen=True)
class CcpmMap:
    """CCPM: the channels are swash servos 1-3 and the tail servo (PWM = 1500 + 500 n)."""

    swash: Swashplate

    def to_normalized(self, pitches_rad: FloatArray) -> FloatArray:
        pwm = self.swash.pwm_from_pitches(pitches_rad)  # clipped to the head's and servos' limits
        return np.asarray((pwm - PWM_CENTRE_US) / PWM_HALF_RANGE_US)

    def from_normalized(self, n: FloatArray) -> FloatArray:
        pwm = PWM_CENTRE_US + PWM_HALF_RANGE_US * np.asarray(n, dtype=float)
        return self.swash.pitches_from_pwm(pwm).as_array()


def as_map(limits_or_map: FloatArray | ServoMap) -> ServoMap:
    """A servo map from the airframe's limits (DirectMap) or a map as it is."""
    if isinstance(limits_or_map, np.ndarray):
        return DirectMap(limits_or_map)
    return limits_or_map
