"""Loop 5 of the rotor-aware TLC: the main rotor's flapping as one more subsystem of the
cascade, and the command filter that models the servos (compiled; no I/O, no clock).

The paper's design model tilts the thrust the instant the cyclic moves. A real rotor with a
stabilizer bar answers through the tip-path plane's first-order flapping (Gavrilets, Mettler
& Feron 2001; ``heli_plant/rotor.py``)::

    a1' = -q - a1/tau_e + A_lon eps / tau_e,     b1' = -p - b1/tau_e + B_lat eta / tau_e

and the disc's tilt moments the body by ``K_beta + T_m h_m`` per rad (the hub spring and the
thrust's arm). Following the paper's method (docs/tlc-rotor.md):

* loop 4's torque command is allocated to the disc's tilt ``(a1_c, b1_c)`` (the design torque
  model with the hub spring: :func:`autopilot.tlc.allocation.collective_tail_tilt`);
* loop 5 inverts the flapping: the nominal cyclic ``(a1_c + tau_e (a1_c' + q)) / A_lon`` with
  ``a1_c'`` from a pseudo-differentiator, plus the error regulator ``tau_e k5 (a1_c - a1^)``;
* the flapping is not measured on a helicopter, so ``a1^, b1^`` come from an observer: the
  design model's flapping driven by the measured rates and the cyclic the servos achieved
  (``[rotor.observer] correction = "open_loop"``, the default), or that model corrected from
  the gyro (``"rate"``): the body rates are predicted one tick ahead from the hub moment of the
  estimated flapping, and the prediction error corrects ``a1^, b1^`` through a steady-state
  Kalman gain (:func:`observer_gain`);
* the command filter sends only what the modelled servos can follow (their position and
  rate limits) and runs the servo model (:mod:`heli_common.world.servo_model`, the plant's own) on
  it; the observer sees what was achieved. The integrators of loops 1-4 hold while a
  command is clipped at a position limit (as the paper's TLC), not while it is slowed to the
  rate limit: a rate limit passes in a tick or two, and holding every integral through the
  many short slews of turbulence starved them (with a 10 % heavier plant the vertical
  integral never caught up, and the pitch axis fell into a bang-bang limit cycle).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from autopilot.tlc.allocation import main_rotor_torque
from autopilot.tlc.differentiator import DiffCoeffs, diff_reset, diff_step, discretize
from autopilot.tlc.gains import RotorAwareGains, RotorObserverGains
from heli_common.config import ConfigError
from heli_common.jit import njit
from heli_common.state import EPS, ETA, N_PITCH, THETA_M, THETA_T, FloatArray
from heli_common.vehicle import rotor
from heli_common.vehicle.airframe import Airframe, PlantConstants
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world import servo_model
from heli_common.world.config import Servos, World

MAX_SERVO_DELAY_TICKS = 4  # the command filter's servo FIFO: delays up to 4 control periods
SERVO_STATE_SIZE = servo_model.SS_FIFO + MAX_SERVO_DELAY_TICKS * N_PITCH


class RotorAwareConstants(NamedTuple):
    on: bool
    tau_e_s: float  # the stabilizer bar's flapping time constant at the nominal rotor speed
    phi: float  # exp(-dt / tau_e): the observer's exact one-tick decay
    k_hub_n_m: float  # K_beta [N m/rad]
    a_lon: float  # A_lon, B_lat [rad/rad]
    b_lat: float
    k5: float  # loop 5's error rate beyond 1/tau_e [rad/s]
    diff: DiffCoeffs
    servo_p: FloatArray  # (4, N_SERVO_PARAM) at the control period; the filter's servo model
    n_servo_state: int  # the servo model's state size (FIFO for its delay)
    dt_s: float  # the control period
    correct: bool  # the observer corrects from the gyro ([rotor.observer] correction = "rate")
    obs_gain: FloatArray  # (4, 2): the Kalman gain of OBS_STATES on the innovation in (p, q)


# the rate-corrected observer's state and measurement, in this order (obs_gain's rows, columns)
OBS_STATES = ("p", "q", "a1", "b1")
OBS_MEASURED = ("p", "q")
OG_P, OG_Q, OG_A1, OG_B1 = (OBS_STATES.index(n) for n in OBS_STATES)


def _off(dt_s: float) -> RotorAwareConstants:
    p = servo_model.servo_parameters((0.0,) * 4, (math.inf,) * 4, (0.0,) * 4, (-1.0,) * 4, (1.0,) * 4,
                                     (0.0,) * 4, (0.0,) * 4, dt_s)  # fmt: skip
    return RotorAwareConstants(False, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, discretize(1.0, 1.0, dt_s), p,
                               servo_model.SS_FIFO, dt_s, False, np.zeros((4, 2)))  # fmt: skip


def observer_model(c: PlantConstants, tau_e_s: float, k_hub: float) -> FloatArray:
    """The design model of the rate-corrected observer, linearised about hover (thrust m g, no
    rates): ``x' = A x`` on ``x = (p, q, a1, b1)``. The body rates answer the hub moment of the
    flapping, ``J omega' = dQ/da1 a1 + dQ/db1 b1`` with loop 4's torque model
    (``dQ/da1 = (Q_m, T_m h_m + K_beta, 0)``, ``dQ/db1 = (T_m h_m + K_beta, -Q_m, -T_m l_m)``), and
    the flapping lags the rates, ``a1' = -q - a1/tau_e`` (``b1`` with ``p``)."""
    j = np.array([[c.ixx, 0.0, -c.ixz], [0.0, c.iyy, 0.0], [-c.ixz, 0.0, c.izz]])
    j_inv = np.linalg.inv(j)
    tm = c.mass_kg * c.gravity_m_s2
    qm = main_rotor_torque(tm, c)
    lever = tm * c.hm + k_hub
    da1 = j_inv @ np.array([qm, lever, 0.0])
    db1 = j_inv @ np.array([lever, -qm, -tm * c.lm])
    a = np.zeros((4, 4))
    a[OG_P, OG_A1], a[OG_P, OG_B1] = da1[0], db1[0]
    a[OG_Q, OG_A1], a[OG_Q, OG_B1] = da1[1], db1[1]
    a[OG_A1, OG_Q], a[OG_A1, OG_A1] = -1.0, -1.0 / tau_e_s
    a[OG_B1, OG_P], a[OG_B1, OG_B1] = -1.0, -1.0 / tau_e_s
    return a


