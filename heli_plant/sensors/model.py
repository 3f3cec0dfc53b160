"""Sensor models in the plant's step (compiled): IMU, GPS, attitude source, barometer,
magnetometer.

:class:`SensorModel` turns a configured :class:`heli_common.world.sensors.Sensors` into three flat
float64 arrays (named offsets below) and :func:`sensor_step` is called once per plant step
with the true state ``x`` at time ``t_s`` and the true acceleration of the c.g. in the earth
frame at that time. It returns a bit mask of the samples that are new this step and writes
them into ``out``, which always holds the latest sample of each sensor.

The caller's acceleration: ``a_earth`` is ``d/dt (R v_body)``, earth NWU [m/s^2], gravity
*not* included (at rest it is zero). The exact value at ``t_s`` comes from the dynamics
derivative, :func:`earth_accel_from_derivative` (``R (dv_body/dt + omega x v_body)``); a
finite difference of two states, :func:`earth_accel_from_states`, is the mean over the step
(exact at the step's midpoint) and is acceptable where the derivative is not at hand.
:func:`specific_force_flu` is what a perfect accelerometer reads, ``R^T (a_earth - g_earth)``
with ``g_earth = (0, 0, -g)``: ``(0, 0, +g)`` at rest and level.

Per sensor (details and sources in docs/sensors.md):

* Schedule: sample number ``k`` is due at ``k / rate`` (vehicle time); it is taken at the
  first plant step at or after that time (within ``SNP_TOL_S``), with the state of that
  step, and valid at the step's time. Timing never drifts (jitter is below one step). A rate
  of 0 in the parameters (a sensor that is off) samples at every step.
* White noise: a per-sample standard deviation; for a density ``N`` it is ``N sqrt(rate)``
  (the two-sided PSD of the sampled sequence is then ``N^2``).
* Bias random walk (IMU): ``b += K sqrt(dt) eta`` per sample, ``dt`` the time since the
  sensor's previous sample, on top of the constant initial bias.
* GPS wander: first-order Gauss-Markov per axis, discretised exactly for the actual sample
  interval, ``z = a z + sqrt(1 - a^2) eta``, ``a = exp(-dt/tau)``, run normalised (unit
  variance, stationary from its first sample) and scaled by the configured sigma.
* Latency (GPS, attitude): each sample enters a FIFO with its validity time and is delivered
  at the first step at or after ``t_valid + lag``. At most one per step: if several are
  ready (only after a lag is shortened live) the newest is delivered, older ones dropped;
  if the FIFO is full the oldest entry is overwritten (sized so that cannot happen).
* Baro drift: ``d += rate * dt`` per sample (ArduPilot's SITL_Baro drifts the same way).
* Magnetometer: ``R^T m_nwu`` (the earth's field at home, :mod:`heli_common.world.magnetic`, carried
  in the parameters) + a constant hard-iron offset + white noise, no latency.
* GPS receiver status, written with each fix delivered: fix type 3 (3D), the configured
  satellite count, and the receiver's own 1-sigma accuracies ``eph`` (per horizontal axis)
  and ``epv``: ``sqrt(noise^2 + wander^2)`` of its error model, at least
  ``GPS_ACCURACY_FLOOR_M`` (also what an ideal receiver, a GPS that is off, reports).
* Failures: from ``fault_start_s`` (compared with the sample's validity time) a step bias is
  added, and ``freeze`` holds the last output values (new samples keep their times, the
  values stay); a frozen sensor with no output yet outputs its first sample. GPS
  ``disabled``: fixes are still taken (the noise processes run on) but none is delivered.

Randomness is counter-based (:mod:`heli_plant.world.noise`): each process draws from
its own stream id (>= ``STREAM_SENSOR_BASE``, never the world's) at its sensor's sample
count, so the same seed and the same sequence of calls give the same samples in any process
(and under ``NUMBA_DISABLE_JIT=1``). With every error term zero no arithmetic but ``+ 0.0``
touches the truth: a sensor that is off reads the truth exactly.

Parameters (``params[SNP_*]``, float64, built by :func:`sensor_parameters`)::

    SNP_SEED, SNP_TOL_S, SNP_GRAVITY         seed (exact below 2^53), timing tolerance [s], g
    SNP_IMU_RATE_HZ                          0: every step
    SNP_GYRO_SIGMA, SNP_ACCEL_SIGMA          white std per sample [rad/s], [m/s^2]
    SNP_GYRO_BIAS (3), SNP_ACCEL_BIAS (3)    constant bias
    SNP_GYRO_WALK, SNP_ACCEL_WALK            random-walk intensity K [unit/sqrt(s)]
    SNP_IMU_FREEZE, SNP_IMU_FAULT_T          0/1, fault start [s]
    SNP_GYRO_STEP (3), SNP_ACCEL_STEP (3)    step bias from the fault start
    SNP_GPS_RATE_HZ, SNP_GPS_LAG_S
    SNP_GPS_SIGMA_H, SNP_GPS_SIGMA_V         white position std per fix [m]
    SNP_GPS_WANDER_H, SNP_GPS_WANDER_V       Gauss-Markov sigma [m]
    SNP_GPS_TAU_S                            Gauss-Markov time constant
    SNP_GPS_VEL_SIGMA                        white velocity std per fix [m/s]
    SNP_GPS_DISABLED, SNP_GPS_OUTAGE_T0, SNP_GPS_OUTAGE_T1, SNP_GPS_FREEZE, SNP_GPS_FAULT_T, SNP_GPS_STEP (3)
    SNP_GPS_SATS, SNP_GPS_EPH_M, SNP_GPS_EPV_M   what the receiver reports with a fix
    SNP_GPS_QUEUE, SNP_GPS_QUEUE_CAP         state offset and slots of the GPS FIFO
    SNP_ATT_RATE_HZ, SNP_ATT_LAG_S, SNP_ATT_SIGMA (3), SNP_ATT_BIAS (3)
    SNP_ATT_FREEZE, SNP_ATT_FAULT_T, SNP_ATT_STEP (3), SNP_ATT_QUEUE, SNP_ATT_QUEUE_CAP
    SNP_BARO_RATE_HZ, SNP_BARO_SIGMA, SNP_BARO_DRIFT, SNP_BARO_FREEZE, SNP_BARO_FAULT_T,
    SNP_BARO_STEP
    SNP_MAG_RATE_HZ, SNP_MAG_SIGMA           white std per sample per axis [gauss]
    SNP_MAG_FIELD (3)                        the earth's field at home, earth NWU [gauss]
    SNP_MAG_HARD_IRON (3)                    constant offset, body FLU [gauss]
    SNP_MAG_FREEZE, SNP_MAG_FAULT_T, SNP_MAG_STEP (3)

State (``state[SNS_*]``, float64, :func:`sensor_state`), per sensor ``NEXT`` (index of the
next due sample, -1: schedule from the next call), ``LAST_T`` (time of the last sample, NaN
before the first), ``N`` (samples taken: the noise counter), ``OUT`` (samples output)::

    SNS_GYRO_WALK (3), SNS_ACCEL_WALK (3)    bias random-walk parts
    SNS_GPS_WANDER (3), SNS_GPS_WANDER_ON    normalised Gauss-Markov state, 1 once started
    SNS_GPS_HEAD, SNS_GPS_COUNT              FIFO ring: oldest slot, entries
    SNS_ATT_HEAD, SNS_ATT_COUNT
    SNS_BARO_DRIFT                           accumulated drift [m]
    SNS_MAG_NEXT, SNS_MAG_LAST_T, SNS_MAG_N, SNS_MAG_OUT
    state[SNP_GPS_QUEUE + slot * GPS_REC ...]   (t_valid, pos 3, vel 3)
    state[SNP_ATT_QUEUE + slot * ATT_REC ...]   (t_valid, euler 3)

Output (``out[OUT_*]``, float64, NaN before a sensor's first sample)::

    OUT_IMU_T, OUT_GYRO (3), OUT_ACCEL (3)           body FLU [rad/s], [m/s^2]
    OUT_GPS_T, OUT_GPS_POS (3), OUT_GPS_VEL (3)      validity time; earth NWU [m], [m/s]
    OUT_GPS_FIX_TYPE, OUT_GPS_SATS, OUT_GPS_EPH_M, OUT_GPS_EPV_M   the receiver's status
    OUT_ATT_T, OUT_ATT (3)                           ZYX Euler [rad]
    OUT_BARO_T, OUT_BARO_ALT                         height above home [m]
    OUT_MAG_T, OUT_MAG (3)                           body FLU [gauss]

and the mask bits ``NEW_IMU``, ``NEW_GPS``, ``NEW_ATT``, ``NEW_BARO``, ``NEW_MAG``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from heli_common.defaults import HOME
from heli_common.geo import GeoPoint
from heli_common.jit import njit
from heli_common.kinematics import rot_euler_entries
from heli_common.layout import Layout
from heli_common.state import N_STATE, P_X, PHI, PSI, THETA, U_F, V_L, W_U, X_N, Z_U, FloatArray
from heli_common.wire.measurements import (  # the out layout and mask bits are the contract's
    GPS_FIX_3D,
    N_OUT,
    NEW_ATT,
    NEW_BARO,
    NEW_GPS,
    NEW_IMU,
    NEW_MAG,
    OUT_ACCEL,
    OUT_ATT,
    OUT_ATT_T,
    OUT_BARO_ALT,
    OUT_BARO_T,
    OUT_GPS_EPH_M,
    OUT_GPS_EPV_M,
    OUT_GPS_FIX_TYPE,
    OUT_GPS_POS,
    OUT_GPS_SATS,
    OUT_GPS_T,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_IMU_T,
    OUT_MAG,
    OUT_MAG_T,
    AttitudeSample,
    BaroSample,
    GpsFix,
    ImuSample,
    MagSample,
)
from heli_common.world.magnetic import earth_field_nwu_gauss
from heli_common.world.sensors import SENSOR_TABLES, Sensors, validate
from heli_plant.world.noise import STREAM_SENSOR_BASE, normal, normal_pair

# --- stream ids (one per random process; the world owns those below 16) -----------------
STREAM_GYRO = STREAM_SENSOR_BASE + 0
STREAM_GYRO_WALK = STREAM_SENSOR_BASE + 1
STREAM_ACCEL = STREAM_SENSOR_BASE + 2
STREAM_ACCEL_WALK = STREAM_SENSOR_BASE + 3
STREAM_GPS_POS = STREAM_SENSOR_BASE + 4
STREAM_GPS_WANDER = STREAM_SENSOR_BASE + 5
STREAM_GPS_WANDER_INIT = STREAM_SENSOR_BASE + 6
STREAM_GPS_VEL = STREAM_SENSOR_BASE + 7
STREAM_ATT = STREAM_SENSOR_BASE + 8
STREAM_BARO = STREAM_SENSOR_BASE + 9
STREAM_MAG = STREAM_SENSOR_BASE + 10


# --- params[SNP_*] ---------------------------------------------------------------------------
SENSOR_PARAMS = Layout(
    "sensor parameters",
    ("seed", 1), ("tol_s", 1), ("gravity", 1),
    # IMU
    ("imu_rate_hz", 1), ("gyro_sigma", 1), ("accel_sigma", 1), ("gyro_bias", 3), ("accel_bias", 3),
    ("gyro_walk", 1), ("accel_walk", 1), ("imu_freeze", 1), ("imu_fault_t", 1), ("gyro_step", 3),
    ("accel_step", 3),
    # GPS
    ("gps_rate_hz", 1), ("gps_lag_s", 1), ("gps_sigma_h", 1), ("gps_sigma_v", 1), ("gps_wander_h", 1),
    ("gps_wander_v", 1), ("gps_tau_s", 1), ("gps_vel_sigma", 1), ("gps_disabled", 1), ("gps_freeze", 1),
    ("gps_outage_t0", 1), ("gps_outage_t1", 1),
    ("gps_fault_t", 1), ("gps_step", 3), ("gps_sats", 1), ("gps_eph_m", 1), ("gps_epv_m", 1),
    ("gps_queue", 1), ("gps_queue_cap", 1),
    # attitude source
    ("att_rate_hz", 1), ("att_lag_s", 1), ("att_sigma", 3), ("att_bias", 3), ("att_freeze", 1),
    ("att_fault_t", 1), ("att_step", 3), ("att_queue", 1), ("att_queue_cap", 1),
    # barometer
    ("baro_rate_hz", 1), ("baro_sigma", 1), ("baro_drift", 1), ("baro_freeze", 1), ("baro_fault_t", 1),
    ("baro_step", 1),
    # magnetometer
    ("mag_rate_hz", 1), ("mag_sigma", 1), ("mag_field", 3), ("mag_hard_iron", 3), ("mag_freeze", 1),
    ("mag_fault_t", 1), ("mag_step", 3),
)  # fmt: skip
SNP_SEED = SENSOR_PARAMS.offset("seed")
SNP_TOL_S = SENSOR_PARAMS.offset("tol_s")
SNP_GRAVITY = SENSOR_PARAMS.offset("gravity")
SNP_IMU_RATE_HZ = SENSOR_PARAMS.offset("imu_rate_hz")
SNP_GYRO_SIGMA = SENSOR_PARAMS.offset("gyro_sigma")
SNP_ACCEL_SIGMA = SENSOR_PARAMS.offset("accel_sigma")
SNP_GYRO_BIAS = SENSOR_PARAMS.offset("gyro_bias")
SNP_ACCEL_BIAS = SENSOR_PARAMS.offset("accel_bias")
SNP_GYRO_WALK = SENSOR_PARAMS.offset("gyro_walk")
SNP_ACCEL_WALK = SENSOR_PARAMS.offset("accel_walk")
SNP_IMU_FREEZE = SENSOR_PARAMS.offset("imu_freeze")
SNP_IMU_FAULT_T = SENSOR_PARAMS.offset("imu_fault_t")
SNP_GYRO_STEP = SENSOR_PARAMS.offset("gyro_step")
SNP_ACCEL_STEP = SENSOR_PARAMS.offset("accel_step")
SNP_GPS_RATE_HZ = SENSOR_PARAMS.offset("gps_rate_hz")
SNP_GPS_LAG_S = SENSOR_PARAMS.offset("gps_lag_s")
SNP_GPS_SIGMA_H = SENSOR_PARAMS.offset("gps_sigma_h")
SNP_GPS_SIGMA_V = SENSOR_PARAMS.offset("gps_sigma_v")
SNP_GPS_WANDER_H = SENSOR_PARAMS.offset("gps_wander_h")
SNP_GPS_WANDER_V = SENSOR_PARAMS.offset("gps_wander_v")
SNP_GPS_TAU_S = SENSOR_PARAMS.offset("gps_tau_s")
SNP_GPS_VEL_SIGMA = SENSOR_PARAMS.offset("gps_vel_sigma")
SNP_GPS_DISABLED = SENSOR_PARAMS.offset("gps_disabled")
SNP_GPS_OUTAGE_T0 = SENSOR_PARAMS.offset("gps_outage_t0")
SNP_GPS_OUTAGE_T1 = SENSOR_PARAMS.offset("gps_outage_t1")
SNP_GPS_FREEZE = SENSOR_PARAMS.offset("gps_freeze")
SNP_GPS_FAULT_T = SENSOR_PARAMS.offset("gps_fault_t")
SNP_GPS_STEP = SENSOR_PARAMS.offset("gps_step")
SNP_GPS_SATS = SENSOR_PARAMS.offset("gps_sats")
SNP_GPS_EPH_M = SENSOR_PARAMS.offset("gps_eph_m")
SNP_GPS_EPV_M = SENSOR_PARAMS.offset("gps_epv_m")
SNP_GPS_QUEUE = SENSOR_PARAMS.offset("gps_queue")
SNP_GPS_QUEUE_CAP = SENSOR_PARAMS.offset("gps_queue_cap")
SNP_ATT_RATE_HZ = SENSOR_PARAMS.offset("att_rate_hz")
SNP_ATT_LAG_S = SENSOR_PARAMS.offset("att_lag_s")
SNP_ATT_SIGMA = SENSOR_PARAMS.offset("att_sigma")
SNP_ATT_BIAS = SENSOR_PARAMS.offset("att_bias")
SNP_ATT_FREEZE = SENSOR_PARAMS.offset("att_freeze")
SNP_ATT_FAULT_T = SENSOR_PARAMS.offset("att_fault_t")
SNP_ATT_STEP = SENSOR_PARAMS.offset("att_step")
SNP_ATT_QUEUE = SENSOR_PARAMS.offset("att_queue")
SNP_ATT_QUEUE_CAP = SENSOR_PARAMS.offset("att_queue_cap")
SNP_BARO_RATE_HZ = SENSOR_PARAMS.offset("baro_rate_hz")
SNP_BARO_SIGMA = SENSOR_PARAMS.offset("baro_sigma")
SNP_BARO_DRIFT = SENSOR_PARAMS.offset("baro_drift")
SNP_BARO_FREEZE = SENSOR_PARAMS.offset("baro_freeze")
SNP_BARO_FAULT_T = SENSOR_PARAMS.offset("baro_fault_t")
SNP_BARO_STEP = SENSOR_PARAMS.offset("baro_step")
SNP_MAG_RATE_HZ = SENSOR_PARAMS.offset("mag_rate_hz")
SNP_MAG_SIGMA = SENSOR_PARAMS.offset("mag_sigma")
SNP_MAG_FIELD = SENSOR_PARAMS.offset("mag_field")
SNP_MAG_HARD_IRON = SENSOR_PARAMS.offset("mag_hard_iron")
SNP_MAG_FREEZE = SENSOR_PARAMS.offset("mag_freeze")
SNP_MAG_FAULT_T = SENSOR_PARAMS.offset("mag_fault_t")
SNP_MAG_STEP = SENSOR_PARAMS.offset("mag_step")
N_SNP = SENSOR_PARAMS.size

# --- state[SNS_*] ----------------------------------------------------------------------------
# the fixed part; the FIFOs follow (their offsets and slots in SNP_*_QUEUE, SNP_*_QUEUE_CAP)
SENSOR_STATE = Layout(
    "sensor state",
    ("imu_next", 1), ("imu_last_t", 1), ("imu_n", 1), ("imu_out", 1), ("gyro_walk", 3), ("accel_walk", 3),
    ("gps_next", 1), ("gps_last_t", 1), ("gps_n", 1), ("gps_out", 1), ("gps_wander", 3), ("gps_wander_on", 1),
    ("gps_head", 1), ("gps_count", 1),
    ("att_next", 1), ("att_last_t", 1), ("att_n", 1), ("att_out", 1), ("att_head", 1), ("att_count", 1),
    ("baro_next", 1), ("baro_last_t", 1), ("baro_n", 1), ("baro_out", 1), ("baro_drift", 1),
    ("mag_next", 1), ("mag_last_t", 1), ("mag_n", 1), ("mag_out", 1),
)  # fmt: skip
SNS_IMU_NEXT = SENSOR_STATE.offset("imu_next")
SNS_IMU_LAST_T = SENSOR_STATE.offset("imu_last_t")
SNS_IMU_N = SENSOR_STATE.offset("imu_n")
SNS_IMU_OUT = SENSOR_STATE.offset("imu_out")
SNS_GYRO_WALK = SENSOR_STATE.offset("gyro_walk")
SNS_ACCEL_WALK = SENSOR_STATE.offset("accel_walk")
SNS_GPS_NEXT = SENSOR_STATE.offset("gps_next")
SNS_GPS_LAST_T = SENSOR_STATE.offset("gps_last_t")
SNS_GPS_N = SENSOR_STATE.offset("gps_n")
SNS_GPS_OUT = SENSOR_STATE.offset("gps_out")
SNS_GPS_WANDER = SENSOR_STATE.offset("gps_wander")
SNS_GPS_WANDER_ON = SENSOR_STATE.offset("gps_wander_on")
SNS_GPS_HEAD = SENSOR_STATE.offset("gps_head")
SNS_GPS_COUNT = SENSOR_STATE.offset("gps_count")
SNS_ATT_NEXT = SENSOR_STATE.offset("att_next")
SNS_ATT_LAST_T = SENSOR_STATE.offset("att_last_t")
SNS_ATT_N = SENSOR_STATE.offset("att_n")
SNS_ATT_OUT = SENSOR_STATE.offset("att_out")
SNS_ATT_HEAD = SENSOR_STATE.offset("att_head")
SNS_ATT_COUNT = SENSOR_STATE.offset("att_count")
SNS_BARO_NEXT = SENSOR_STATE.offset("baro_next")
SNS_BARO_LAST_T = SENSOR_STATE.offset("baro_last_t")
SNS_BARO_N = SENSOR_STATE.offset("baro_n")
SNS_BARO_OUT = SENSOR_STATE.offset("baro_out")
SNS_BARO_DRIFT = SENSOR_STATE.offset("baro_drift")
SNS_MAG_NEXT = SENSOR_STATE.offset("mag_next")
SNS_MAG_LAST_T = SENSOR_STATE.offset("mag_last_t")
SNS_MAG_N = SENSOR_STATE.offset("mag_n")
SNS_MAG_OUT = SENSOR_STATE.offset("mag_out")
N_SNS = SENSOR_STATE.size

# one FIFO entry of each delayed sensor, relative to its slot's start
GPS_RECORD = Layout("GPS FIFO entry", ("t_valid", 1), ("pos", 3), ("vel", 3))
GR_T = GPS_RECORD.offset("t_valid")
GR_POS = GPS_RECORD.offset("pos")
GR_VEL = GPS_RECORD.offset("vel")
GPS_REC = GPS_RECORD.size
ATT_RECORD = Layout("attitude FIFO entry", ("t_valid", 1), ("euler", 3))
AR_T = ATT_RECORD.offset("t_valid")
AR_EULER = ATT_RECORD.offset("euler")
ATT_REC = ATT_RECORD.size


#: timing tolerance as a fraction of the plant step (absorbs a time accumulated by += dt)
TOL_STEPS = 1e-3

#: the accuracy a receiver reports when its error model is off (an ideal receiver) or adds
#: up to less [m]: 1 cm, the resolution of HIL_GPS eph/epv, so the report is never 0
#: ("exact"), which a consumer could take as infinite confidence
GPS_ACCURACY_FLOOR_M = 0.01


# ---------------------------------------------------------------- truth helpers


Rot = tuple[float, float, float, float, float, float, float, float, float]


@njit
def _rot(x: FloatArray) -> Rot:
    """:func:`~heli_common.kinematics.rot_body_to_earth` of the state's Euler angles as
    values, row-major, the same arithmetic: no array made (several a step)."""
    return rot_euler_entries(x[PHI], x[THETA], x[PSI])


@njit
def velocity_nwu(x: FloatArray) -> tuple[float, float, float]:
    """The c.g. velocity in earth NWU, ``R v_body`` [m/s]."""
    rt = _rot(x)
    u, v, w = x[U_F], x[V_L], x[W_U]
    return (
        rt[0] * u + rt[1] * v + rt[2] * w,
        rt[3] * u + rt[4] * v + rt[5] * w,
        rt[6] * u + rt[7] * v + rt[8] * w,
    )


@njit
def specific_force_flu(
    x: FloatArray, accel_earth_nwu: FloatArray, gravity_m_s2: float
) -> tuple[float, float, float]:
    """What a perfect accelerometer reads, body FLU: ``R^T (a_earth - g_earth)``,
    ``g_earth = (0, 0, -g)``; ``(0, 0, +g)`` at rest and level."""
    rt = _rot(x)
    ax, ay, az = accel_earth_nwu[0], accel_earth_nwu[1], accel_earth_nwu[2] + gravity_m_s2
    return (
        rt[0] * ax + rt[3] * ay + rt[6] * az,
        rt[1] * ax + rt[4] * ay + rt[7] * az,
        rt[2] * ax + rt[5] * ay + rt[8] * az,
    )


@njit
def magnetic_field_flu(x: FloatArray, field_nwu_gauss: FloatArray, at: int = 0) -> tuple[float, float, float]:
    """What a perfect magnetometer reads, body FLU: ``R^T m_nwu`` [gauss], ``m_nwu`` the
    earth's field (:func:`heli_common.world.magnetic.earth_field_nwu_gauss` at home) at
    ``field_nwu_gauss[at:]``."""
    rt = _rot(x)
    m0, m1, m2 = field_nwu_gauss[at], field_nwu_gauss[at + 1], field_nwu_gauss[at + 2]
    return (
        rt[0] * m0 + rt[3] * m1 + rt[6] * m2,
        rt[1] * m0 + rt[4] * m1 + rt[7] * m2,
        rt[2] * m0 + rt[5] * m1 + rt[8] * m2,
    )


@njit
def earth_accel_from_derivative(x: FloatArray, xdot: FloatArray) -> tuple[float, float, float]:
    """``a_earth = d/dt (R v) = R (dv/dt + omega x v)`` from the state and its derivative
    (the plant's ``rigid_body``/``derivative`` output) at the same time [m/s^2, NWU]."""
    rt = _rot(x)
    # omega x v (heli_common.kinematics.cross) on values
    p, q, r, u, v, w = x[P_X], x[P_X + 1], x[P_X + 2], x[U_F], x[V_L], x[W_U]
    b0 = xdot[U_F] + (q * w - r * v)
    b1 = xdot[V_L] + (r * u - p * w)
    b2 = xdot[W_U] + (p * v - q * u)
    return (
        rt[0] * b0 + rt[1] * b1 + rt[2] * b2,
        rt[3] * b0 + rt[4] * b1 + rt[5] * b2,
        rt[6] * b0 + rt[7] * b1 + rt[8] * b2,
    )


@njit
def earth_accel_from_states(x0: FloatArray, x1: FloatArray, dt_s: float) -> tuple[float, float, float]:
    """The mean earth-frame acceleration over a step, ``(R1 v1 - R0 v0) / dt`` [m/s^2, NWU]:
    the acceleration at the step's midpoint to O(dt^2), at either end to O(dt)."""
    a0, a1, a2 = velocity_nwu(x0)
    b0, b1, b2 = velocity_nwu(x1)
    return ((b0 - a0) / dt_s, (b1 - a1) / dt_s, (b2 - a2) / dt_s)


@njit
def specific_force_over_step(
    x0: FloatArray, x1: FloatArray, dt_s: float, gravity_m_s2: float
) -> tuple[float, float, float]:
    """What a perfect accelerometer reads at the end of a step from ``x0`` to ``x1``, body
    FLU [m/s^2]: :func:`specific_force_flu` of :func:`earth_accel_from_states`, in one
    compiled call (the ArduPilot backend answers 1200 frames a second)."""
    a0, a1, a2 = earth_accel_from_states(x0, x1, dt_s)
    return specific_force_flu(x1, np.array((a0, a1, a2)), gravity_m_s2)


# ---------------------------------------------------------------- compiled pieces


@njit
def _normal3(seed: int, stream: int, n: int) -> tuple[float, float, float]:
    """Three independent N(0, 1) deviates for sample ``n`` of ``stream``."""
    a, b = normal_pair(seed, stream, 2 * n)
    c, _ = normal_pair(seed, stream, 2 * n + 1)
    return a, b, c


@njit
def _due(t: float, rate_hz: float, tol: float, state: FloatArray, i_next: int) -> bool:
    """Whether the sensor samples at ``t``: its next sample time ``k / rate`` is reached
    (every step for a rate of 0). Advances ``k`` past ``t`` when it does."""
    if rate_hz <= 0.0:
        return True
    k = state[i_next]
    if k < 0.0:  # first call (or a new rate): the first grid point at or after t
        k = math.ceil((t - tol) * rate_hz)
        state[i_next] = k
    if t >= k / rate_hz - tol:
        state[i_next] = math.floor((t + tol) * rate_hz) + 1.0
        return True
    return False


@njit
def _since(t: float, last: float) -> float:
    """Time since the sensor's previous sample (0 for the first)."""
    if math.isnan(last):
        return 0.0
    return max(t - last, 0.0)


@njit
def _push_slot(state: FloatArray, cap: int, i_head: int, i_count: int) -> int:
    """The FIFO slot for a new entry (the oldest one is overwritten when full)."""
    head = int(state[i_head])
    count = int(state[i_count])
    if count >= cap:
        head = (head + 1) % cap
        state[i_head] = float(head)
        count = cap - 1
    state[i_count] = float(count + 1)
    return (head + count) % cap


@njit
def _pop_ready(
    state: FloatArray, base: int, cap: int, width: int, i_t: int, i_head: int, i_count: int, t: float,
    lag: float, tol: float,
) -> int:  # fmt: skip
    """The slot of the newest entry due at ``t`` (``t_valid + lag <= t``, ``t_valid`` at offset
    ``i_t`` of an entry), removing it and any older one; -1 if none is due. The slot stays
    intact until the next push."""
    head = int(state[i_head])
    count = int(state[i_count])
    slot = -1
    while count > 0 and state[base + head * width + i_t] + lag <= t + tol:
        slot = head
        head = (head + 1) % cap
        count -= 1
    state[i_head] = float(head)
    state[i_count] = float(count)
    return slot


@njit
def _imu_sample(
    t: float, x: FloatArray, a_e: tuple[float, float, float], rt: Rot, seed: int, p: FloatArray,
    s: FloatArray, out: FloatArray,
) -> None:  # fmt: skip
    n = int(s[SNS_IMU_N])
    dt = _since(t, s[SNS_IMU_LAST_T])
    s[SNS_IMU_LAST_T] = t
    s[SNS_IMU_N] = float(n + 1)
    kg, ka = p[SNP_GYRO_WALK], p[SNP_ACCEL_WALK]
    if kg > 0.0 and dt > 0.0:
        e0, e1, e2 = _normal3(seed, STREAM_GYRO_WALK, n)
        sd = kg * math.sqrt(dt)
        s[SNS_GYRO_WALK] += sd * e0
        s[SNS_GYRO_WALK + 1] += sd * e1
        s[SNS_GYRO_WALK + 2] += sd * e2
    if ka > 0.0 and dt > 0.0:
        e0, e1, e2 = _normal3(seed, STREAM_ACCEL_WALK, n)
        sd = ka * math.sqrt(dt)
        s[SNS_ACCEL_WALK] += sd * e0
        s[SNS_ACCEL_WALK + 1] += sd * e1
        s[SNS_ACCEL_WALK + 2] += sd * e2
    sg, sa = p[SNP_GYRO_SIGMA], p[SNP_ACCEL_SIGMA]
    wg = _normal3(seed, STREAM_GYRO, n) if sg > 0.0 else (0.0, 0.0, 0.0)
    wa = _normal3(seed, STREAM_ACCEL, n) if sa > 0.0 else (0.0, 0.0, 0.0)
    out[OUT_IMU_T] = t
    fault = t >= p[SNP_IMU_FAULT_T]
    if fault and p[SNP_IMU_FREEZE] != 0.0 and s[SNS_IMU_OUT] > 0.0:
        s[SNS_IMU_OUT] += 1.0
        return  # the values stay
    ax, ay, az = a_e[0], a_e[1], a_e[2] + p[SNP_GRAVITY]
    for i in range(3):
        g = x[P_X + i] + p[SNP_GYRO_BIAS + i] + s[SNS_GYRO_WALK + i]
        f = rt[i] * ax + rt[3 + i] * ay + rt[6 + i] * az + p[SNP_ACCEL_BIAS + i] + s[SNS_ACCEL_WALK + i]
        if sg > 0.0:
            g += sg * wg[i]
        if sa > 0.0:
            f += sa * wa[i]
        if fault:
            g += p[SNP_GYRO_STEP + i]
            f += p[SNP_ACCEL_STEP + i]
        out[OUT_GYRO + i] = g
        out[OUT_ACCEL + i] = f
    s[SNS_IMU_OUT] += 1.0


@njit
def _gps_sample(t: float, x: FloatArray, seed: int, p: FloatArray, s: FloatArray) -> None:
    n = int(s[SNS_GPS_N])
    dt = _since(t, s[SNS_GPS_LAST_T])
    s[SNS_GPS_LAST_T] = t
    s[SNS_GPS_N] = float(n + 1)
    wh, wv = p[SNP_GPS_WANDER_H], p[SNP_GPS_WANDER_V]
    if wh > 0.0 or wv > 0.0:
        if s[SNS_GPS_WANDER_ON] == 0.0:  # a stationary start
            e0, e1, e2 = _normal3(seed, STREAM_GPS_WANDER_INIT, n)
            s[SNS_GPS_WANDER], s[SNS_GPS_WANDER + 1], s[SNS_GPS_WANDER + 2] = e0, e1, e2
            s[SNS_GPS_WANDER_ON] = 1.0
        elif dt > 0.0:
            r = dt / p[SNP_GPS_TAU_S]
            a = math.exp(-r)
            q = math.sqrt(-math.expm1(-2.0 * r))  # sqrt(1 - a^2), accurate for small r
            e0, e1, e2 = _normal3(seed, STREAM_GPS_WANDER, n)
            s[SNS_GPS_WANDER] = a * s[SNS_GPS_WANDER] + q * e0
            s[SNS_GPS_WANDER + 1] = a * s[SNS_GPS_WANDER + 1] + q * e1
            s[SNS_GPS_WANDER + 2] = a * s[SNS_GPS_WANDER + 2] + q * e2
    sh, sv, svel = p[SNP_GPS_SIGMA_H], p[SNP_GPS_SIGMA_V], p[SNP_GPS_VEL_SIGMA]
    wp = _normal3(seed, STREAM_GPS_POS, n) if sh > 0.0 or sv > 0.0 else (0.0, 0.0, 0.0)
    wvel = _normal3(seed, STREAM_GPS_VEL, n) if svel > 0.0 else (0.0, 0.0, 0.0)
    vel = velocity_nwu(x)
    cap = int(p[SNP_GPS_QUEUE_CAP])
    slot = _push_slot(s, cap, SNS_GPS_HEAD, SNS_GPS_COUNT)
    base = int(p[SNP_GPS_QUEUE]) + slot * GPS_REC
    s[base + GR_T] = t
    fault = t >= p[SNP_GPS_FAULT_T]
    for i in range(3):
        wander = wv if i == 2 else wh
        white = sv if i == 2 else sh
        pos = x[X_N + i]
        if wander > 0.0:
            pos += wander * s[SNS_GPS_WANDER + i]
        if white > 0.0:
            pos += white * wp[i]
        if fault:
            pos += p[SNP_GPS_STEP + i]
        v = vel[i]
        if svel > 0.0:
            v += svel * wvel[i]
        s[base + GR_POS + i] = pos
        s[base + GR_VEL + i] = v


@njit
def _gps_deliver(t: float, p: FloatArray, s: FloatArray, out: FloatArray) -> bool:
    cap = int(p[SNP_GPS_QUEUE_CAP])
    q0 = int(p[SNP_GPS_QUEUE])
    slot = _pop_ready(s, q0, cap, GPS_REC, GR_T, SNS_GPS_HEAD, SNS_GPS_COUNT, t, p[SNP_GPS_LAG_S],
                      p[SNP_TOL_S])  # fmt: skip
    if slot < 0 or p[SNP_GPS_DISABLED] != 0.0:
        return False
    base = q0 + slot * GPS_REC
    t_valid = s[base + GR_T]
    if p[SNP_GPS_OUTAGE_T0] <= t_valid < p[SNP_GPS_OUTAGE_T1]:
        return False
    out[OUT_GPS_T] = t_valid
    frozen = p[SNP_GPS_FREEZE] != 0.0 and t_valid >= p[SNP_GPS_FAULT_T] and s[SNS_GPS_OUT] > 0.0
    if not frozen:
        for i in range(3):
            out[OUT_GPS_POS + i] = s[base + GR_POS + i]
            out[OUT_GPS_VEL + i] = s[base + GR_VEL + i]
    # the receiver's own report (a frozen receiver does not know it is: status as usual)
    out[OUT_GPS_FIX_TYPE] = float(GPS_FIX_3D)
    out[OUT_GPS_SATS] = p[SNP_GPS_SATS]
    out[OUT_GPS_EPH_M] = p[SNP_GPS_EPH_M]
    out[OUT_GPS_EPV_M] = p[SNP_GPS_EPV_M]
    s[SNS_GPS_OUT] += 1.0
    return True


@njit
def _att_sample(t: float, x: FloatArray, seed: int, p: FloatArray, s: FloatArray) -> None:
    n = int(s[SNS_ATT_N])
    s[SNS_ATT_LAST_T] = t
    s[SNS_ATT_N] = float(n + 1)
    noisy = p[SNP_ATT_SIGMA] > 0.0 or p[SNP_ATT_SIGMA + 1] > 0.0 or p[SNP_ATT_SIGMA + 2] > 0.0
    w = _normal3(seed, STREAM_ATT, n) if noisy else (0.0, 0.0, 0.0)
    cap = int(p[SNP_ATT_QUEUE_CAP])
    slot = _push_slot(s, cap, SNS_ATT_HEAD, SNS_ATT_COUNT)
    base = int(p[SNP_ATT_QUEUE]) + slot * ATT_REC
    s[base + AR_T] = t
    fault = t >= p[SNP_ATT_FAULT_T]
    for i in range(3):
        e = x[PHI + i] + p[SNP_ATT_BIAS + i]
        if p[SNP_ATT_SIGMA + i] > 0.0:
            e += p[SNP_ATT_SIGMA + i] * w[i]
        if fault:
            e += p[SNP_ATT_STEP + i]
        s[base + AR_EULER + i] = e


@njit
def _att_deliver(t: float, p: FloatArray, s: FloatArray, out: FloatArray) -> bool:
    cap = int(p[SNP_ATT_QUEUE_CAP])
    q0 = int(p[SNP_ATT_QUEUE])
    slot = _pop_ready(s, q0, cap, ATT_REC, AR_T, SNS_ATT_HEAD, SNS_ATT_COUNT, t, p[SNP_ATT_LAG_S],
                      p[SNP_TOL_S])  # fmt: skip
    if slot < 0:
        return False
    base = q0 + slot * ATT_REC
    t_valid = s[base + AR_T]
    out[OUT_ATT_T] = t_valid
    frozen = p[SNP_ATT_FREEZE] != 0.0 and t_valid >= p[SNP_ATT_FAULT_T] and s[SNS_ATT_OUT] > 0.0
    if not frozen:
        for i in range(3):
            out[OUT_ATT + i] = s[base + AR_EULER + i]
    s[SNS_ATT_OUT] += 1.0
    return True


@njit
def _baro_sample(t: float, x: FloatArray, seed: int, p: FloatArray, s: FloatArray, out: FloatArray) -> None:
    n = int(s[SNS_BARO_N])
    dt = _since(t, s[SNS_BARO_LAST_T])
    s[SNS_BARO_LAST_T] = t
    s[SNS_BARO_N] = float(n + 1)
    s[SNS_BARO_DRIFT] += p[SNP_BARO_DRIFT] * dt
    sigma = p[SNP_BARO_SIGMA]
    w = normal(seed, STREAM_BARO, n) if sigma > 0.0 else 0.0
    out[OUT_BARO_T] = t
    fault = t >= p[SNP_BARO_FAULT_T]
    if fault and p[SNP_BARO_FREEZE] != 0.0 and s[SNS_BARO_OUT] > 0.0:
        s[SNS_BARO_OUT] += 1.0
        return
    alt = x[Z_U] + s[SNS_BARO_DRIFT]
    if sigma > 0.0:
        alt += sigma * w
    if fault:
        alt += p[SNP_BARO_STEP]
    out[OUT_BARO_ALT] = alt
    s[SNS_BARO_OUT] += 1.0


@njit
def _mag_sample(t: float, x: FloatArray, seed: int, p: FloatArray, s: FloatArray, out: FloatArray) -> None:
    n = int(s[SNS_MAG_N])
    s[SNS_MAG_LAST_T] = t
    s[SNS_MAG_N] = float(n + 1)
    sigma = p[SNP_MAG_SIGMA]
    w = _normal3(seed, STREAM_MAG, n) if sigma > 0.0 else (0.0, 0.0, 0.0)
    out[OUT_MAG_T] = t
    fault = t >= p[SNP_MAG_FAULT_T]
    if fault and p[SNP_MAG_FREEZE] != 0.0 and s[SNS_MAG_OUT] > 0.0:
        s[SNS_MAG_OUT] += 1.0
        return  # the values stay
    b = magnetic_field_flu(x, p, SNP_MAG_FIELD)
    for i in range(3):
        v = b[i] + p[SNP_MAG_HARD_IRON + i]
        if sigma > 0.0:
            v += sigma * w[i]
        if fault:
            v += p[SNP_MAG_STEP + i]
        out[OUT_MAG + i] = v
    s[SNS_MAG_OUT] += 1.0


@njit
def sensor_step(
    t_s: float, x: FloatArray, accel_earth_nwu: FloatArray, params: FloatArray, state: FloatArray,
    out: FloatArray,
) -> int:  # fmt: skip
    """One plant step of every sensor: ``x`` the true state at ``t_s``, ``accel_earth_nwu``
    the true c.g. acceleration ``d/dt (R v)`` there (gravity not included). Writes the new
    samples into ``out`` (layout in the module docstring) and returns the mask of the new
    ones (``NEW_IMU | NEW_GPS | NEW_ATT | NEW_BARO | NEW_MAG``). Call it once per step,
    with non-decreasing ``t_s``."""
    a = (accel_earth_nwu[0], accel_earth_nwu[1], accel_earth_nwu[2])
    return sensor_step3(t_s, x, a, params, state, out)


@njit
def sensor_step3(
    t_s: float, x: FloatArray, accel_earth_nwu: tuple[float, float, float], params: FloatArray,
    state: FloatArray, out: FloatArray,
) -> int:  # fmt: skip
    """:func:`sensor_step` with the acceleration as values (no array made for it)."""
    seed = int(params[SNP_SEED])
    tol = params[SNP_TOL_S]
    new = 0
    if _due(t_s, params[SNP_IMU_RATE_HZ], tol, state, SNS_IMU_NEXT):
        _imu_sample(t_s, x, accel_earth_nwu, _rot(x), seed, params, state, out)
        new |= NEW_IMU
    if _due(t_s, params[SNP_GPS_RATE_HZ], tol, state, SNS_GPS_NEXT):
        _gps_sample(t_s, x, seed, params, state)
    if _gps_deliver(t_s, params, state, out):
        new |= NEW_GPS
    if _due(t_s, params[SNP_ATT_RATE_HZ], tol, state, SNS_ATT_NEXT):
        _att_sample(t_s, x, seed, params, state)
    if _att_deliver(t_s, params, state, out):
        new |= NEW_ATT
    if _due(t_s, params[SNP_BARO_RATE_HZ], tol, state, SNS_BARO_NEXT):
        _baro_sample(t_s, x, seed, params, state, out)
        new |= NEW_BARO
    if _due(t_s, params[SNP_MAG_RATE_HZ], tol, state, SNS_MAG_NEXT):
        _mag_sample(t_s, x, seed, params, state, out)
        new |= NEW_MAG
    return new


# ---------------------------------------------------------------- arrays from a config


def _queue_slots(rate_hz: float, lag_s: float) -> int:
    """FIFO slots that hold every sample in flight: those taken within one lag, plus the
    one pushed before the step's delivery, plus margin for jitter."""
    if rate_hz <= 0.0:
        return 2
    return int(math.ceil(lag_s * rate_hz)) + 3


def gps_accuracy_m(config: Sensors) -> tuple[float, float]:
    """What the receiver reports as its 1-sigma position accuracy, (per horizontal axis,
    vertical) [m]: its error model's ``sqrt(noise^2 + wander^2)``, at least
    :data:`GPS_ACCURACY_FLOOR_M` (all it reports when its error model is off)."""
    g = config.gps
    if not g.on:
        return GPS_ACCURACY_FLOOR_M, GPS_ACCURACY_FLOOR_M
    h = math.sqrt(g.noise_h_m**2 + g.wander_h_m**2)
    v = math.sqrt(g.noise_v_m**2 + g.wander_v_m**2)
    return max(h, GPS_ACCURACY_FLOOR_M), max(v, GPS_ACCURACY_FLOOR_M)


def sensor_parameters(
    config: Sensors, step_s: float, gravity_m_s2: float, *, min_slots: tuple[int, int] = (0, 0),
    home: GeoPoint = HOME,
) -> FloatArray:  # fmt: skip
    """The compiled step's parameters for ``config`` at plant step ``step_s`` (layout: the
    SNP_* offsets). A sensor that is off gets rate 0 (every step) and no error terms; its
    failure settings still apply. ``min_slots``: the least GPS and attitude FIFO sizes (a
    live update never shrinks them, so the entries in flight fit). ``home``: where the
    magnetometer's earth field is taken (:mod:`heli_common.world.magnetic`; the vehicle flies
    within kilometres of it). ValueError: a field out of range, a non-positive step or
    gravity, or a sensor rate above the plant rate."""
    validate(config)
    h = float(step_s)
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f"step_s must be finite and > 0, got {step_s}")
    if not (math.isfinite(gravity_m_s2) and gravity_m_s2 > 0.0):
        raise ValueError(f"gravity_m_s2 must be finite and > 0, got {gravity_m_s2}")
    plant_hz = 1.0 / h
    for name in SENSOR_TABLES:
        part = getattr(config, name)
        if part.on and part.rate_hz > plant_hz * (1.0 + 1e-9):
            raise ValueError(f"{name}.rate_hz = {part.rate_hz} Hz exceeds the plant rate {plant_hz} Hz")
    p = np.zeros(N_SNP)
    p[SNP_SEED] = float(config.seed)
    p[SNP_TOL_S] = TOL_STEPS * h
    p[SNP_GRAVITY] = gravity_m_s2

    i = config.imu
    if i.on:
        root = math.sqrt(i.rate_hz)
        p[SNP_IMU_RATE_HZ] = i.rate_hz
        p[SNP_GYRO_SIGMA] = i.gyro_density_rad_s_rthz * root
        p[SNP_ACCEL_SIGMA] = i.accel_density_m_s2_rthz * root
        p[SNP_GYRO_BIAS : SNP_GYRO_BIAS + 3] = i.gyro_bias_rad_s
        p[SNP_ACCEL_BIAS : SNP_ACCEL_BIAS + 3] = i.accel_bias_m_s2
        p[SNP_GYRO_WALK] = i.gyro_walk_rad_s_rts
        p[SNP_ACCEL_WALK] = i.accel_walk_m_s2_rts
    p[SNP_IMU_FREEZE] = 1.0 if i.freeze else 0.0
    p[SNP_IMU_FAULT_T] = i.fault_start_s
    p[SNP_GYRO_STEP : SNP_GYRO_STEP + 3] = i.gyro_step_rad_s
    p[SNP_ACCEL_STEP : SNP_ACCEL_STEP + 3] = i.accel_step_m_s2

    g = config.gps
    p[SNP_GPS_TAU_S] = g.wander_tau_s
    if g.on:
        p[SNP_GPS_RATE_HZ] = g.rate_hz
        p[SNP_GPS_LAG_S] = g.lag_s
        p[SNP_GPS_SIGMA_H] = g.noise_h_m
        p[SNP_GPS_SIGMA_V] = g.noise_v_m
        p[SNP_GPS_WANDER_H] = g.wander_h_m
        p[SNP_GPS_WANDER_V] = g.wander_v_m
        p[SNP_GPS_VEL_SIGMA] = g.vel_noise_m_s
    p[SNP_GPS_DISABLED] = 1.0 if g.disabled else 0.0
    p[SNP_GPS_OUTAGE_T0] = g.outage_start_s
    p[SNP_GPS_OUTAGE_T1] = g.outage_start_s + g.outage_s
    p[SNP_GPS_FREEZE] = 1.0 if g.freeze else 0.0
    p[SNP_GPS_FAULT_T] = g.fault_start_s
    p[SNP_GPS_STEP : SNP_GPS_STEP + 3] = g.step_m
    p[SNP_GPS_SATS] = float(g.satellites)
    p[SNP_GPS_EPH_M], p[SNP_GPS_EPV_M] = gps_accuracy_m(config)

    a = config.attitude
    if a.on:
        p[SNP_ATT_RATE_HZ] = a.rate_hz
        p[SNP_ATT_LAG_S] = a.lag_s
        p[SNP_ATT_SIGMA : SNP_ATT_SIGMA + 3] = a.noise_rad
        p[SNP_ATT_BIAS : SNP_ATT_BIAS + 3] = a.bias_rad
    p[SNP_ATT_FREEZE] = 1.0 if a.freeze else 0.0
    p[SNP_ATT_FAULT_T] = a.fault_start_s
    p[SNP_ATT_STEP : SNP_ATT_STEP + 3] = a.step_rad

    b = config.baro
    if b.on:
        p[SNP_BARO_RATE_HZ] = b.rate_hz
        p[SNP_BARO_SIGMA] = b.noise_m
        p[SNP_BARO_DRIFT] = b.drift_m_s
    p[SNP_BARO_FREEZE] = 1.0 if b.freeze else 0.0
    p[SNP_BARO_FAULT_T] = b.fault_start_s
    p[SNP_BARO_STEP] = b.step_m

    mg = config.mag
    p[SNP_MAG_FIELD : SNP_MAG_FIELD + 3] = earth_field_nwu_gauss(home.lat_deg, home.lon_deg)
    if mg.on:
        p[SNP_MAG_RATE_HZ] = mg.rate_hz
        p[SNP_MAG_SIGMA] = mg.noise_gauss
        p[SNP_MAG_HARD_IRON : SNP_MAG_HARD_IRON + 3] = mg.hard_iron_gauss
    p[SNP_MAG_FREEZE] = 1.0 if mg.freeze else 0.0
    p[SNP_MAG_FAULT_T] = mg.fault_start_s
    p[SNP_MAG_STEP : SNP_MAG_STEP + 3] = mg.step_gauss

    gps_slots = max(_queue_slots(p[SNP_GPS_RATE_HZ], p[SNP_GPS_LAG_S]), min_slots[0])
    att_slots = max(_queue_slots(p[SNP_ATT_RATE_HZ], p[SNP_ATT_LAG_S]), min_slots[1])
    p[SNP_GPS_QUEUE] = float(N_SNS)
    p[SNP_GPS_QUEUE_CAP] = float(gps_slots)
    p[SNP_ATT_QUEUE] = float(N_SNS + gps_slots * GPS_REC)
    p[SNP_ATT_QUEUE_CAP] = float(att_slots)
    return p


