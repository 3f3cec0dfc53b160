"""Servos and linkage: what sits between the held blade-pitch command and the blade (compiled).

One model, two users: the plant's world moves its servos with it, and a controller's command
filter (the rotor-aware TLC) runs the same model on what it sends, to know what was achieved.

Per channel (the four pitches of ``heli_common.state``), advanced once per plant (sub)step of
length ``h`` with the command held over the step::

    command -> transport delay -> quantum / dead band -> rate limit -> first-order lag -> limits

* Transport delay ``T_d``: a FIFO of whole steps, ``round(T_d / h)`` of them (so ``T_d`` is
  realised to the nearest step; choose it a multiple of ``h`` for an exact delay). ArduPilot's
  SITL servo model (``libraries/SITL/ServoModel.cpp``, ``SIM_SERVO_DELAY``) delays the same way,
  through a buffer of whole loop periods.
* Quantum ``q`` (the PWM resolution seen at the blade): the delayed command is rounded to the
  nearest multiple of ``q`` (halves round up); ``q = 0`` is off.
* Dead band ``d``: the target only moves when the quantised command differs from the current
  (rate-limited) target by more than ``d``; once moving it goes straight for the command, and a
  rate-limited move stops as soon as it is within ``d`` of it, as a servo amplifier does; ``d = 0``
  is off.
* Rate limit: the target moves at most ``rate * h`` per step, the slew limit a hobby servo's
  speed rating (seconds per 60 degrees of arm travel, ArduPilot's ``SIM_SERVO_SPEED``, 0.14 s by
  default) sets through the linkage (:func:`rate_limit_from_speed`); ``inf`` is off.
* Lag ``tau``: the exact zero-order-hold discretisation of ``tau y' = target - y``,
  ``y += (1 - exp(-h/tau)) (target - y)``; ``tau = 0`` is a pass-through. (With neither a delay nor
  a filter set, ArduPilot turns ``SIM_SERVO_SPEED`` into a first-order low-pass of this kind.)
* Limits ``[lo, hi]``: the target and the position are both clipped, so a command beyond a stop
  does not wind anything up: the servo leaves the stop as soon as the command does.

The output of a step is the servo position at the *end* of the step (where the discretisation
is exact): a step of the command reaches ``1 - exp(-t/tau)`` at ``t = (n + 1) h`` in step ``n``.
Against the held command that is the continuous lag ``atan(w tau) + w T_d``; held in turn by the
plant over the next step it leads the continuous servo by half a step (``w h / 2``).

With every element off (no delay, ``q = d = 0``, rate ``inf``, ``tau = 0``, the command inside the
limits) the output is the command, bit for bit: no arithmetic touches it.

``servo_step`` assumes a finite command (the plant refuses non-finite ones before they are held)
and does not check it in the hot path. As it happens a NaN fails the dead-band comparison, so
the target is held, but that is not a contract.

Parameters, ``params[channel, SP_*]`` (float64, shape ``(N_PITCH, N_SERVO_PARAM)``; the channel
is the pitch offset ``THETA_M``, ``THETA_T``, ``EPS``, ``ETA``):

    SP_DELAY_STEPS  delay in whole steps (a float holding an integer)
    SP_RATE_STEP    largest move of the target per step [rad] (rate * h; inf = off)
    SP_ALPHA        lag coefficient 1 - exp(-h/tau) (1.0 = pass-through)
    SP_LO, SP_HI    position limits [rad]
    SP_QUANTUM      quantum [rad] (0 = off)
    SP_DEADBAND     dead band half-width [rad] (0 = off)

State, one flat float64 array (``servo_state``):

    state[SS_RING_INDEX]                      next FIFO slot to write (a float holding an integer)
    state[SS_POSITION + channel]              servo (blade-pitch) position [rad]
    state[SS_TARGET + channel]                rate-limited target [rad]
    state[SS_FIFO + slot * N_PITCH + channel] FIFO ring of past commands [rad]; as many slots as
                                              the largest delay (none without a delay)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import N_PITCH, PITCH_NAMES, FloatArray
from heli_common.world.config import Servos

# params[channel, SP_*]: one row per channel
SERVO_PARAM = Layout(
    "servo parameters",
    ("delay_steps", 1), ("rate_step", 1), ("alpha", 1), ("lo", 1), ("hi", 1), ("quantum", 1), ("deadband", 1),
)  # fmt: skip
SP_DELAY_STEPS = SERVO_PARAM.offset("delay_steps")
SP_RATE_STEP = SERVO_PARAM.offset("rate_step")
SP_ALPHA = SERVO_PARAM.offset("alpha")
SP_LO = SERVO_PARAM.offset("lo")
SP_HI = SERVO_PARAM.offset("hi")
SP_QUANTUM = SERVO_PARAM.offset("quantum")
SP_DEADBAND = SERVO_PARAM.offset("deadband")
N_SERVO_PARAM = SERVO_PARAM.size

# state[SS_* + ...]: the fixed part; the FIFO ring (its slots set by the largest delay) follows
SERVO_STATE = Layout("servo state", ("ring_index", 1), ("position", N_PITCH), ("target", N_PITCH))
SS_RING_INDEX = SERVO_STATE.offset("ring_index")
SS_POSITION = SERVO_STATE.offset("position")
SS_TARGET = SERVO_STATE.offset("target")
SS_FIFO = SERVO_STATE.end

_DEG_60_RAD = math.pi / 3.0


def rate_limit_from_speed(t60_s: float, linkage_rad_per_rad: float) -> float:
    """Blade-pitch rate limit [rad/s] of a hobby servo rated ``t60_s`` seconds per 60 degrees
    of arm travel, driving the blade through ``linkage_rad_per_rad`` (blade pitch per arm
    angle): ``k (pi/3) / t60``. ``t60_s = 0`` (an ideal servo) gives ``inf``, the rate limit off.
    Example: 0.14 s/60 deg (ArduPilot's ``SIM_SERVO_SPEED`` default) with k = 0.178 -> 1.33 rad/s."""
    if not (math.isfinite(t60_s) and t60_s >= 0.0):
        raise ValueError(f"servo speed t60_s must be finite and >= 0 s per 60 deg, got {t60_s}")
    if not (math.isfinite(linkage_rad_per_rad) and linkage_rad_per_rad > 0.0):
        raise ValueError(f"linkage ratio must be finite and > 0 rad/rad, got {linkage_rad_per_rad}")
    if t60_s == 0.0:
        return math.inf
    return linkage_rad_per_rad * _DEG_60_RAD / t60_s


def _per_channel(item: str, values: Sequence[float]) -> list[float]:
    if len(values) != N_PITCH:
        raise ValueError(f"{item} needs one value per channel {PITCH_NAMES}, got {len(values)}")
    return [float(v) for v in values]


def _check(ok: bool, channel: int, item: str, value: float, rule: str) -> None:
    if not ok:
        raise ValueError(f"servo {PITCH_NAMES[channel]}: {item} must be {rule}, got {value}")


def servo_parameters(
    delay_s: Sequence[float],
    rate_rad_s: Sequence[float],
    tau_s: Sequence[float],
    lo_rad: Sequence[float],
    hi_rad: Sequence[float],
    quantum_rad: Sequence[float],
    deadband_rad: Sequence[float],
    step_s: float,
) -> FloatArray:
    """The per-channel parameter table for a step of ``step_s`` seconds (layout in the module
    docstring). Every item is one value per channel, in the order of ``PITCH_NAMES``. Raises
    ValueError naming the channel and the item for a value out of range: all must be finite
    and >= 0, except the rate, which must be > 0 (``inf`` = off; 0 would freeze the servo),
    and the limits, which may be negative but need ``lo < hi``."""
    h = float(step_s)
    if not (math.isfinite(h) and h > 0.0):
        raise ValueError(f"step_s must be finite and > 0, got {step_s}")
    delay = _per_channel("delay_s", delay_s)
    rate = _per_channel("rate_rad_s", rate_rad_s)
    tau = _per_channel("tau_s", tau_s)
    lo = _per_channel("lo_rad", lo_rad)
    hi = _per_channel("hi_rad", hi_rad)
    quantum = _per_channel("quantum_rad", quantum_rad)
    deadband = _per_channel("deadband_rad", deadband_rad)
    p = np.empty((N_PITCH, N_SERVO_PARAM))
    for i in range(N_PITCH):
        for item, v in (
            ("delay_s", delay[i]),
            ("tau_s", tau[i]),
            ("quantum_rad", quantum[i]),
            ("deadband_rad", deadband[i]),
        ):
            _check(math.isfinite(v) and v >= 0.0, i, item, v, "finite and >= 0")
        _check(rate[i] > 0.0, i, "rate_rad_s", rate[i], "> 0 (inf = off)")  # NaN fails too
        _check(math.isfinite(lo[i]), i, "lo_rad", lo[i], "finite")
        _check(math.isfinite(hi[i]), i, "hi_rad", hi[i], "finite")
        _check(lo[i] < hi[i], i, "lo_rad", lo[i], f"< hi_rad = {hi[i]}")
        p[i, SP_DELAY_STEPS] = float(round(delay[i] / h))
        p[i, SP_RATE_STEP] = rate[i] * h
        p[i, SP_ALPHA] = 1.0 if tau[i] == 0.0 else -math.expm1(-h / tau[i])
        p[i, SP_LO] = lo[i]
        p[i, SP_HI] = hi[i]
        p[i, SP_QUANTUM] = quantum[i]
        p[i, SP_DEADBAND] = deadband[i]
    return p


def servo_table(servos: Servos, limits: FloatArray, step_s: float) -> FloatArray:
    """:func:`servo_parameters` for a world's ``servos`` (a rate of 0 is none) and the
    airframe's pitch ``limits`` (4 x 2)."""
    rate = [r if r > 0.0 else math.inf for r in servos.rate_rad_s]
    lim = np.asarray(limits, dtype=float)
    return servo_parameters(servos.delay_s, rate, servos.tau_s, lim[:, 0].tolist(), lim[:, 1].tolist(),
                            servos.quantum_rad, servos.deadband_rad, step_s)  # fmt: skip


def fifo_slots(params: FloatArray) -> int:
    """Slots the FIFO ring needs: the largest delay in steps."""
    return int(np.max(params[:, SP_DELAY_STEPS]))


def servo_state(params: FloatArray, initial_rad: FloatArray) -> FloatArray:
    """A state at rest at ``initial_rad`` (layout in the module docstring): position, target
    and every FIFO slot hold it, so a command that starts there causes no start-up transient.
    ``initial_rad`` must be finite and inside each channel's limits."""
    params = np.asarray(params, dtype=float)
    if params.shape != (N_PITCH, N_SERVO_PARAM):
        raise ValueError(f"params must have shape ({N_PITCH}, {N_SERVO_PARAM}), got {params.shape}")
    x0 = np.asarray(initial_rad, dtype=float)
    if x0.shape != (N_PITCH,):
        raise ValueError(f"initial_rad must have shape ({N_PITCH},), got {x0.shape}")
    for i in range(N_PITCH):
        lo, hi = params[i, SP_LO], params[i, SP_HI]
        _check(bool(lo <= x0[i] <= hi), i, "initial_rad", float(x0[i]), f"finite and in [{lo}, {hi}]")
    state = np.empty(SS_FIFO + fifo_slots(params) * N_PITCH)
    servo_rest(state, x0)
    return state


@njit
def servo_rest(state: FloatArray, position: FloatArray) -> None:
    """``state`` (its size sets the FIFO's slots) at rest at ``position``: position, target
    and every FIFO slot hold it."""
    state[SS_RING_INDEX] = 0.0
    n_slots = (state.shape[0] - SS_FIFO) // N_PITCH
    for i in range(N_PITCH):
        state[SS_POSITION + i] = position[i]
        state[SS_TARGET + i] = position[i]
        for k in range(n_slots):
            state[SS_FIFO + k * N_PITCH + i] = position[i]


@njit
def servo_step(params: FloatArray, state: FloatArray, command: FloatArray, out: FloatArray) -> None:
    """Advance every channel one step with ``command`` [rad] held over it; write the blade
    pitches the rotor sees (the positions at the end of the step) into ``out``. ``command``
    must be finite (not checked)."""
    n_slots = (state.shape[0] - SS_FIFO) // N_PITCH
    k = int(state[SS_RING_INDEX])  # slot written now; it holds the command of n_slots steps ago
    for i in range(N_PITCH):
        v = command[i]
        delay = int(params[i, SP_DELAY_STEPS])
        if delay > 0:
            slot = k - delay  # written ``delay`` steps ago (read before this step's write)
            if slot < 0:
                slot += n_slots
            v = state[SS_FIFO + slot * N_PITCH + i]
        if n_slots > 0:
            state[SS_FIFO + k * N_PITCH + i] = command[i]

        q = params[i, SP_QUANTUM]
        if q > 0.0:
            v = q * np.floor(v / q + 0.5)

        lo = params[i, SP_LO]
        hi = params[i, SP_HI]
        target = state[SS_TARGET + i]
        err = v - target
        if abs(err) > params[i, SP_DEADBAND]:
            r = params[i, SP_RATE_STEP]
            if abs(err) <= r:
                target = v  # exact: no rounding when the rate limit does not bite
            elif err > 0.0:
                target += r
            else:
                target -= r
            target = min(max(target, lo), hi)
            state[SS_TARGET + i] = target

        alpha = params[i, SP_ALPHA]
        y = state[SS_POSITION + i]
        y = target if alpha == 1.0 else y + alpha * (target - y)
        y = min(max(y, lo), hi)
        state[SS_POSITION + i] = y
        out[i] = y
    if n_slots > 0:
        k += 1
        if k == n_slots:
            k = 0
        state[SS_RING_INDEX] = float(k)
