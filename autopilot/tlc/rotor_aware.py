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
  design model's flapping driven by the measured rates and the cyclic the servos achieved;
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

from autopilot.tlc.differentiator import DiffCoeffs, diff_reset, diff_step, discretize
from autopilot.tlc.gains import RotorAwareGains
from heli_common.config import ConfigError
from heli_common.jit import njit
from heli_common.state import EPS, ETA, N_PITCH, FloatArray
from heli_common.vehicle.airframe import Airframe
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


def _off(dt_s: float) -> RotorAwareConstants:
    p = servo_model.servo_parameters((0.0,) * 4, (math.inf,) * 4, (0.0,) * 4, (-1.0,) * 4, (1.0,) * 4,
                                     (0.0,) * 4, (0.0,) * 4, dt_s)  # fmt: skip
    return RotorAwareConstants(False, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, discretize(1.0, 1.0, dt_s), p,
                               servo_model.SS_FIFO)  # fmt: skip


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
    return RotorAwareConstants(
        on=True, tau_e_s=tau, phi=math.exp(-dt_s / tau), k_hub_n_m=fl.hub_stiffness_n_m_per_rad,
        a_lon=fl.lon_gain_rad_per_rad, b_lat=fl.lat_gain_rad_per_rad, k5=g.flapping_rate_rad_s,
        diff=discretize(g.differentiator.omega_rad_s, g.differentiator.zeta, dt_s), servo_p=p,
        n_servo_state=servo_model.SS_FIFO + slots * N_PITCH,
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
