"""Which plant flies: the paper's model, or Gavrilets' X-Cell with its rotor (``--plant``).

``paper`` is Zhu & Huo's equations (7)-(13): the controller's own design model, cyclic
tilting the thrust instantly. ``gavrilets`` (``configs/plant/xcell60-gavrilets.toml``) is
the nonlinear X-Cell 60 model of Gavrilets, Mettler & Feron (AIAA GNC 2001) and Gavrilets'
thesis (MIT 2003): first-order tip-path-plane flapping with the Bell-Hiller bar's time
constant, hub spring, governed rotor speed, tail rotor with fin blockage, horizontal
stabilizer, fuselage drag and ground effect. The physics is in
:mod:`heli_plant.rotor`; this module only reads the file into frozen dataclasses, so
the autopilot's analysis tools, the campaigns and the command line can name the same plant.
The sources and what was and was not verified against them: ``docs/rotor-plant.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from heli_common.config import CONFIG_DIR, ConfigError, load, spec
from heli_common.user_class import absolute_spec, is_class_spec, registered
from heli_common.vehicle.airframe import Air, Airframe, Body, PitchLimits, Rotor

PLANT_KINDS = ("paper", "gavrilets")
# other packages' plants by name (heli_plant.vehicle.VehicleModel subclasses), as controllers
PLANT_ENTRY_POINT_GROUP = "heli_tlc_sitl.plants"
PLANT_HELP = ("the plant that flies: paper (Zhu & Huo's model, the controller's own design model; "
              "default), gavrilets (configs/plant/xcell60-gavrilets.toml: rotor flapping, hub spring, "
              "governed rotor speed), a plant file, a plant another package registers by name (entry "
              f"point group {PLANT_ENTRY_POINT_GROUP}), or your own model as package.module:Class or "
              "path/to/file.py:Class (docs/architecture.md, 'A plant of your own')")  # fmt: skip


@dataclass(frozen=True)
class Flapping:
    """Tip-path-plane flapping, first order, the stabilizer bar folded into one time constant
    ``tau_e = 16 / (lock_number Omega)`` (Gavrilets 2001: gamma_fb)."""

    stabilizer_bar_lock_number: float = spec("", 0.0, 100.0, lo_open=True)
    # steady-state flapping per rad of cyclic blade pitch (A_dlon, B_dlat): the inputs here are
    # the controller's eps/eta in blade-pitch radians (docs/rotor-plant.md, "linkage gains")
    lon_gain_rad_per_rad: float = spec("rad/rad", 0.0, 20.0, lo_open=True)
    lat_gain_rad_per_rad: float = spec("rad/rad", 0.0, 20.0, lo_open=True)
    hub_stiffness_n_m_per_rad: float = spec("N m/rad", 0.0, 1e4)  # K_beta
    blowback_k_mu: float = spec("", 0.0, 10.0)  # K_mu in da1/dmu = 2 K_mu (4 theta/3 - lambda)


@dataclass(frozen=True)
class Engine:
    """Engine and drive: ``Omega' = (P_e/Omega - Q_mr - n_tr Q_tr) / I_rot``, ``P_e = P_max delta_t``."""

    max_power_w: float = spec("W", 0.0, 1e6, lo_open=True)
    rotating_inertia_kg_m2: float = spec("kg m^2", 0.0, 1e3, lo_open=True)  # about the main shaft


@dataclass(frozen=True)
class Governor:
    """PI governor on the rotor speed: ``delta_t = kp e + ki int e``, ``e = Omega_c - Omega``,
    limited to [0, 1] with the integrator held while the limit is pushed (anti-windup)."""

    kp_per_rad_s: float = spec("1/(rad/s)", 0.0, 10.0)
    ki_per_rad: float = spec("1/rad", 0.0, 10.0)


@dataclass(frozen=True)
class Surface:
    """A tail surface: area, lift slope, position behind and above the c.g."""

    area_m2: float = spec("m^2", 0.0, 10.0)
    lift_slope_per_rad: float = spec("1/rad", 0.0, 10.0)
    behind_cg_m: float = spec("m", 0.0, 20.0)
    above_cg_m: float = spec("m", -5.0, 5.0, default=0.0)
    # fraction of the surface in the tail rotor's wake (vertical fin only: blockage)
    tail_rotor_blockage: float = spec("", 0.0, 1.0, default=0.0)


