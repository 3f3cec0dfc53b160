"""The world around the vehicle, as configured: wind, gusts, turbulence, air loads, servos,
model mismatch and injected disturbances. TOML -> frozen dataclasses (``--world FILE``).

Every table and key is optional and every effect is off by default: an empty file (or no
``--world``) is the paper's ideal world, and the plant then runs exactly the code it ran
before the world existed. The physics lives in :mod:`heli_plant.world`; this module
only says what is asked for, so the autopilot's ground-station parameters (``SIM_*``) and
the campaigns can name the same settings. Units are SI unless a name says otherwise
(``_deg``); directions follow ArduPilot's SIM_WIND_* convention: the direction the wind
comes FROM, degrees clockwise from north, and an elevation (90 = pure updraft).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

from heli_common.config import ConfigError, SimParam, load, spec
from heli_common.vehicle.airframe import Airframe
from heli_common.wire.mavlink.wire import f32
from heli_common.world.sensors import (
    SEED_MAX,
    SIM_SENSOR_PARAM_NAMES,
    SIM_SENSOR_PARAMS,
    Sensors,
    sensor_sim_values,
    with_sensor_param,
)

Channels = tuple[float, float, float, float]  # theta_m, theta_t, eps, eta
ZERO4: Channels = (0.0, 0.0, 0.0, 0.0)
ZERO3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Wind:
    """Steady wind (SIM_WIND_SPD, SIM_WIND_DIR, SIM_WIND_DIR_Z)."""

    speed_m_s: float = spec("m/s", 0.0, 100.0, default=0.0)
    from_deg: float = spec("deg", -360.0, 360.0, default=180.0)
    elevation_deg: float = spec("deg", -90.0, 90.0, default=0.0)


@dataclass(frozen=True)
class Turbulence:
    """Continuous Dryden turbulence, MIL-F-8785C low-altitude form: ``w20_m_s`` is the
    wind speed at 20 ft that sets the intensities (sigma_w = 0.1 W20; light, moderate and
    severe are 15, 30 and 45 kt = 7.7, 15.4 and 23.2 m/s). 0 = off."""

    w20_m_s: float = spec("m/s", 0.0, 50.0, default=0.0)
    # the height the scale lengths and intensities are evaluated at (clipped to 3-305 m);
    # 0: the vehicle's initial height above ground
    altitude_m: float = spec("m", 0.0, 1000.0, default=0.0)


@dataclass(frozen=True)
class Gust:
    """A discrete 1-cosine gust (MIL-F-8785C): rises over ``rise_s`` from ``start_s`` to
    ``amplitude_m_s``, holds ``hold_s`` (negative: for ever), falls over ``fall_s``."""

    amplitude_m_s: float = spec("m/s", 0.0, 50.0, default=0.0)
    from_deg: float = spec("deg", -360.0, 360.0, default=180.0)
    elevation_deg: float = spec("deg", -90.0, 90.0, default=0.0)
    start_s: float = spec("s", 0.0, 1e6, default=0.0)
    rise_s: float = spec("s", 0.0, 1e3, default=2.0)
    hold_s: float = spec("s", -1.0, 1e6, default=-1.0)
    fall_s: float = spec("s", 0.0, 1e3, default=2.0)


@dataclass(frozen=True)
class AirLoads:
    """How the air acts on the vehicle. Without it, wind does nothing (the paper's model
    has no aerodynamics but the rotors' hover maps)."""

    # fuselage drag on the air-relative velocity: equivalent flat-plate areas (C_D
    # included) frontal, side, vertical; X-Cell 60 values of Gavrilets, Mettler & Feron
    fuselage: bool = spec(default=False)
    fuselage_areas_m2: tuple[float, float, float] = spec("m^2", 0.0, 10.0, default=(0.10, 0.22, 0.15))
    # momentum/blade-element inflow of both rotors with the air-relative hub velocity
    # (climb, descent, translational lift); in hover it is the paper's map exactly
    rotor_inflow: bool = spec(default=False)
    wake_factor: float = spec("", 0.0, 2.0, lo_open=True, default=1.0)


@dataclass(frozen=True)
class Servos:
    """Per servo, in the order theta_m, theta_t, eps, eta: transport delay, rate limit of
    the blade pitch (0 = none), first-order lag, quantum and dead band (0 = none). The
    position limits are the airframe's."""

    delay_s: Channels = spec("s", 0.0, 1.0, default=ZERO4)
    rate_rad_s: Channels = spec("rad/s", 0.0, 1e3, default=ZERO4)
    tau_s: Channels = spec("s", 0.0, 5.0, default=ZERO4)
    quantum_rad: Channels = spec("rad", 0.0, 0.1, default=ZERO4)
    deadband_rad: Channels = spec("rad", 0.0, 0.1, default=ZERO4)

    @property
    def on(self) -> bool:
        return any(any(v != 0.0 for v in getattr(self, f.name)) for f in dataclasses.fields(self))


@dataclass(frozen=True)
class Mismatch:
    """The plant's airframe against the controller's design airframe: scale factors, or a
    whole second airframe file (``airframe``, then scaled). The controller keeps its own."""

    airframe: str = spec(default="")
    mass: float = spec("x", 0.1, 10.0, default=1.0)
    ixx: float = spec("x", 0.1, 10.0, default=1.0)
    iyy: float = spec("x", 0.1, 10.0, default=1.0)
    izz: float = spec("x", 0.1, 10.0, default=1.0)
    lift_slope_main: float = spec("x", 0.1, 10.0, default=1.0)  # the rotor maps, eqs 16-17
    lift_slope_tail: float = spec("x", 0.1, 10.0, default=1.0)
    rotor_speed_main: float = spec("x", 0.1, 10.0, default=1.0)
    rotor_speed_tail: float = spec("x", 0.1, 10.0, default=1.0)
    hm: float = spec("x", -10.0, 10.0, default=1.0)  # hub geometry
    lm: float = spec("x", -10.0, 10.0, default=1.0)
    ht: float = spec("x", -10.0, 10.0, default=1.0)
    lt: float = spec("x", 0.1, 10.0, default=1.0)

    @property
    def on(self) -> bool:
        return bool(self.airframe) or any(
            getattr(self, f.name) != 1.0 for f in dataclasses.fields(self) if f.name != "airframe"
        )

    def apply(self, design: Airframe, base_dir: Path | None = None) -> Airframe:
        """The plant's airframe: the design one (or the named file) with the scales applied."""
        af = design
        if self.airframe:
            path = Path(self.airframe)
            if base_dir is not None and not path.is_absolute() and (base_dir / path).is_file():
                path = base_dir / path
            af = Airframe.load(path)
        b, m, t = af.body, af.main_rotor, af.tail_rotor
        body = dataclasses.replace(
            b,
            mass_kg=b.mass_kg * self.mass,
            ixx_kg_m2=b.ixx_kg_m2 * self.ixx,
            iyy_kg_m2=b.iyy_kg_m2 * self.iyy,
            izz_kg_m2=b.izz_kg_m2 * self.izz,
            main_hub_above_cg_m=b.main_hub_above_cg_m * self.hm,
            main_hub_ahead_cg_m=b.main_hub_ahead_cg_m * self.lm,
            tail_hub_above_cg_m=b.tail_hub_above_cg_m * self.ht,
            tail_hub_behind_cg_m=b.tail_hub_behind_cg_m * self.lt,
        )
        main = dataclasses.replace(m, lift_slope_per_rad=m.lift_slope_per_rad * self.lift_slope_main,
                                   speed_rad_s=m.speed_rad_s * self.rotor_speed_main)  # fmt: skip
        tail = dataclasses.replace(t, lift_slope_per_rad=t.lift_slope_per_rad * self.lift_slope_tail,
                                   speed_rad_s=t.speed_rad_s * self.rotor_speed_tail)  # fmt: skip
        return dataclasses.replace(af, name=f"{af.name} (plant)", body=body, main_rotor=main, tail_rotor=tail)


@dataclass(frozen=True)
class Disturbance:
    """An injected force and torque, for robustness studies: in the earth (NWU) or body
    (FLU) frame, constant, a step at ``start_s``, or a sinusoid from ``start_s``."""

    frame: str = spec(default="earth", choices=("earth", "body"))
    kind: str = spec(default="constant", choices=("constant", "step", "sine"))
    force_n: tuple[float, float, float] = spec("N", -1e3, 1e3, default=ZERO3)
    torque_n_m: tuple[float, float, float] = spec("N m", -1e3, 1e3, default=ZERO3)
    start_s: float = spec("s", 0.0, 1e6, default=0.0)
    frequency_hz: float = spec("Hz", 0.0, 100.0, default=0.0)

    @property
    def on(self) -> bool:
        return any(v != 0.0 for v in (*self.force_n, *self.torque_n_m))


@dataclass(frozen=True)
class World:
    name: str = spec(default="calm")
    seed: int = spec("", 0, SEED_MAX, default=0)
    wind: Wind = spec(default=Wind())
    turbulence: Turbulence = spec(default=Turbulence())
    gust: Gust = spec(default=Gust())
    air: AirLoads = spec(default=AirLoads())
    servos: Servos = spec(default=Servos())
    mismatch: Mismatch = spec(default=Mismatch())
    disturbance: Disturbance = spec(default=Disturbance())
    # what the autopilot measures (off: it is handed the true state, as in the paper)
    sensors: Sensors = spec(default=Sensors())
    source: str = spec(default="")  # the file it came from (filled in by load)

    @classmethod
    def load(cls, path: str | Path) -> World:
        """A world file as given, or a preset name from ``configs/world/`` (``breezy``)."""
        p = Path(path)
        if not p.suffix and not p.is_file():
            p = Path("world") / f"{path}.toml"
        w = load(cls, p)
        if w.air_matters and not (w.air.fuselage or w.air.rotor_inflow):
            raise ConfigError(f"{p}: wind, gust or turbulence set but [air] has neither fuselage "
                              "nor rotor_inflow on: the air would not act on the vehicle")  # fmt: skip
        if w.sensors.seed not in (0, w.seed) or w.sensors.name != Sensors().name or w.sensors.source:
            raise ConfigError(f"{p}: [sensors] takes no seed, name or source of its own: the "
                              "world's seed drives every random stream")  # fmt: skip
        return dataclasses.replace(w, source=str(p), sensors=dataclasses.replace(w.sensors, seed=w.seed))

    @property
    def sensing(self) -> bool:
        """The autopilot flies on measurements through its estimator (any sensor error
        model or failure on); otherwise it is handed the true state."""
        return self.sensors.on

    @property
    def air_matters(self) -> bool:
        """Any moving air (it acts only through [air])."""
        return self.wind.speed_m_s > 0.0 or self.turbulence.w20_m_s > 0.0 or self.gust.amplitude_m_s > 0.0

    @property
    def on(self) -> bool:
        """Anything at all differs from the paper's ideal world."""
        return (self.air_matters or self.air.fuselage or self.air.rotor_inflow or self.servos.on
                or self.mismatch.on or self.disturbance.on)  # fmt: skip

    def describe(self, design: Airframe | None = None) -> dict[str, object]:
        """What is on, for the summary (only the effects that are on); with a mismatch and
        the controller's ``design`` airframe, each plant constant that differs beside it."""
        out: dict[str, object] = {"name": self.name, "seed": self.seed}
        if self.source:
            out["file"] = self.source
        for part in ("wind", "turbulence", "gust", "air", "servos", "mismatch", "disturbance"):
            value = getattr(self, part)
            if value != type(value)():
                out[part] = dataclasses.asdict(value)
        if self.sensing:
            out["sensors"] = {k: v for k, v in self.sensors.describe().items() if k not in ("name", "seed")}
        if design is not None and self.mismatch.on:
            base = Path(self.source).parent if self.source else None
            plant, ctrl = self.mismatch.apply(design, base).constants(), design.constants()
            out["plant_vs_design"] = {
                k: [getattr(plant, k), getattr(ctrl, k)]
                for k in plant._fields
                if getattr(plant, k) != getattr(ctrl, k)
            }
        return out


CALM = World()


# ---------------------------------------------------------------- live knobs (SIM_*)

#: blade pitch per servo-arm angle, theta_m, theta_t, eps, eta: the pitch limits over a
#: 45 deg servo throw (an estimate: no X-Cell linkage data was found)
LINKAGE_RAD_PER_RAD: Channels = (0.255, 0.446, 0.178, 0.178)


#: ArduPilot's SIM_ names where it has the setting (SIM_WIND_TURB and SIM_SERVO_SPEED with
#: this bench's models behind them; see docs/world.md), this bench's own otherwise.
WORLD_SIM_PARAMS: tuple[SimParam, ...] = (
    SimParam("SIM_WIND_SPD", 0.0, 100.0, "m/s", "steady wind speed"),
    SimParam("SIM_WIND_DIR", -360.0, 360.0, "deg", "direction the wind comes from"),
    SimParam("SIM_WIND_DIR_Z", -90.0, 90.0, "deg", "wind elevation (90: updraft)"),
    SimParam("SIM_WIND_TURB", 0.0, 50.0, "m/s", "Dryden turbulence: wind at 20 ft (W20)"),
    SimParam("SIM_GUST_SPD", 0.0, 50.0, "m/s", "1-cosine gust amplitude"),
    SimParam("SIM_GUST_DIR", -360.0, 360.0, "deg", "direction the gust comes from"),
    SimParam("SIM_GUST_START", 0.0, 1e6, "s", "gust start, vehicle time"),
    SimParam("SIM_SERVO_SPEED", 0.0, 10.0, "s", "servo time per 60 deg of arm (0: no limit)"),
    SimParam("SIM_SERVO_DELAY", 0.0, 1.0, "s", "servo transport delay"),
    SimParam("SIM_SERVO_TAU", 0.0, 5.0, "s", "servo first-order lag"),
)
#: every live knob of a world: the physics' above and the sensors' (docs/sensors.md)
SIM_PARAMS = WORLD_SIM_PARAMS + SIM_SENSOR_PARAMS
SIM_PARAM_NAMES = frozenset(p.name for p in SIM_PARAMS)


def _servo_speed(servos: Servos) -> float:
    """The servo speed (s/60 deg) the cyclic rate limit implies; 0 without a limit."""
    rate = servos.rate_rad_s[2]
    return 0.0 if rate <= 0.0 else LINKAGE_RAD_PER_RAD[2] * (math.pi / 3.0) / rate


def sim_values(w: World) -> dict[str, float]:
    """The SIM_ parameters of a world (the servo values of the cyclic channel where they
    differ per channel)."""
    return {
        "SIM_WIND_SPD": w.wind.speed_m_s,
        "SIM_WIND_DIR": w.wind.from_deg,
        "SIM_WIND_DIR_Z": w.wind.elevation_deg,
        "SIM_WIND_TURB": w.turbulence.w20_m_s,
        "SIM_GUST_SPD": w.gust.amplitude_m_s,
        "SIM_GUST_DIR": w.gust.from_deg,
        "SIM_GUST_START": w.gust.start_s,
        "SIM_SERVO_SPEED": _servo_speed(w.servos),
        "SIM_SERVO_DELAY": w.servos.delay_s[2],
        "SIM_SERVO_TAU": w.servos.tau_s[2],
        **sensor_sim_values(w.sensors),
    }


def with_sim_param(w: World, name: str, value: float) -> World:
    """``w`` with one SIM_ parameter set (ValueError: unknown name or out of range). A
    servo parameter sets all four servos; the speed goes through each linkage ratio."""
    if name in SIM_SENSOR_PARAM_NAMES:
        sensors = with_sensor_param(w.sensors, name, value)
        return w if sensors is w.sensors else dataclasses.replace(w, sensors=sensors)
    spec_ = next((p for p in WORLD_SIM_PARAMS if p.name == name), None)
    if spec_ is None:
        raise ValueError(f"unknown world parameter {name!r}")
    if not (math.isfinite(value) and spec_.lo <= value <= spec_.hi):
        raise ValueError(f"{name} must be in [{spec_.lo}, {spec_.hi}] {spec_.unit}, got {value}")
    if f32(value) == f32(sim_values(w)[name]):
        # the value it already has (as float32, the wire's): the world stays exactly as
        # loaded, so a repeated or echoed setting never rewrites per-servo values
        return w
    r = dataclasses.replace
    if name.startswith("SIM_WIND_") and name != "SIM_WIND_TURB":
        field = {"SIM_WIND_SPD": "speed_m_s", "SIM_WIND_DIR": "from_deg", "SIM_WIND_DIR_Z": "elevation_deg"}
        return r(w, wind=r(w.wind, **{field[name]: value}))
    if name == "SIM_WIND_TURB":
        return r(w, turbulence=r(w.turbulence, w20_m_s=value))
    if name.startswith("SIM_GUST_"):
        field = {"SIM_GUST_SPD": "amplitude_m_s", "SIM_GUST_DIR": "from_deg", "SIM_GUST_START": "start_s"}
        return r(w, gust=r(w.gust, **{field[name]: value}))
    four = (value,) * 4
    if name == "SIM_SERVO_SPEED":
        rates = tuple(0.0 if value == 0.0 else k * (math.pi / 3.0) / value for k in LINKAGE_RAD_PER_RAD)
        return r(w, servos=r(w.servos, rate_rad_s=rates))
    if name == "SIM_SERVO_DELAY":
        return r(w, servos=r(w.servos, delay_s=four))
    return r(w, servos=r(w.servos, tau_s=four))
