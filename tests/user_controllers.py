"""Controllers written as a user would (autopilot.user_controller's contract), for the tests:
one that wraps the compiled TLC (so a flight from Python can be compared bit for bit), and
the faulty ones the bench must survive."""

from __future__ import annotations

import numpy as np

from autopilot.tlc.controller import TLController
from autopilot.tlc.gains import Gains
from heli_common.state import FloatArray
from heli_common.vehicle.airframe import Airframe


class WrappedTLC:
    """The paper's TLC called from Python: the compiled loop's own law, outside it."""

    name = "TLC from Python"

    def __init__(self, airframe: Airframe, rate_hz: float) -> None:
        self.c = TLController(airframe, Gains.load("gains_paper.toml"), rate_hz)

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
        return self.c.update(t_s, state, reference)

    def reset(self) -> None:
        self.c.reset()


class Faulty(WrappedTLC):
    """The TLC until ``t_fault_s``, then a fault every tick: NaN, an exception or a wrong
    shape, by the class attribute ``fault``."""

    fault = "nan"
    t_fault_s = 5.0

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
        u = super().update(t_s, state, reference)
        if t_s < self.t_fault_s:
            return u
        if self.fault == "raise":
            raise RuntimeError("a bug in the user's law")
        if self.fault == "shape":
            return np.zeros(3)
        return np.full(4, np.nan)


class RaisesAfter5s(Faulty):
    fault = "raise"


class WrongShapeAfter5s(Faulty):
    fault = "shape"


class NoReset:
    def __init__(self, airframe: Airframe, rate_hz: float) -> None:
        pass

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
        return np.zeros(4)
