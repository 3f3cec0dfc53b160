"""Airframe parameters: frozen dataclasses loaded from TOML, and the flat constants the JIT uses."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from heli_common.config import load, spec


@dataclass(frozen=True)
class Body:
    mass_kg: float = spec("kg", 0.0, 1000.0, lo_open=True)
    gravity_m_s2: float = spec("m/s^2", 0.0, 30.0, lo_open=True)
    ixx_kg_m2: float = spec("kg m^2", 0.0, 1e3, lo_open=True)
    iyy_kg_m2: float = spec("kg m^2", 0.0, 1e3, lo_open=True)
    izz_kg_m2: float = spec("kg m^2", 0.0, 1e3, lo_open=True)
    ixz_kg_m2: float = spec("kg m^2", -1e3, 1e3)
    main_hub_above_cg_m: float = spec("m", -5.0, 5.0)  # hm
    main_hub_ahead_cg_m: float = spec("m", -5.0, 5.0)  # lm
    tail_hub_above_cg_m: float = spec("m", -5.0, 5.0)  # ht
    tail_hub_behind_cg_m: float = spec("m", 0.0, 20.0, lo_open=True)  # lt

    def __post_init__(self) -> None:
        # J must be positive definite: the xz block needs Ixx Izz > Ixz^2.
        if self.ixx_kg_m2 * self.izz_kg_m2 <= self.ixz_kg_m2**2:
            raise ValueError("inertia not positive definite: need ixx*izz > ixz^2")


@dataclass(frozen=True)
class Air:
    density_kg_m3: float = spec("kg/m^3", 0.0, 5.0, lo_open=True)
    profile_drag_coeff: float = spec("", 0.0, 0.2)  # delta in qc = delta/8 + ...


@dataclass(frozen=True)
class Rotor:
    radius_m: float = spec("m", 0.0, 20.0, lo_open=True)
    chord_m: float = spec("m", 0.0, 2.0, lo_open=True)
    blades: int = spec("", 1, 12)
    lift_slope_per_rad: float = spec("1/rad", 0.0, 10.0, lo_open=True)
    speed_rad_s: float = spec("rad/s", 0.0, 5000.0, lo_open=True)

    @property
    def solidity(self) -> float:
        return self.blades * self.chord_m / (math.pi * self.radius_m)

    @property
    def disc_area_m2(self) -> float:
        return math.pi * self.radius_m**2

    def thrust_scale_n(self, density_kg_m3: float) -> float:
        """rho s A Omega^2 R^2: thrust per unit thrust coefficient [N]."""
        return density_kg_m3 * self.solidity * self.disc_area_m2 * (self.speed_rad_s * self.radius_m) ** 2

    def torque_scale_n_m(self, density_kg_m3: float) -> float:
        """rho s A Omega^2 R^3: torque per unit torque coefficient [N m]."""
        return self.thrust_scale_n(density_kg_m3) * self.radius_m


@dataclass(frozen=True)
class PitchLimits:
    theta_m_rad: tuple[float, float] = spec("rad", -0.6, 0.6)
    theta_t_rad: tuple[float, float] = spec("rad", -0.8, 0.8)
    eps_rad: tuple[float, float] = spec("rad", -0.5, 0.5)
    eta_rad: tuple[float, float] = spec("rad", -0.5, 0.5)

    def __post_init__(self) -> None:
        for name in ("theta_m_rad", "theta_t_rad", "eps_rad", "eta_rad"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name}: lower limit {lo} must be below upper limit {hi}")

    def as_tuple(self) -> tuple[tuple[float, float], ...]:
        """(lo, hi) per pitch in the order theta_m, theta_t, eps, eta."""
        return (self.theta_m_rad, self.theta_t_rad, self.eps_rad, self.eta_rad)


@dataclass(frozen=True)
class Airframe:
    name: str = spec()
    body: Body = spec()
    air: Air = spec()
    main_rotor: Rotor = spec()
    tail_rotor: Rotor = spec()
    limits: PitchLimits = spec()

    @classmethod
    def load(cls, path: str | Path = "xcell60.toml") -> Airframe:
        return load(cls, path)

    def constants(self) -> PlantConstants:
        """Flat float constants for the compiled model (and the model-based controller)."""
        b, rho = self.body, self.air.density_kg_m3
        m, t = self.main_rotor, self.tail_rotor
        det_xz = b.ixx_kg_m2 * b.izz_kg_m2 - b.ixz_kg_m2**2
        return PlantConstants(
            mass_kg=b.mass_kg,
            gravity_m_s2=b.gravity_m_s2,
            ixx=b.ixx_kg_m2,
            iyy=b.iyy_kg_m2,
            izz=b.izz_kg_m2,
            ixz=b.ixz_kg_m2,
            inv_ixx=b.izz_kg_m2 / det_xz,
            inv_iyy=1.0 / b.iyy_kg_m2,
            inv_izz=b.ixx_kg_m2 / det_xz,
            inv_ixz=b.ixz_kg_m2 / det_xz,
            hm=b.main_hub_above_cg_m,
            lm=b.main_hub_ahead_cg_m,
            ht=b.tail_hub_above_cg_m,
            lt=b.tail_hub_behind_cg_m,
            delta=self.air.profile_drag_coeff,
            a_m=m.lift_slope_per_rad,
            s_m=m.solidity,
            thrust_scale_m=m.thrust_scale_n(rho),
            torque_scale_m=m.torque_scale_n_m(rho),
            a_t=t.lift_slope_per_rad,
            s_t=t.solidity,
            thrust_scale_t=t.thrust_scale_n(rho),
            torque_scale_t=t.torque_scale_n_m(rho),
        )


class PlantConstants(NamedTuple):
    """Everything the compiled plant needs, as plain floats (J^-1 precomputed; Ixz couples x-z)."""

    mass_kg: float
    gravity_m_s2: float
    ixx: float
    iyy: float
    izz: float
    ixz: float
    inv_ixx: float
    inv_iyy: float
    inv_izz: float
    inv_ixz: float
    hm: float
    lm: float
    ht: float
    lt: float
    delta: float
    a_m: float
    s_m: float
    thrust_scale_m: float
    torque_scale_m: float
    a_t: float
    s_t: float
    thrust_scale_t: float
    torque_scale_t: float
