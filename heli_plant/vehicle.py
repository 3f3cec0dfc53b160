"""The plant contract, as ArduPilot's SITL ``Aircraft``: one base class, each vehicle model
a subclass, registered by name.

A vehicle model is its parameters (the airframe it is built on, and whatever it adds), its
derivative ``f(t, x, u)`` of the 12 rigid-body states (heli_common.state's order: earth NWU
position, body FLU velocity, ZYX Euler angles, body FLU rates) with the blade pitches ``u``
held, and its trim's first guess. The base class gives it the rest: the
integrator (RK4, the same stages and sums as the compiled plant's), the ground and the
input guards (:class:`heli_plant.model.Plant`), the sim link and the plant process, trim
and linearisation (:mod:`heli_plant.trim`). Pure: no I/O, no clock.

The plants by name: ``paper`` and ``gavrilets`` are the bench's own, flown by its compiled
world step (the world's air, servos and sensors around them); :class:`PaperPlant` is the
paper's model through this contract (the reference a model of yours is checked against).
A model of yours flies by ``module:Class`` or ``file.py:Class``, or by the name its package
registers in the entry point group ``heli_tlc_sitl.plants``; it flies the ideal world (a
world's effects or sensors around it are refused, by name, not ignored: the bench's sensor
models compute the specific force from the paper's own loads, so they would measure the
wrong vehicle).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from heli_common import user_class
from heli_common.config import ConfigError
from heli_common.state import N_PITCH, N_STATE, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import PLANT_ENTRY_POINT_GROUP, PLANT_KINDS
from heli_plant import dynamics
from heli_plant.contact import apply_ground_contact


class VehicleModel(ABC):
    """One vehicle model (see the module). Subclass it, give it a ``name`` and a
    :meth:`derivative`; the constructor takes the design airframe the scenario names."""

    name: ClassVar[str] = ""

    def __init__(self, airframe: Airframe) -> None:
        self.airframe = airframe

    @abstractmethod
    def derivative(self, t_s: float, x: FloatArray, u: FloatArray) -> FloatArray:
        """dx/dt (12,) at state ``x`` (12,) with the pitches ``u`` [rad] (theta_m, theta_t,
        eps, eta) held."""

    def trim_guess(self) -> FloatArray:
        """Where trim starts: (phi, theta, theta_m, theta_t, eps, eta) [rad]."""
        return np.array([0.0, 0.0, 0.1, 0.15, 0.0, 0.0])

    def step(self, t_s: float, x: FloatArray, u: FloatArray, dt_s: float, substeps: int = 1) -> FloatArray:
        """The state after ``dt_s`` with ``u`` held: RK4 in ``substeps`` steps, each sum in
        the order the compiled plant's evaluates it (heli_plant.world.model.world_plant_step)."""
        h = dt_s / substeps
        half, sixth = 0.5 * h, h / 6.0
        y = np.array(x, dtype=float)
        for k in range(substeps):
            tk = t_s + k * h
            k1 = self.derivative(tk, y, u)
            k2 = self.derivative(tk + 0.5 * h, y + half * k1, u)
            k3 = self.derivative(tk + 0.5 * h, y + half * k2, u)
            k4 = self.derivative(tk + h, y + h * k3, u)
            y = y + sixth * (((k1 + 2.0 * k2) + 2.0 * k3) + k4)
        return y

    def advance(
        self, t_s: float, x: FloatArray, u: FloatArray, dt_s: float, substeps: int, contact: bool
    ) -> tuple[FloatArray, bool]:
        """:meth:`step`, then the ground (the paper plant's flat ground at z = 0): the new
        state and whether the vehicle rests on the ground."""
        y = self.step(t_s, x, u, dt_s, substeps)
        if not y.shape == (N_STATE,):
            raise ValueError(f"plant {self.name or type(self).__name__}: derivative gave shape {y.shape}, "
                             f"not ({N_STATE},)")  # fmt: skip
        on_ground = bool(apply_ground_contact(y, np.asarray(x, dtype=float))) if contact else False
        return y, on_ground


class PaperPlant(VehicleModel):
    """Zhu & Huo's model, equations (7)-(13), through this contract: the same derivative the
    compiled plant integrates (:func:`heli_plant.dynamics.derivative`)."""

    name = "paper (Python)"

    def __init__(self, airframe: Airframe) -> None:
        super().__init__(airframe)
        self.constants = airframe.constants()

    def derivative(self, t_s: float, x: FloatArray, u: FloatArray) -> FloatArray:
        return np.asarray(dynamics.derivative(t_s, x, u, self.constants))


def vehicle_class(spec: str) -> type[VehicleModel]:
    """The model a registered name, ``module:Class`` or ``file.py:Class`` names, checked to keep
    the contract; :class:`ConfigError` names what is wrong."""
    if spec in PLANT_KINDS:
        raise ConfigError(f"plant {spec!r} is the bench's own: it flies by its compiled world step")
    names = user_class.registered(PLANT_ENTRY_POINT_GROUP, PLANT_KINDS)
    cls = user_class.load_class(names.get(spec, spec), "plant")
    if not (isinstance(cls, type) and issubclass(cls, VehicleModel)):
        raise ConfigError(f"plant {spec!r}: {cls.__name__} is not a heli_plant.vehicle.VehicleModel")
    return cls


def build_vehicle(spec: str, airframe: Airframe) -> VehicleModel:
    """The model, built on the design ``airframe``, its derivative tried once at hover (a
    model that cannot answer a state is refused here, not on its first step)."""
    model: Any = vehicle_class(spec)(airframe)
    x = np.zeros(N_STATE)
    x[2] = 20.0
    dx = np.asarray(model.derivative(0.0, x, np.zeros(N_PITCH)), dtype=float)
    if dx.shape != (N_STATE,):
        raise ConfigError(f"plant {spec!r}: derivative returned shape {dx.shape}, not ({N_STATE},)")
    return model  # type: ignore[no-any-return]