def observer_gain(a: FloatArray, o: RotorObserverGains, dt_s: float) -> FloatArray:
    """The steady-state Kalman gain (4, 2) of the model ``a`` discretised at ``dt_s`` (zero-order
    hold; the process noise by Van Loan's method): white angular accelerations of intensity
    ``moment_noise`` on p and q, white flapping rates of intensity ``flapping_noise`` on a1 and
    b1, the gyro's noise ``gyro_noise`` per tick on the measured p and q. The filter's form is
    ``x+ = x- + K (y - C x-)`` (the gain on the a-priori estimate)."""
    n = a.shape[0]
    qc = np.diag([o.moment_noise_rad_s2_rthz**2] * 2 + [o.flapping_noise_rad_s_rthz**2] * 2)
    vl = np.zeros((2 * n, 2 * n))
    vl[:n, :n], vl[:n, n:], vl[n:, n:] = -a * dt_s, qc * dt_s, a.T * dt_s
    e = expm(vl)
    f = e[n:, n:].T
    qd = f @ e[:n, n:]
    qd = 0.5 * (qd + qd.T)
    cm = np.zeros((2, n))
    cm[0, OG_P], cm[1, OG_Q] = 1.0, 1.0
    r = np.eye(2) * o.gyro_noise_rad_s**2
    p = solve_discrete_are(f.T, cm.T, qd, r)
    k: FloatArray = p @ cm.T @ np.linalg.inv(cm @ p @ cm.T + r)
    return k


def observer_poles(a: FloatArray, k: FloatArray, dt_s: float) -> FloatArray:
    """The estimate error's discrete poles ``eig((I - K C) F)``, as continuous rates ``ln(z)/dt``."""
    f = expm(a * dt_s)
    cm = np.zeros((2, a.shape[0]))
    cm[0, OG_P], cm[1, OG_Q] = 1.0, 1.0
    z = np.linalg.eigvals((np.eye(a.shape[0]) - k @ cm) @ f)
    out: FloatArray = np.log(z.astype(complex)) / dt_s
    return out


def design_servos(name: str) -> Servos:
    """The servos a gain set names: a world preset's (``ideal``: none)."""
    return Servos() if name == "ideal" else World.load(name).servos


