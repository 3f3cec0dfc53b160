"""Estimator tuning: a frozen dataclass with units and ranges, loadable from TOML.

Every field has a default (docs/estimator.md, "Tuning", says where each comes from), so a
TOML file needs only the keys it changes; unknown keys and out-of-range values are refused
by :mod:`heli_common.config`. Per-axis tuples are ordered (north, west, up).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from heli_common.config import load, spec

# MPU-6000 accelerometer noise density, 400 ug/rtHz, in SI
MPU6000_ACCEL_DENSITY = 400e-6 * 9.80665  # [m/s^2/rtHz]


@dataclass(frozen=True)
class EstimatorConfig:
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
