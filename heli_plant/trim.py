"""Trim and linearisation of either plant, from the compiled derivative (no air, no servos).

:func:`trim` finds the controls and attitude that hold steady level flight at a given
airspeed (hover at 0): the rigid body's accelerations and, on the rotor plant, the
flapping and rotor-speed derivatives are zero, the rotor at its governed speed.
:func:`linearize` differentiates the same derivative numerically about a trim (central
differences) into ``A``, ``B`` with named states and inputs, and names the modes by the
states their eigenvectors move most. Both call the very function the plant integrates
(:func:`heli_plant.world.model.derivative_in_air`), so the linear model is the
flown model's.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from heli_common.kinematics import rot_body_to_earth
from heli_common.state import (
    N_STATE,
    P_X,
    PHI,
    PITCH_NAMES,
    Q_Y,
    R_Z,
    STATE_NAMES,
    THETA,
    THETA_M,
    THETA_T,
    U_F,
    V_L,
    W_U,
    Z_U,
    FloatArray,
)
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.plant_model import PlantModel
from heli_plant import rotor
from heli_plant.vehicle import VehicleModel, build_vehicle
from heli_plant.world.model import (
    CALM_AIR,
    N_WS,
    WS_GOVERNOR_SET,
    WS_LAM_MAIN,
    WS_LAM_TAIL,
    derivative_in_air,
    world_parameters,
)

TRIM_ALTITUDE_M = 20.0  # out of ground effect


@dataclass(frozen=True)
class PlantFunction:
    """dx/dt of a plant with the world off: ``f(x, u)`` over the augmented state (the rigid
    body, then the rotor plant's states)."""

    model: PlantModel
    airframe: Airframe
    constants: PlantConstants
    rotor: rotor.RotorConstants
    wp: FloatArray = field(repr=False)
    vehicle: VehicleModel | None = None  # a model of the user's: its own derivative

    @classmethod
    def build(cls, model: PlantModel, design: Airframe) -> PlantFunction:
        af = design if model.rotor is None else model.rotor.airframe()
        g = rotor.OFF if model.rotor is None else rotor.rotor_constants(model.rotor, af)
        from heli_common.world.config import World

        vehicle = None if model.vehicle is None else build_vehicle(model.vehicle, design)
        return cls(model, af, af.constants(), g, world_parameters(World()), vehicle)

    @property
    def n_state(self) -> int:
        return N_STATE + (rotor.N_ROTOR if self.rotor.on else 0)

    @property
    def state_names(self) -> tuple[str, ...]:
        return STATE_NAMES + (rotor.ROTOR_STATE.names if self.rotor.on else ())

    def __call__(self, x: FloatArray, u: FloatArray) -> FloatArray:
        if self.vehicle is not None:
            xa, ua = np.asarray(x, dtype=float), np.asarray(u, dtype=float)
            return np.asarray(self.vehicle.derivative(0.0, xa, ua))
        ws = np.zeros(N_WS)
        ws[WS_LAM_MAIN] = ws[WS_LAM_TAIL] = 0.05
        ws[WS_GOVERNOR_SET] = self.rotor.omega_c
        return derivative_in_air(0.0, np.asarray(x, dtype=float), np.asarray(u, dtype=float), self.constants,
                                 CALM_AIR, np.zeros(3), self.wp, ws, self.rotor)  # fmt: skip

    def throttle(self, x: FloatArray, u: FloatArray) -> float:
        """The governor's throttle at ``x`` (rotor plant; NaN for the paper's)."""
        if not self.rotor.on:
            return math.nan
        v = x[U_F : W_U + 1]
        g = self.rotor
        return rotor.rotor_loads(np.asarray(x, dtype=float), np.asarray(u, dtype=float), self.constants,
                                 g, v[0], v[1], v[2], 0.05, 0.05, N_STATE, g.omega_c)[5]  # fmt: skip


@dataclass(frozen=True)
class Trim:
    """A trim: the augmented state ``x`` and the pitches ``u`` [rad] that hold it."""

    plant: str
    speed_m_s: float
    x: FloatArray
    u: FloatArray
    state_names: tuple[str, ...]
    residual_max: float  # the largest |derivative| left (accelerations, rotor rates)
    throttle: float

    def as_dict(self) -> dict[str, object]:
        d: dict[str, object] = {"plant": self.plant, "speed_m_s": self.speed_m_s,
                                "residual_max": self.residual_max}  # fmt: skip
        d.update({f"{n}": float(v) for n, v in zip(PITCH_NAMES, self.u, strict=True)})
        d.update({"phi_rad": float(self.x[PHI]), "theta_rad": float(self.x[THETA])})
        if len(self.x) > N_STATE:
            d.update({n: float(v) for n, v in zip(rotor.ROTOR_STATE.names, self.x[N_STATE:], strict=True)})
            d["throttle"] = self.throttle
        return d


def _state(
    fn: PlantFunction, z: FloatArray, speed_m_s: float, altitude_m: float
) -> tuple[FloatArray, FloatArray]:
    x = np.zeros(fn.n_state)
    x[Z_U] = altitude_m
    x[PHI], x[THETA] = z[0], z[1]
    u = np.array(z[2:6])
    rt = rot_body_to_earth(x[PHI], x[THETA], 0.0)
    x[U_F : W_U + 1] = rt.T @ np.array([speed_m_s, 0.0, 0.0])  # level flight north, heading north
    if fn.rotor.on:
        x[N_STATE + rotor.A1], x[N_STATE + rotor.B1] = z[6], z[7]
        x[N_STATE + rotor.OMEGA_R] = fn.rotor.omega_c
        x[N_STATE + rotor.GOV_INT] = z[8]
    return x, u


_RESIDUAL = (U_F, V_L, W_U, P_X, Q_Y, R_Z)


def _residual(fn: PlantFunction, z: FloatArray, speed_m_s: float, altitude_m: float) -> FloatArray:
    x, u = _state(fn, z, speed_m_s, altitude_m)
    dx = fn(x, u)
    r = [dx[i] for i in _RESIDUAL]
    if fn.rotor.on:
        r += [dx[N_STATE + rotor.A1], dx[N_STATE + rotor.B1], dx[N_STATE + rotor.OMEGA_R]]
    return np.array(r)


def trim(
    model: PlantModel, design: Airframe, speed_m_s: float = 0.0, altitude_m: float = TRIM_ALTITUDE_M,
    guess: FloatArray | None = None,
) -> Trim:  # fmt: skip
    """Steady level flight north at ``speed_m_s`` [m/s] (0: hover), ``altitude_m`` above the
    ground. Unknowns: roll, pitch, the four pitches (and the flapping and the governor's
    integral on the rotor plant). Raises ValueError if no trim is found."""
    fn = PlantFunction.build(model, design)
    n = 9 if fn.rotor.on else 6
    z0 = np.zeros(n) if guess is None else np.asarray(guess, dtype=float)
    if guess is None and fn.vehicle is not None:
        z0 = np.asarray(fn.vehicle.trim_guess(), dtype=float)
    elif guess is None:
        z0[2 + THETA_M], z0[2 + THETA_T] = 0.1, 0.15
        if fn.rotor.on:
            z0[8] = 0.4 / max(fn.rotor.ki, 1e-9)
    sol = least_squares(lambda z: _residual(fn, z, speed_m_s, altitude_m), z0, xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, max_nfev=2000)  # fmt: skip
    x, u = _state(fn, sol.x, speed_m_s, altitude_m)
    res = float(np.max(np.abs(_residual(fn, sol.x, speed_m_s, altitude_m))))
    if not res < 1e-8:
        raise ValueError(f"{model.name}: no trim at {speed_m_s} m/s (residual {res:.2e})")
    own = model.rotor is None and model.vehicle is None  # the paper's, by its kind
    return Trim(model.kind if own else model.name, speed_m_s, x, u, fn.state_names, res,
                fn.throttle(x, u))  # fmt: skip


@functools.lru_cache(maxsize=16)
def hover_rotor_state(model: PlantModel, design: Airframe) -> tuple[float, ...]:
    """The rotor plant's states in hover trim: where a flight's rotor starts."""
    t = trim(model, design)
    return tuple(float(v) for v in t.x[N_STATE:])


@dataclass(frozen=True)
class Mode:
    """One mode of a linear model: an eigenvalue (the upper one of a complex pair)."""

    eigenvalue: complex
    natural_frequency_rad_s: float
    damping: float
    dominant: tuple[str, ...]  # the states its eigenvector moves most (scaled)
    name: str


@dataclass(frozen=True)
class Linearization:
    """``dx' = A dx + B du`` about ``trim``; ``modes`` from A's eigenvalues."""

    trim: Trim
    a: FloatArray
    b: FloatArray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    modes: tuple[Mode, ...]


# typical sizes that make eigenvector components comparable (m/s, rad, rad/s, rad/s of rotor)
_SCALE = {"u_m_s": 1.0, "v_m_s": 1.0, "w_m_s": 1.0, "phi_rad": 0.1, "theta_rad": 0.1, "psi_rad": 0.1,
          "p_rad_s": 1.0, "q_rad_s": 1.0, "r_rad_s": 1.0, "a1_rad": 0.05, "b1_rad": 0.05,
          "omega_rad_s": 10.0, "governor_int_rad": 10.0}  # fmt: skip


def _mode_name(dom: tuple[str, ...], wn: float) -> str:
    s = set(dom)
    if s & {"a1_rad", "q_rad_s"} and "a1_rad" in s:
        return "rotor-body pitch (flapping a1, q)"
    if s & {"b1_rad", "p_rad_s"} and "b1_rad" in s:
        return "rotor-body roll (flapping b1, p)"
    if s & {"omega_rad_s", "governor_int_rad"}:
        return "rotor speed (governor)"
    if dom[0] == "w_m_s":
        return "heave"
    if dom[0] in ("r_rad_s", "psi_rad"):
        return "yaw"
    if s & {"u_m_s", "theta_rad", "q_rad_s"}:
        return "longitudinal (pitch/surge)"
    if s & {"v_m_s", "phi_rad", "p_rad_s"}:
        return "lateral (roll/sway)"
    return "+".join(dom)


def jacobian(f: Callable[[FloatArray], FloatArray], z0: FloatArray, rel_step: float = 1e-6) -> FloatArray:
    """Central differences of ``f`` at ``z0``, each step ``rel_step`` x max(1, |z0_j|)."""
    y0 = f(z0)
    jac = np.empty((y0.size, z0.size))
    for j in range(z0.size):
        h = rel_step * max(1.0, abs(z0[j]))
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        jac[:, j] = (f(zp) - f(zm)) / (2.0 * h)
    return jac


def linearize(tr: Trim, model: PlantModel, design: Airframe, rel_step: float = 1e-6) -> Linearization:
    """Central differences of the compiled derivative about ``tr`` (steps ``rel_step`` x
    max(1, |value|)); the position states are kept (their rows are kinematics)."""
    fn = PlantFunction.build(model, design)
    x0, u0 = tr.x, tr.u
    a = jacobian(lambda x: fn(x, u0), x0, rel_step)
    b = jacobian(lambda u: fn(x0, u), u0, rel_step)
    return Linearization(tr, a, b, fn.state_names, PITCH_NAMES, _modes(a, fn.state_names))


def _modes(a: FloatArray, names: tuple[str, ...]) -> tuple[Mode, ...]:
    """The modes of the dynamics without position and heading (their integrators are zero
    eigenvalues of no interest), slowest first."""
    keep = [i for i, nm in enumerate(names) if nm not in ("x_m", "y_m", "z_m", "psi_rad")]
    sub = a[np.ix_(keep, keep)]
    sub_names = tuple(names[i] for i in keep)
    scale = np.array([_SCALE.get(nm, 1.0) for nm in sub_names])
    lam, vec = np.linalg.eig(sub)
    modes = []
    for k in np.argsort(np.abs(lam)):
        ev = complex(lam[k])
        if ev.imag < -1e-9:
            continue
        mag = np.abs(vec[:, k]) / scale
        order = np.argsort(mag)[::-1]
        dom = tuple(sub_names[i] for i in order[:2] if mag[i] > 0.2 * mag[order[0]])
        wn = abs(ev)
        zeta = -ev.real / wn if wn > 0 else 1.0
        modes.append(Mode(ev, wn, zeta, dom, _mode_name(dom, wn)))
    return tuple(modes)