def rotor_aware_constants(g: RotorAwareGains | None, airframe: Airframe, dt_s: float) -> RotorAwareConstants:
    """Loop 5's constants from the gains' design plant and servos (off without ``g``)."""
    if g is None:
        return _off(dt_s)
    try:
        model = PlantModel.load(g.design_plant)
        servos = design_servos(g.servos)
    except ConfigError as exc:
        raise ConfigError(f"gains [rotor]: {exc}") from exc
    if model.rotor is None:
        raise ValueError(f"rotor.design_plant {g.design_plant!r} has no rotor: name a plant file "
                         "with flapping")  # fmt: skip
    rp = model.rotor
    tau = rp.tau_e_s()
    # the quantum and the dead band are left out of the filter's model: their steps would hide
    # small cyclic moves from the observer, which should see the servo's mean response
    sv = dataclasses.replace(servos, quantum_rad=(0.0,) * 4, deadband_rad=(0.0,) * 4)
    p = servo_model.servo_table(sv, np.array(airframe.limits.as_tuple()), dt_s)
    slots = servo_model.fifo_slots(p)
    if slots > MAX_SERVO_DELAY_TICKS:
        raise ValueError(f"rotor.servos {g.servos!r}: a delay of {slots} control periods; the command "
                         f"filter models at most {MAX_SERVO_DELAY_TICKS}")  # fmt: skip
    fl = rp.flapping
    correct = g.observer.correction == "rate"
    gain = np.zeros((4, 2))
    if correct:
        obs_model = observer_model(airframe.constants(), tau, fl.hub_stiffness_n_m_per_rad)
        gain = observer_gain(obs_model, g.observer, dt_s)
    return RotorAwareConstants(
        on=True, tau_e_s=tau, phi=math.exp(-dt_s / tau), k_hub_n_m=fl.hub_stiffness_n_m_per_rad,
        a_lon=fl.lon_gain_rad_per_rad, b_lat=fl.lat_gain_rad_per_rad, k5=g.flapping_rate_rad_s,
        diff=discretize(g.differentiator.omega_rad_s, g.differentiator.zeta, dt_s), servo_p=p,
        n_servo_state=servo_model.SS_FIFO + slots * N_PITCH, dt_s=dt_s, correct=correct, obs_gain=gain,
    )  # fmt: skip


@njit
def flapping_inversion(
    r: RotorAwareConstants, s: FloatArray, d_flap: int, flap_hat: int, tilt: FloatArray,
    p: float, q: float, first: bool,
) -> tuple[float, float]:  # fmt: skip
    """Loop 5: the disc's tilt command ``tilt`` (a1_c, b1_c) -> the cyclic (eps, eta) [rad].
    ``s[d_flap:+6]`` is the pseudo-differentiator's state, ``s[flap_hat:+2]`` the observer's."""
    cmd = np.zeros(3)
    cmd[0], cmd[1] = tilt[0], tilt[1]
    if first:
        diff_reset(s, d_flap, cmd)
        s[flap_hat], s[flap_hat + 1] = tilt[0], tilt[1]
    d1 = np.empty(3)
    unused = np.empty(3)
    diff_step(s, d_flap, cmd, r.diff, d1, unused)
    ea = tilt[0] - s[flap_hat]
    eb = tilt[1] - s[flap_hat + 1]
    eps = (tilt[0] + r.tau_e_s * (d1[0] + q + r.k5 * ea)) / r.a_lon
    eta = (tilt[1] + r.tau_e_s * (d1[1] + p + r.k5 * eb)) / r.b_lat
    return eps, eta


@njit
def command_filter(
    r: RotorAwareConstants, s: FloatArray, sent: int, servo: int, desired: FloatArray,
    lim: FloatArray, first: bool, achieved: FloatArray,
) -> tuple[FloatArray, int, int]:  # fmt: skip
    """What the servos can follow: ``desired`` clipped to the position limits ``lim`` and
    moved at most one tick's rate from the last command sent (``s[sent:+4]``); the servo
    model (``s[servo:]``) then runs on it and writes the achieved pitches into ``achieved``.
    Returns (the command to send, mask of the channels clipped at a position limit, mask of
    those slowed to the rate limit: 1, 2, 4, 8 each)."""
    out = np.empty(N_PITCH)
    clipped = 0
    slowed = 0
    if first:
        for i in range(N_PITCH):
            s[sent + i] = min(max(desired[i], lim[i, 0]), lim[i, 1])
        servo_model.servo_rest(s[servo : servo + r.n_servo_state], s[sent : sent + N_PITCH])
    for i in range(N_PITCH):
        v = min(max(desired[i], lim[i, 0]), lim[i, 1])
        if v != desired[i]:
            clipped |= 1 << i
        step = r.servo_p[i, servo_model.SP_RATE_STEP]
        last = s[sent + i]
        if v > last + step:
            v = last + step
            slowed |= 1 << i
        elif v < last - step:
            v = last - step
            slowed |= 1 << i
        out[i] = v
        s[sent + i] = v
    servo_model.servo_step(r.servo_p, s[servo : servo + r.n_servo_state], out, achieved)
    return out, clipped, slowed