def sensor_state(params: FloatArray) -> FloatArray:
    """A fresh state for ``params`` (layout: the SNS_* offsets, then the FIFOs): no sample
    taken, the schedules start at the first call, the bias walks at zero."""
    n = int(params[SNP_ATT_QUEUE]) + int(params[SNP_ATT_QUEUE_CAP]) * ATT_REC
    s = np.zeros(n)
    for i_next, i_last in (
        (SNS_IMU_NEXT, SNS_IMU_LAST_T),
        (SNS_GPS_NEXT, SNS_GPS_LAST_T),
        (SNS_ATT_NEXT, SNS_ATT_LAST_T),
        (SNS_BARO_NEXT, SNS_BARO_LAST_T),
        (SNS_MAG_NEXT, SNS_MAG_LAST_T),
    ):
        s[i_next] = -1.0
        s[i_last] = math.nan
    return s


def _move_queue(
    old_p: FloatArray, old_s: FloatArray, new_p: FloatArray, new_s: FloatArray, q: int, cap_i: int,
    head_i: int, count_i: int, width: int,
) -> None:  # fmt: skip
    """Carry the FIFO's entries, oldest first, into the new FIFO (at least as large)."""
    old_cap, new_cap = int(old_p[cap_i]), int(new_p[cap_i])
    head, count = int(old_s[head_i]), int(old_s[count_i])
    entries = [int(old_p[q]) + ((head + j) % old_cap) * width for j in range(count)][-new_cap:]
    base = int(new_p[q])
    for j, src in enumerate(entries):
        new_s[base + j * width : base + (j + 1) * width] = old_s[src : src + width]
    new_s[head_i] = 0.0
    new_s[count_i] = float(len(entries))