@dataclass(frozen=True)
class Aero:
    """Inflow and fuselage: wake factor of the momentum relation; flat-plate areas."""

    wake_factor: float = spec("", 0.0, 2.0, lo_open=True)  # eta_w
    fuselage_areas_m2: tuple[float, float, float] = spec("m^2", 0.0, 10.0)
    ground_effect: bool = spec(default=True)


@dataclass(frozen=True)
class RotorPlant:
    """A plant file (``configs/plant/*.toml``): the airframe's tables as in an airframe
    file, then the rotor's. ``rotation`` is the main rotor's sense seen from above."""

    name: str = spec()
    kind: str = spec(choices=("gavrilets",))
    rotation: str = spec(choices=("clockwise", "counter-clockwise"))
    body: Body = spec()
    air: Air = spec()
    main_rotor: Rotor = spec()
    tail_rotor: Rotor = spec()
    limits: PitchLimits = spec()
    flapping: Flapping = spec()
    engine: Engine = spec()
    governor: Governor = spec()
    aero: Aero = spec()
    fin: Surface = spec()
    stabilizer: Surface = spec()

    def airframe(self) -> Airframe:
        return Airframe(self.name, self.body, self.air, self.main_rotor, self.tail_rotor, self.limits)

    @property
    def rotation_sign(self) -> float:
        """+1: counter-clockwise from above (the paper's frame), -1: clockwise (the real X-Cell)."""
        return 1.0 if self.rotation == "counter-clockwise" else -1.0

    def tau_e_s(self, omega_rad_s: float | None = None) -> float:
        """The flapping's effective time constant at ``omega_rad_s`` (default: nominal)."""
        om = self.main_rotor.speed_rad_s if omega_rad_s is None else omega_rad_s
        return 16.0 / (self.flapping.stabilizer_bar_lock_number * om)


@dataclass(frozen=True)
class PlantModel:
    """The plant a run flies: ``rotor`` None is the paper's model on ``airframe`` (the
    scenario's design airframe); otherwise Gavrilets' model with its own airframe.
    ``vehicle``: a model of the user's (:class:`heli_plant.vehicle.VehicleModel`), by its
    registered name or ``module:Class``, built on the design airframe."""

    name: str
    rotor: RotorPlant | None = None
    vehicle: str | None = None

    @property
    def kind(self) -> str:
        if self.vehicle is not None:
            return self.vehicle
        return "paper" if self.rotor is None else self.rotor.kind

    @classmethod
    def load(cls, name_or_path: str | Path | None) -> PlantModel:
        """``paper`` (or None), ``gavrilets``, a plant file path, a registered plant's name, or
        ``module:Class`` / ``file.py:Class`` (checked where the plant is built)."""
        if name_or_path is None or str(name_or_path) == "paper":
            return cls("paper")
        s = str(name_or_path)
        if is_class_spec(s) and not s.endswith(".toml"):
            spec = absolute_spec(s)
            return cls(spec, vehicle=spec)
        path = CONFIG_DIR / "plant" / "xcell60-gavrilets.toml" if s == "gavrilets" else Path(s)
        if not path.suffix and not path.is_file():
            names = registered(PLANT_ENTRY_POINT_GROUP, PLANT_KINDS)
            if s in names:
                return cls(s, vehicle=s)
            others = f", a registered plant ({', '.join(sorted(names))})" if names else ""
            raise ConfigError(f"plant {s!r}: expected paper, gavrilets{others}, a plant file (.toml) or "
                              "module:Class")  # fmt: skip
        rp = load(RotorPlant, path)
        return cls(s, rp)


def hover_check(rp: RotorPlant) -> float:
    """The rotor-body pitch mode's natural frequency [rad/s] of the simple check in the
    docs: ``sqrt((K_beta + m g h_mr) / I_yy)`` (first-order flapping, body held level)."""
    b = rp.body
    k = rp.flapping.hub_stiffness_n_m_per_rad + b.mass_kg * b.gravity_m_s2 * b.main_hub_above_cg_m
    return math.sqrt(k / b.iyy_kg_m2)