@njit
def observe_flapping(r: RotorAwareConstants, s: FloatArray, flap_hat: int, achieved: FloatArray,
                     p: float, q: float) -> None:  # fmt: skip
    """One tick of the design model's flapping, exact under the rates and cyclic held:
    ``a1 -> phi a1 + (1 - phi)(A_lon eps - tau_e q)`` (and b1 with p, eta)."""
    g = 1.0 - r.phi
    s[flap_hat] = r.phi * s[flap_hat] + g * (r.a_lon * achieved[EPS] - r.tau_e_s * q)
    s[flap_hat + 1] = r.phi * s[flap_hat + 1] + g * (r.b_lat * achieved[ETA] - r.tau_e_s * p)


@njit
def correct_flapping(r: RotorAwareConstants, s: FloatArray, flap_hat: int, rate_hat: int, p: float, q: float,
                     first: bool) -> None:  # fmt: skip
    """The rate-corrected observer's measurement update (``r.correct``), before loop 5 reads
    the estimate: the measured ``p, q`` against their one-tick prediction ``s[rate_hat:+2]``
    correct ``a1^, b1^`` (``s[flap_hat:+2]``) and the rates' estimate by the Kalman gain. On the
    first tick the prediction is the measurement (no innovation)."""
    if first:
        s[rate_hat], s[rate_hat + 1] = p, q
        return
    k = r.obs_gain
    ep = p - s[rate_hat]
    eq = q - s[rate_hat + 1]
    s[rate_hat] += k[OG_P, 0] * ep + k[OG_P, 1] * eq
    s[rate_hat + 1] += k[OG_Q, 0] * ep + k[OG_Q, 1] * eq
    s[flap_hat] += k[OG_A1, 0] * ep + k[OG_A1, 1] * eq
    s[flap_hat + 1] += k[OG_B1, 0] * ep + k[OG_B1, 1] * eq


@njit
def predict_rates_and_flapping(
    r: RotorAwareConstants, c: PlantConstants, j: FloatArray, j_inv: FloatArray, s: FloatArray, flap_hat: int,
    rate_hat: int, achieved: FloatArray, yaw_rate: float,
) -> None:  # fmt: skip
    """The rate-corrected observer's one-tick prediction (``r.correct``), from the corrected
    estimate and the pitches the servos achieved, held: the flapping as
    :func:`observe_flapping` on the estimated rates, then the rates from the design model's
    torque (loop 4's: ``Q = QA (T_t, a1, b1) + QB`` with the hub spring, thrusts from the
    achieved collective and tail pitch through the design rotor maps) at the tick's mean
    flapping, ``omega+ = omega + dt J^-1 (Q - omega x J omega)``."""
    p0, q0 = s[rate_hat], s[rate_hat + 1]
    a0, b0 = s[flap_hat], s[flap_hat + 1]
    g = 1.0 - r.phi
    a1 = r.phi * a0 + g * (r.a_lon * achieved[EPS] - r.tau_e_s * q0)
    b1 = r.phi * b0 + g * (r.b_lat * achieved[ETA] - r.tau_e_s * p0)
    am, bm = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
    tm = rotor.thrust_coeff(achieved[THETA_M], c.a_m, c.s_m) * c.thrust_scale_m
    tt = rotor.thrust_coeff(achieved[THETA_T], c.a_t, c.s_t) * c.thrust_scale_t
    qm = main_rotor_torque(tm, c)
    lever = tm * c.hm + r.k_hub_n_m
    q_l = c.ht * tt + qm * am + lever * bm
    q_m = lever * am - qm * bm + tm * c.lm
    q_n = c.lt * tt - tm * c.lm * bm - qm
    w0, w1, w2 = p0, q0, yaw_rate
    h0 = j[0, 0] * w0 + j[0, 1] * w1 + j[0, 2] * w2
    h1 = j[1, 0] * w0 + j[1, 1] * w1 + j[1, 2] * w2
    h2 = j[2, 0] * w0 + j[2, 1] * w1 + j[2, 2] * w2
    t0 = q_l - (w1 * h2 - w2 * h1)
    t1 = q_m - (w2 * h0 - w0 * h2)
    t2 = q_n - (w0 * h1 - w1 * h0)
    dt = r.dt_s
    s[rate_hat] = p0 + dt * (j_inv[0, 0] * t0 + j_inv[0, 1] * t1 + j_inv[0, 2] * t2)
    s[rate_hat + 1] = q0 + dt * (j_inv[1, 0] * t0 + j_inv[1, 1] * t1 + j_inv[1, 2] * t2)
    s[flap_hat], s[flap_hat + 1] = a1, b1