class SensorSamples(NamedTuple):
    """The samples one plant step produced (None: no new sample of that sensor)."""

    imu: ImuSample | None
    gps: GpsFix | None
    attitude: AttitudeSample | None
    baro: BaroSample | None
    mag: MagSample | None


def samples_from_out(out: FloatArray, mask: int) -> SensorSamples:
    """The NamedTuples of :mod:`heli_common.wire.measurements` for the samples flagged in ``mask``."""

    def v3(i: int) -> tuple[float, float, float]:
        return (float(out[i]), float(out[i + 1]), float(out[i + 2]))

    imu = ImuSample(float(out[OUT_IMU_T]), v3(OUT_GYRO), v3(OUT_ACCEL)) if mask & NEW_IMU else None
    gps = GpsFix(float(out[OUT_GPS_T]), v3(OUT_GPS_POS), v3(OUT_GPS_VEL)) if mask & NEW_GPS else None
    att = AttitudeSample(float(out[OUT_ATT_T]), v3(OUT_ATT)) if mask & NEW_ATT else None
    baro = BaroSample(float(out[OUT_BARO_T]), float(out[OUT_BARO_ALT])) if mask & NEW_BARO else None
    mag = MagSample(float(out[OUT_MAG_T]), v3(OUT_MAG)) if mask & NEW_MAG else None
    return SensorSamples(imu, gps, att, baro, mag)


