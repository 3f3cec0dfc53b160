"""The vehicle's sensors, as configured: IMU, GPS, an attitude source, a barometer and a
magnetometer.
TOML -> frozen dataclasses, in the pattern of :mod:`heli_common.world.config`.

Every sensor is off by default. A sensor that is off is *ideal*: it delivers the truth at
every plant step, with no rate, latency, noise or bias, so an empty file (or no sensors
configured) gives the autopilot the true state exactly. Switching a sensor ``on`` applies
its error model: its own sample rate, latency (GPS, attitude), white noise, bias and bias
random walk, GPS Gauss-Markov wander, barometer drift, the magnetometer's hard-iron
offset. The failures (``freeze``, a step bias from ``fault_start_s``, GPS loss with
``gps.disabled``) act whether the error model is on or not. The models themselves live in
:mod:`heli_plant.sensors`; the numbers, conventions and sources are in ``docs/sensors.md``.

Units are SI but the magnetic field's, gauss (as MAVLink and the data sheets give it);
frames earth NWU, body FLU (:mod:`heli_common.wire.measurements`). A noise
*density* ``N`` (``_rthz``: per root hertz) becomes a per-sample standard deviation
``N sqrt(rate_hz)``; a bias random-walk intensity ``K`` (``_rts``: per root second) makes
the bias variance grow as ``K^2 t``.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass
from typing import Any

from heli_common.config import SimParam, build, spec
from heli_common.wire.mavlink.wire import f32

Vec3 = tuple[float, float, float]
ZERO3: Vec3 = (0.0, 0.0, 0.0)

#: standard gravity [m/s^2], only to turn datasheet figures in g (ug/rtHz, mg) into SI
G0_M_S2 = 9.80665
#: the largest seed the float64 parameter array carries exactly (2^53)
SEED_MAX = 2**53


@dataclass(frozen=True)
class Imu:
    """Gyro and accelerometer (body FLU): truth + constant bias + bias random walk + white
    noise, sampled at ``rate_hz`` (at most the plant rate), no latency."""

    on: bool = spec(default=False)
    rate_hz: float = spec("Hz", 0.0, 1e4, lo_open=True, default=100.0)
    gyro_density_rad_s_rthz: float = spec("rad/s/sqrt(Hz)", 0.0, 1.0, default=0.0)
    accel_density_m_s2_rthz: float = spec("m/s^2/sqrt(Hz)", 0.0, 10.0, default=0.0)
    gyro_bias_rad_s: Vec3 = spec("rad/s", -10.0, 10.0, default=ZERO3)
    accel_bias_m_s2: Vec3 = spec("m/s^2", -50.0, 50.0, default=ZERO3)
    gyro_walk_rad_s_rts: float = spec("rad/s/sqrt(s)", 0.0, 1.0, default=0.0)
    accel_walk_m_s2_rts: float = spec("m/s^2/sqrt(s)", 0.0, 10.0, default=0.0)
    # failures, from fault_start_s (vehicle time) on
    freeze: bool = spec(default=False)
    fault_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    gyro_step_rad_s: Vec3 = spec("rad/s", -100.0, 100.0, default=ZERO3)
    accel_step_m_s2: Vec3 = spec("m/s^2", -1e3, 1e3, default=ZERO3)


@dataclass(frozen=True)
class Gps:
    """Position and velocity (earth NWU): truth + first-order Gauss-Markov wander + white
    noise (position), truth + white noise (velocity), sampled at ``rate_hz``, delivered
    ``lag_s`` after the time it is valid at. The ``_h`` numbers apply to each horizontal
    axis (north, west), the ``_v`` ones to up. ``disabled``: GPS loss, no fix delivered;
    ``outage_start_s`` / ``outage_s``: a timed loss (fixes valid in that window are not
    delivered), the scripted form of a ground station setting SIM_GPS_DISABLE."""

    on: bool = spec(default=False)
    rate_hz: float = spec("Hz", 0.0, 1e3, lo_open=True, default=5.0)
    lag_s: float = spec("s", 0.0, 2.0, default=0.1)
    noise_h_m: float = spec("m", 0.0, 1e3, default=0.0)
    noise_v_m: float = spec("m", 0.0, 1e3, default=0.0)
    wander_h_m: float = spec("m", 0.0, 1e3, default=0.0)
    wander_v_m: float = spec("m", 0.0, 1e3, default=0.0)
    wander_tau_s: float = spec("s", 0.0, 1e6, lo_open=True, default=60.0)
    vel_noise_m_s: float = spec("m/s", 0.0, 100.0, default=0.0)
    disabled: bool = spec(default=False)
    outage_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    outage_s: float = spec("s", 0.0, 1e6, default=0.0)
    # what the receiver reports while it has a fix (HIL_GPS satellites_visible); the
    # accuracies it reports (eph, epv) follow from the noise numbers above
    satellites: int = spec("", 0, 40, default=14)
    # failures, from fault_start_s (validity time) on
    freeze: bool = spec(default=False)
    fault_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    step_m: Vec3 = spec("m", -1e4, 1e4, default=ZERO3)


@dataclass(frozen=True)
class Attitude:
    """An attitude source (AHRS emulation, a documented simplification): the true ZYX Euler
    angles + constant bias + white noise, per angle (roll, pitch, yaw), sampled at
    ``rate_hz`` and delivered ``lag_s`` later. No filter dynamics, no coupling to the IMU."""

    on: bool = spec(default=False)
    rate_hz: float = spec("Hz", 0.0, 1e4, lo_open=True, default=100.0)
    lag_s: float = spec("s", 0.0, 2.0, default=0.0)
    noise_rad: Vec3 = spec("rad", 0.0, 1.0, default=ZERO3)
    bias_rad: Vec3 = spec("rad", -math.pi, math.pi, default=ZERO3)
    freeze: bool = spec(default=False)
    fault_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    step_rad: Vec3 = spec("rad", -math.pi, math.pi, default=ZERO3)


@dataclass(frozen=True)
class Baro:
    """Barometric height above home: truth + linear drift + white noise at ``rate_hz``."""

    on: bool = spec(default=False)
    rate_hz: float = spec("Hz", 0.0, 1e4, lo_open=True, default=50.0)
    noise_m: float = spec("m", 0.0, 100.0, default=0.0)
    drift_m_s: float = spec("m/s", -1.0, 1.0, default=0.0)
    freeze: bool = spec(default=False)
    fault_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    step_m: float = spec("m", -1e4, 1e4, default=0.0)


@dataclass(frozen=True)
class Mag:
    """Magnetometer (body FLU, gauss): the earth's field at home (:mod:`heli_common.world.magnetic`,
    a tilted dipole) rotated into the body + a constant hard-iron offset + white noise,
    sampled at ``rate_hz``, no latency. ``hard_iron_gauss`` is the offset in the sensor's
    (body FLU) frame that a compass calibration removes: configure what is left after it."""

    on: bool = spec(default=False)
    rate_hz: float = spec("Hz", 0.0, 1e4, lo_open=True, default=100.0)
    noise_gauss: float = spec("gauss", 0.0, 10.0, default=0.0)
    hard_iron_gauss: Vec3 = spec("gauss", -10.0, 10.0, default=ZERO3)
    freeze: bool = spec(default=False)
    fault_start_s: float = spec("s", 0.0, 1e6, default=0.0)
    step_gauss: Vec3 = spec("gauss", -100.0, 100.0, default=ZERO3)


#: the sensor tables of :class:`Sensors`, in order
SENSOR_TABLES = ("imu", "gps", "attitude", "baro", "mag")


@dataclass(frozen=True)
class Sensors:
    name: str = spec(default="ideal")
    seed: int = spec("", 0, SEED_MAX, default=0)
    imu: Imu = spec(default=Imu())
    gps: Gps = spec(default=Gps())
    attitude: Attitude = spec(default=Attitude())
    baro: Baro = spec(default=Baro())
    mag: Mag = spec(default=Mag())
    source: str = spec(default="")  # the file it came from (filled in by load)

    @property
    def on(self) -> bool:
        """Anything differs from ideal sensors (an error model or a failure)."""
        return self.errors_on or self.faults_on

    @property
    def errors_on(self) -> bool:
        return self.imu.on or self.gps.on or self.attitude.on or self.baro.on or self.mag.on

    @property
    def faults_on(self) -> bool:
        i, g, a, b, m = self.imu, self.gps, self.attitude, self.baro, self.mag
        return (i.freeze or any(i.gyro_step_rad_s) or any(i.accel_step_m_s2) or g.disabled or g.outage_s > 0.0
                or g.freeze
                or any(g.step_m) or a.freeze or any(a.step_rad) or b.freeze or b.step_m != 0.0
                or m.freeze or any(m.step_gauss))  # fmt: skip

    def describe(self) -> dict[str, object]:
        """What is configured, for a run summary (only the tables that differ from ideal)."""
        out: dict[str, object] = {"name": self.name, "seed": self.seed}
        if self.source:
            out["file"] = self.source
        for part in SENSOR_TABLES:
            value = getattr(self, part)
            if value != type(value)():
                out[part] = dataclasses.asdict(value)
        return out


IDEAL = Sensors()


def validate(s: Sensors) -> Sensors:
    """``s`` itself if every field is inside its declared range (what :func:`load` checks
    for a file); ValueError naming the field otherwise (for configs built in code)."""
    for part in SENSOR_TABLES:
        table = getattr(s, part)
        for f in dataclasses.fields(table):
            _check_field(type(table), f.name, getattr(table, f.name), f"{part}.{f.name}")
    if isinstance(s.seed, bool) or not isinstance(s.seed, int) or not 0 <= s.seed <= SEED_MAX:
        raise ValueError(f"seed must be an integer in [0, {SEED_MAX}], got {s.seed!r}")
    return s


def _check_field(cls: type, name: str, value: Any, where: str) -> None:
    meta = next(f.metadata for f in dataclasses.fields(cls) if f.name == name)
    values = value if isinstance(value, tuple) else (value,)
    hint = typing.get_type_hints(cls)[name]
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise ValueError(f"{where} must be an integer, got {value!r}")
    lo, hi = meta.get("lo"), meta.get("hi")
    for v in values:
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if ok and lo is not None:
            ok = v > lo if meta.get("lo_open") else v >= lo
        if ok and hi is not None:
            ok = v <= hi
        if not ok:
            rng = f"{'(' if meta.get('lo_open') else '['}{lo}, {hi}]"
            raise ValueError(f"{where} must be finite and in {rng} {meta.get('unit', '')}, got {value!r}")


# ---------------------------------------------------------------- presets

_DEG = math.pi / 180.0
_UG = 1e-6 * G0_M_S2  # one micro-g [m/s^2]
_MG = 1e-3 * G0_M_S2
_MGAUSS = 1e-3  # one milligauss [gauss]
_HOUR_S = 3600.0


def _walk_per_hour(bias_after_1h: float) -> float:
    """The random-walk intensity K whose bias standard deviation after one hour is the
    given figure: ``K sqrt(3600 s) = b_1h``."""
    return bias_after_1h / math.sqrt(_HOUR_S)


#: The presets' numbers as TOML-shaped tables (``preset(name)`` builds them; they were
#: written to ``configs/world/NAME.toml``, and a test keeps the two equal). Sources and the
#: project's choices are in docs/sensors.md; in short:
#:   gps-typical  u-blox M8 class receiver: 2.5 m CEP = 2.12 m per axis (CEP = 1.1774 sigma),
#:                split into Gauss-Markov wander 2.1 m (tau 60 s) + 0.3 m white (total
#:                2.121 m per axis); 5 Hz, 100 ms latency, 0.05 m/s velocity; the vertical
#:                takes the horizontal numbers (no vertical figure in the M8 data); baro
#:                0.2 m white at 50 Hz (ArduPilot's SIM_BARO_RND default).
#:   imu-consumer MPU-6000 class IMU at 100 Hz: gyro 0.005 deg/s/rtHz, accel 400 ug/rtHz; a
#:                residual bias after calibration of 0.2 deg/s and 20 mg, gyro bias walk
#:                reaching 10 deg/h after an hour, accel bias walk 1 mg after an hour; an
#:                HMC5883L class magnetometer at 75 Hz (its highest continuous rate) with its
#:                2 mG noise floor and a residual hard iron after calibration of 5 mG.
#:   noisy        a stress case: 4x the IMU densities, the MPU-6000's untrimmed accel bias
#:                bounds (50/50/80 mg), 5 m CEP GPS with 200 ms lag, an attitude source with
#:                1/1/2 deg noise and a bias, 0.5 m baro with 1 mm/s drift, a magnetometer
#:                with 4x the HMC5883L's noise and a 30 mG residual hard iron.
PRESETS: dict[str, dict[str, Any]] = {
    "gps-typical": {
        "name": "gps-typical",
        "seed": 1,
        "gps": {
            "on": True, "rate_hz": 5.0, "lag_s": 0.1, "noise_h_m": 0.3, "noise_v_m": 0.3,
            "wander_h_m": 2.1, "wander_v_m": 2.1, "wander_tau_s": 60.0, "vel_noise_m_s": 0.05,
        },
        "baro": {"on": True, "rate_hz": 50.0, "noise_m": 0.2, "drift_m_s": 0.0},
    },
    "imu-consumer": {
        "name": "imu-consumer",
        "seed": 1,
        "imu": {
            "on": True, "rate_hz": 100.0,
            "gyro_density_rad_s_rthz": 0.005 * _DEG,
            "accel_density_m_s2_rthz": 400.0 * _UG,
            "gyro_bias_rad_s": [0.2 * _DEG, -0.2 * _DEG, 0.2 * _DEG],
            "accel_bias_m_s2": [20.0 * _MG, -20.0 * _MG, 20.0 * _MG],
            "gyro_walk_rad_s_rts": _walk_per_hour(10.0 * _DEG / _HOUR_S),
            "accel_walk_m_s2_rts": _walk_per_hour(1.0 * _MG),
        },
        "mag": {
            "on": True, "rate_hz": 75.0, "noise_gauss": 2.0 * _MGAUSS,
            "hard_iron_gauss": [5.0 * _MGAUSS, -5.0 * _MGAUSS, 5.0 * _MGAUSS],
        },
    },
    "noisy": {
        "name": "noisy",
        "seed": 1,
        "imu": {
            "on": True, "rate_hz": 100.0,
            "gyro_density_rad_s_rthz": 0.02 * _DEG,
            "accel_density_m_s2_rthz": 1600.0 * _UG,
            "gyro_bias_rad_s": [0.5 * _DEG, -0.5 * _DEG, 0.5 * _DEG],
            "accel_bias_m_s2": [50.0 * _MG, -50.0 * _MG, 80.0 * _MG],
            "gyro_walk_rad_s_rts": _walk_per_hour(30.0 * _DEG / _HOUR_S),
            "accel_walk_m_s2_rts": _walk_per_hour(3.0 * _MG),
        },
        "gps": {
            "on": True, "rate_hz": 5.0, "lag_s": 0.2, "noise_h_m": 0.5, "noise_v_m": 0.5,
            "wander_h_m": 4.2, "wander_v_m": 4.2, "wander_tau_s": 60.0, "vel_noise_m_s": 0.1,
        },
        "attitude": {
            "on": True, "rate_hz": 50.0, "lag_s": 0.02,
            "noise_rad": [1.0 * _DEG, 1.0 * _DEG, 2.0 * _DEG],
            "bias_rad": [0.5 * _DEG, -0.5 * _DEG, 2.0 * _DEG],
        },
        "baro": {"on": True, "rate_hz": 50.0, "noise_m": 0.5, "drift_m_s": 0.001},
        "mag": {
            "on": True, "rate_hz": 75.0, "noise_gauss": 8.0 * _MGAUSS,
            "hard_iron_gauss": [30.0 * _MGAUSS, -30.0 * _MGAUSS, 30.0 * _MGAUSS],
        },
    },
}  # fmt: skip
#: consumer  what a hobby helicopter carries: the gps-typical receiver and barometer with the
#:           imu-consumer IMU and magnetometer (the navigation filter's consistency world)
PRESETS["consumer"] = {
    "name": "consumer", "seed": 1,
    "gps": PRESETS["gps-typical"]["gps"], "baro": PRESETS["gps-typical"]["baro"],
    "imu": PRESETS["imu-consumer"]["imu"], "mag": PRESETS["imu-consumer"]["mag"],
}  # fmt: skip


def preset(name: str) -> Sensors:
    """The built-in preset ``name`` (a key of :data:`PRESETS`); ValueError otherwise."""
    if name not in PRESETS:
        raise ValueError(f"unknown sensors preset {name!r}; expected one of {', '.join(PRESETS)}")
    return build(Sensors, PRESETS[name], f"sensors preset {name}")


# ---------------------------------------------------------------- live knobs (SIM_*)

#: ArduPilot's SITL names (its older, un-numbered forms: SIM_GPS_HZ, not SIM_GPS1_HZ), with
#: this bench's models behind them; the mapping is in docs/sensors.md. The noise knobs are
#: per-sample standard deviations: SIM_ACC_RND and SIM_GYR_RND at the IMU's rate (so they
#: set the noise density ``value / sqrt(rate)``), in ArduPilot's units (m/s^2, deg/s).
SIM_SENSOR_PARAMS: tuple[SimParam, ...] = (
    SimParam("SIM_GPS_HZ", 0.1, 100.0, "Hz", "GPS fix rate"),
    SimParam("SIM_GPS_LAG_MS", 0.0, 2000.0, "ms", "GPS latency (delivery after validity)"),
    SimParam("SIM_GPS_NOISE", 0.0, 1000.0, "m", "GPS horizontal wander (Gauss-Markov sigma per axis)"),
    SimParam("SIM_GPS_DISABLE", 0.0, 1.0, "", "1: GPS lost, no fixes delivered"),
    SimParam("SIM_ACC_RND", 0.0, 100.0, "m/s^2", "accelerometer white noise, std per sample"),
    SimParam("SIM_GYR_RND", 0.0, 500.0, "deg/s", "gyro white noise, std per sample"),
    SimParam("SIM_BARO_RND", 0.0, 100.0, "m", "barometer white noise, std per sample"),
    SimParam("SIM_BARO_DRIFT", -1.0, 1.0, "m/s", "barometer drift rate"),
)
SIM_SENSOR_PARAM_NAMES = frozenset(p.name for p in SIM_SENSOR_PARAMS)


def sensor_sim_values(s: Sensors) -> dict[str, float]:
    """The SIM_ parameters of a sensors configuration (whether each sensor is on or not:
    they set the numbers, the ``on`` switches stay as configured)."""
    i = s.imu
    root = math.sqrt(i.rate_hz)
    return {
        "SIM_GPS_HZ": s.gps.rate_hz,
        "SIM_GPS_LAG_MS": s.gps.lag_s * 1000.0,
        "SIM_GPS_NOISE": s.gps.wander_h_m,
        "SIM_GPS_DISABLE": 1.0 if s.gps.disabled else 0.0,
        "SIM_ACC_RND": i.accel_density_m_s2_rthz * root,
        "SIM_GYR_RND": math.degrees(i.gyro_density_rad_s_rthz * root),
        "SIM_BARO_RND": s.baro.noise_m,
        "SIM_BARO_DRIFT": s.baro.drift_m_s,
    }


def with_sensor_param(s: Sensors, name: str, value: float) -> Sensors:
    """``s`` with one SIM_ parameter set. ValueError: unknown name, value out of range (or
    SIM_GPS_DISABLE not 0 or 1), or a result outside a field's range. A value equal as
    float32 (the wire's type) to the current one returns ``s`` itself, unchanged."""
    spec_ = next((p for p in SIM_SENSOR_PARAMS if p.name == name), None)
    if spec_ is None:
        raise ValueError(f"unknown sensor parameter {name!r}")
    value = float(value)
    if not (math.isfinite(value) and spec_.lo <= value <= spec_.hi):
        raise ValueError(f"{name} must be in [{spec_.lo}, {spec_.hi}] {spec_.unit}, got {value}")
    if name == "SIM_GPS_DISABLE" and value not in (0.0, 1.0):
        raise ValueError(f"{name} must be 0 or 1, got {value}")
    if f32(value) == f32(sensor_sim_values(s)[name]):
        return s
    r = dataclasses.replace
    if name == "SIM_GPS_HZ":
        new = r(s, gps=r(s.gps, rate_hz=value))
    elif name == "SIM_GPS_LAG_MS":
        new = r(s, gps=r(s.gps, lag_s=value / 1000.0))
    elif name == "SIM_GPS_NOISE":
        new = r(s, gps=r(s.gps, wander_h_m=value))
    elif name == "SIM_GPS_DISABLE":
        new = r(s, gps=r(s.gps, disabled=value == 1.0))
    elif name == "SIM_ACC_RND":
        new = r(s, imu=r(s.imu, accel_density_m_s2_rthz=value / math.sqrt(s.imu.rate_hz)))
    elif name == "SIM_GYR_RND":
        new = r(s, imu=r(s.imu, gyro_density_rad_s_rthz=math.radians(value) / math.sqrt(s.imu.rate_hz)))
    elif name == "SIM_BARO_RND":
        new = r(s, baro=r(s.baro, noise_m=value))
    else:
        new = r(s, baro=r(s.baro, drift_m_s=value))
    return validate(new)
