"""Estimator tuning: a frozen dataclass with units and ranges, loadable from TOML.

Every field has a default (docs/estimator.md, "Tuning", says where each comes from), so a
TOML file needs only the keys it changes; unknown keys and out-of-range values are refused
by :mod:`heli_common.config`. Per-axis tuples are ordered (north, west, up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from heli_common.config import load, spec

# MPU-6000 accelerometer noise density, 400 ug/rtHz, in SI
MPU6000_ACCEL_DENSITY = 400e-6 * 9.80665  # [m/s^2/rtHz]
# MPU-6000 gyro noise density, 0.005 deg/s/rtHz (InvenSense PS-MPU-6000A-00 rev 3.4, table 6.1)
MPU6000_GYRO_DENSITY = 0.005 * math.pi / 180.0  # [rad/s/rtHz]
_DEG = math.pi / 180.0
_HOUR_S = 3600.0

#: what ``attitude`` may name: the inertial navigation filter, or the old attitude source
ATTITUDE_SOURCES = ("ins", "ideal-ahrs")


@dataclass(frozen=True)
class InsConfig:
    """The inertial navigation filter's tuning (``[ins]`` of an estimator file). Defaults: a
    consumer IMU (MPU-6000 class) and a u-blox M8 class receiver, the sensors of the
    ``imu-consumer`` and ``gps-typical`` presets; docs/estimator.md, "The navigation filter"."""

    # --- IMU process noise (densities) and bias random walks
    gyro_noise_density: float = spec("rad/s/rtHz", 0.0, 1.0, lo_open=True, default=MPU6000_GYRO_DENSITY)
    accel_noise_density: float = spec("m/s^2/rtHz", 0.0, 10.0, lo_open=True, default=MPU6000_ACCEL_DENSITY)
    # the bias after one hour of walk: 10 deg/h and 1 mg, as the imu-consumer preset
    gyro_bias_walk: float = spec("rad/s/rts", 0.0, 1.0, default=10.0 * _DEG / _HOUR_S / 60.0)
    accel_bias_walk: float = spec("m/s^2/rts", 0.0, 10.0, default=1e-3 * 9.80665 / 60.0)
    # --- initial uncertainty (1 sigma): the start is aligned at a known spawn point
    init_att_sigma_rad: float = spec("rad", 0.0, 1.0, lo_open=True, default=0.01)
    init_vel_sigma_m_s: float = spec("m/s", 0.0, 1e3, lo_open=True, default=0.1)
    init_pos_sigma_m: float = spec("m", 0.0, 1e4, lo_open=True, default=0.5)
    init_gyro_bias_sigma: float = spec("rad/s", 0.0, 1.0, lo_open=True, default=0.5 * _DEG)
    init_accel_bias_sigma: float = spec("m/s^2", 0.0, 10.0, lo_open=True, default=0.3)
    # --- GPS position error: white part, and a first-order Gauss-Markov wander per axis
    # (N, W, U) estimated as three states (0: none, the fix is taken as white)
    gps_white_sigma_m: tuple[float, float, float] = spec("m", 0.0, 1e3, lo_open=True, default=(0.3, 0.3, 0.3))
    gps_wander_sigma_m: tuple[float, float, float] = spec("m", 0.0, 1e3, default=(2.1, 2.1, 2.1))
    gps_wander_tau_s: float = spec("s", 0.0, 1e6, lo_open=True, default=60.0)
    # --- magnetometer, fused as the body field against the earth's field at home
    use_mag: bool = spec(default=True)
    # per axis: noise (HMC5883L class, 2 mG) and what the field model and the calibration
    # leave (a few mG)
    mag_sigma_gauss: float = spec("gauss", 0.0, 1.0, lo_open=True, default=0.003)
    # the offset the calibration leaves, estimated (body FLU; a few mG for a calibrated
    # HMC5883L) and its slow change (temperature, nearby currents)
    init_mag_bias_sigma_gauss: float = spec("gauss", 0.0, 1.0, lo_open=True, default=0.01)
    mag_bias_walk: float = spec("gauss/rts", 0.0, 1.0, default=1e-5)
    # the compass calibration (hard iron) subtracted from the body field, as COMPASS_OFS
    mag_offsets_gauss: tuple[float, float, float] = spec("gauss", -10.0, 10.0, default=(0.0, 0.0, 0.0))
    # --- failsafe: innovations out of their gate for this long -> "diverged"
    divergence_s: float = spec("s", 0.0, 600.0, lo_open=True, default=5.0)


@dataclass(frozen=True)
class EstimatorConfig:
    # "ins": the inertial navigation filter (autopilot/estimation/ins.py) estimates attitude,
    # velocity, position and the IMU biases (the default, as a real autopilot has);
    # "ideal-ahrs": the attitude source's angles and per-axis position filters
    # (autopilot/estimation/kf.py), kept for comparisons
    attitude: str = spec(default="ins", choices=ATTITUDE_SOURCES)
    ins: InsConfig = spec(default=InsConfig())

    # --- process model (per earth axis: position, velocity, acceleration bias)
    gravity_m_s2: float = spec("m/s^2", 0.0, 30.0, lo_open=True, default=9.81)
    accel_noise_density: float = spec("m/s^2/rtHz", 0.0, 10.0, lo_open=True, default=MPU6000_ACCEL_DENSITY)
    # white error of the attitude source, per sample at the estimator rate; it tilts the
    # specific force, adding |f|^2 - f_axis^2 times its variance to each axis' acceleration noise
    attitude_noise_rad: float = spec("rad", 0.0, 0.5, default=0.0035)
    # random walk of the earth-frame acceleration bias (accelerometer bias seen through the
    # attitude, and slow attitude-source tilt errors)
    accel_bias_walk: float = spec("m/s^2/rts", 0.0, 10.0, default=0.003)

    # --- initial uncertainty (1 sigma)
    init_pos_sigma_m: float = spec("m", 0.0, 1e4, lo_open=True, default=1.0)
    init_vel_sigma_m_s: float = spec("m/s", 0.0, 1e3, lo_open=True, default=0.5)
    init_accel_bias_sigma: float = spec("m/s^2", 0.0, 10.0, default=0.2)

    # --- GPS (1 sigma, white; per axis N, W, U)
    gps_pos_sigma_m: tuple[float, float, float] = spec("m", 0.0, 1e3, lo_open=True, default=(1.0, 1.0, 1.5))
    gps_vel_sigma_m_s: tuple[float, float, float] = spec(
        "m/s", 0.0, 1e2, lo_open=True, default=(0.1, 0.1, 0.15)
    )
    use_gps_velocity: bool = spec(default=True)
    # chi-square gate on the normalised innovation of a whole fix (3 or 6 degrees of freedom)
    gate_probability: float = spec("", 0.5, 1.0, lo_open=True, default=0.999)
    # after this many consecutive rejected fixes, the next one re-initialises position/velocity
    max_consecutive_rejects: int = spec("", 1, 1000, default=5)
    gps_timeout_s: float = spec("s", 0.0, 60.0, lo_open=True, default=1.0)

    # --- barometer (z only)
    # on: the height holds when GPS is lost (the baro's slow drift is not estimated)
    use_baro: bool = spec(default=True)
    baro_sigma_m: float = spec("m", 0.0, 100.0, lo_open=True, default=0.5)

    # --- delayed measurements: how far back a measurement may be fused at its validity time
    buffer_s: float = spec("s", 0.0, 5.0, lo_open=True, default=0.5)

    # --- attitude and rates (the documented simplification: AHRS attitude, gyro rates)
    gyro_bias_rad_s: tuple[float, float, float] = spec("rad/s", -1.0, 1.0, default=(0.0, 0.0, 0.0))
    attitude_lpf_tau_s: float = spec("s", 0.0, 10.0, default=0.0)  # 0: pass-through
    rate_lpf_tau_s: float = spec("s", 0.0, 10.0, default=0.0)  # 0: pass-through

    @classmethod
    def load(cls, path: str | Path) -> EstimatorConfig:
        """A tuning file as given, or a name from ``configs/estimator/`` (``noisy``)."""
        p = Path(path)
        if not p.suffix and not p.is_file():
            p = Path("estimator") / f"{path}.toml"
        return load(cls, p)