class SensorModel:
    """A configured set of sensors for one plant running at ``step_s``; ``gravity_m_s2``
    must be the plant's (the airframe's), so that the accelerometer reads exactly +g at
    rest, and ``home`` the plant's (the magnetometer reads the earth's field there).
    :meth:`step` is :func:`sensor_step` with NamedTuples out; the compiled plant can call
    :func:`sensor_step` on :attr:`params`, :attr:`state` and :attr:`out` directly."""

    def __init__(self, config: Sensors, step_s: float, gravity_m_s2: float, home: GeoPoint = HOME) -> None:
        self.config = config
        self.step_s = float(step_s)
        self.gravity_m_s2 = float(gravity_m_s2)
        self.home = home
        self.params = sensor_parameters(config, self.step_s, self.gravity_m_s2, home=home)
        self.state = sensor_state(self.params)
        self.out = np.full(N_OUT, math.nan)
        # load (or compile) the kernel now, on copies, not on the first step
        sensor_step(0.0, np.zeros(N_STATE), np.zeros(3), self.params, self.state.copy(), self.out.copy())

    def step(self, t_s: float, x: FloatArray, accel_earth_nwu: FloatArray) -> SensorSamples:
        """The samples new at ``t_s`` for the true state ``x`` there and the true earth-frame
        acceleration (``d/dt (R v)``, gravity not included; see the module docstring)."""
        xs = np.ascontiguousarray(x, dtype=np.float64)
        a = np.ascontiguousarray(accel_earth_nwu, dtype=np.float64)
        if xs.shape != (N_STATE,) or a.shape != (3,):
            raise ValueError(f"x must have shape ({N_STATE},) and accel_earth_nwu (3,)")
        mask = sensor_step(float(t_s), xs, a, self.params, self.state, self.out)
        return samples_from_out(self.out, mask)

    def update(self, config: Sensors) -> None:
        """Take new settings from the next step on (live knobs, failures). The noise
        processes keep their state (counters, bias walks, GPS wander, baro drift), fixes in
        flight stay in their FIFO, and a sensor whose rate changed restarts its schedule on
        the new rate's grid. The plant step, gravity and home stay."""
        old_p, old_s = self.params, self.state
        slots = (int(old_p[SNP_GPS_QUEUE_CAP]), int(old_p[SNP_ATT_QUEUE_CAP]))
        new_p = sensor_parameters(config, self.step_s, self.gravity_m_s2, min_slots=slots, home=self.home)
        new_s = sensor_state(new_p)
        new_s[:N_SNS] = old_s[:N_SNS]
        for rate_i, next_i in (
            (SNP_IMU_RATE_HZ, SNS_IMU_NEXT),
            (SNP_GPS_RATE_HZ, SNS_GPS_NEXT),
            (SNP_ATT_RATE_HZ, SNS_ATT_NEXT),
            (SNP_BARO_RATE_HZ, SNS_BARO_NEXT),
            (SNP_MAG_RATE_HZ, SNS_MAG_NEXT),
        ):
            if new_p[rate_i] != old_p[rate_i]:
                new_s[next_i] = -1.0
        _move_queue(old_p, old_s, new_p, new_s, SNP_GPS_QUEUE, SNP_GPS_QUEUE_CAP, SNS_GPS_HEAD, SNS_GPS_COUNT,
                    GPS_REC)  # fmt: skip
        _move_queue(old_p, old_s, new_p, new_s, SNP_ATT_QUEUE, SNP_ATT_QUEUE_CAP, SNS_ATT_HEAD, SNS_ATT_COUNT,
                    ATT_REC)  # fmt: skip
        self.config, self.params, self.state = config, new_p, new_s
