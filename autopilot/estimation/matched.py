"""A navigation filter tuned to the sensors it flies on: what a filter tuned from its
sensors' datasheets knows, taken from the world's sensor models.

The default tuning (:class:`~autopilot.estimation.config.InsConfig`) is for a consumer
IMU and a u-blox M8 receiver, whatever the vehicle carries. :func:`matched` takes each
noise, bias and random walk from the sensor configuration instead, with a floor under
each: an ideal sensor (one that is off reads the truth) still leaves the filter the
errors of its own model (the IMU held over a tick, the float32 link, the float arithmetic),
and a filter told "zero noise" would trust itself too much.
"""

from __future__ import annotations

import dataclasses
import math

from autopilot.estimation.config import EstimatorConfig
from heli_common.world.sensors import Sensors

# the floors: the filter's own model error, as a noise of each kind (docs/estimator.md)
GYRO_DENSITY_FLOOR = 2e-5  # [rad/s/rtHz]
ACCEL_DENSITY_FLOOR = 1e-3  # [m/s^2/rtHz]
GYRO_WALK_FLOOR = 1e-7  # [rad/s/rts]
ACCEL_WALK_FLOOR = 1e-5  # [m/s^2/rts]
GYRO_BIAS_FLOOR = 2e-4  # [rad/s]
ACCEL_BIAS_FLOOR = 5e-3  # [m/s^2]
GPS_POS_FLOOR = 0.02  # [m]
GPS_VEL_FLOOR = 0.01  # [m/s]
MAG_NOISE_FLOOR = 5e-4  # [gauss]
MAG_BIAS_FLOOR = 1e-3  # [gauss]
BARO_FLOOR = 0.02  # [m]


def _rms(v: tuple[float, float, float]) -> float:
    return math.sqrt(sum(x * x for x in v) / 3.0)


def matched(config: EstimatorConfig, sensors: Sensors) -> EstimatorConfig:
    """``config`` with the navigation filter's noises, priors and GPS error model taken
    from ``sensors`` (the constant biases' RMS as the bias priors: a preset's bias is one
    draw of a sensor class whose spread the filter is told)."""
    i, g, m, b = sensors.imu, sensors.gps, sensors.mag, sensors.baro
    imu_on, gps_on, mag_on = i.on, g.on, m.on
    ins = dataclasses.replace(
        config.ins,
        gyro_noise_density=max(i.gyro_density_rad_s_rthz if imu_on else 0.0, GYRO_DENSITY_FLOOR),
        accel_noise_density=max(i.accel_density_m_s2_rthz if imu_on else 0.0, ACCEL_DENSITY_FLOOR),
        gyro_bias_walk=max(i.gyro_walk_rad_s_rts if imu_on else 0.0, GYRO_WALK_FLOOR),
        accel_bias_walk=max(i.accel_walk_m_s2_rts if imu_on else 0.0, ACCEL_WALK_FLOOR),
        init_gyro_bias_sigma=max(_rms(i.gyro_bias_rad_s) if imu_on else 0.0, GYRO_BIAS_FLOOR),
        init_accel_bias_sigma=max(_rms(i.accel_bias_m_s2) if imu_on else 0.0, ACCEL_BIAS_FLOOR),
        gps_white_sigma_m=(
            max(g.noise_h_m if gps_on else 0.0, GPS_POS_FLOOR),
            max(g.noise_h_m if gps_on else 0.0, GPS_POS_FLOOR),
            max(g.noise_v_m if gps_on else 0.0, GPS_POS_FLOOR),
        ),
        gps_wander_sigma_m=(
            (g.wander_h_m, g.wander_h_m, g.wander_v_m) if gps_on else (0.0, 0.0, 0.0)
        ),
        gps_wander_tau_s=g.wander_tau_s,
        mag_sigma_gauss=max(m.noise_gauss if mag_on else 0.0, MAG_NOISE_FLOOR),
        init_mag_bias_sigma_gauss=max(_rms(m.hard_iron_gauss) if mag_on else 0.0, MAG_BIAS_FLOOR),
    )
    vel = max(g.vel_noise_m_s if gps_on else 0.0, GPS_VEL_FLOOR)
    return dataclasses.replace(
        config, ins=ins, gps_vel_sigma_m_s=(vel, vel, vel),
        baro_sigma_m=max(b.noise_m if b.on else 0.0, BARO_FLOOR),
    )  # fmt: skip
