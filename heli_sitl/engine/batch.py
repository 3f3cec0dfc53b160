"""The compiled step of N vehicles (the Gymnasium environments' engine): one call, one tick each.

Each vehicle is the in-process loop's flight (:mod:`heli_sitl.engine.closed_loop`) cut at its
control ticks: the command for tick i comes from outside (an action: blade pitches, or a
residual on a built-in law's command), then the very pieces of the compiled loop run,
:func:`~heli_sitl.engine.closed_loop._advance` (the sim link's rounding, the world, the plant)
and :func:`~heli_sitl.engine.closed_loop._observe` (the sensors and the estimator) or the sim
link's state, and :func:`~autopilot.control.control_law` (the built-in law, in residual mode).
A zero residual on the TLC is therefore the in-process flight, bit for bit.

Per-vehicle arrays are stacked on a first axis of N (row v is vehicle v's ``ws``, ``sns``,
...); what all vehicles share (constants, the trajectory's samples) is passed once, read
only. The per-tick logs the loop keeps (estimates, air, servo truth) go to a two-row window
per vehicle: only the row of the current tick is ever read. Every scratch is per vehicle
(:data:`SCRATCH`, the windows), so that no two vehicles write to the same memory: the
vehicles are stepped by one function, :func:`step_vehicle`, in a serial loop
(:func:`batch_step`, the single env) or a parallel one on numba's threads
(:func:`batch_step_parallel`, the vectorised env), with the same bits for any number of
threads. The observation's layout is :data:`OBS`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from numba.typed import List

from autopilot.control import D_SAT_MASK, D_STATUS, OK, control_law
from autopilot.reference import ACC_0, POS_0, VEL_0
from heli_common.jit import njit, prange
from heli_common.kinematics import rot_euler_entries
from heli_common.layout import Layout
from heli_common.state import N_PITCH, N_STATE, PHI, PSI, THETA, U_F, X_N, Z_U, FloatArray
from heli_common.vehicle.airframe import PlantConstants
from heli_common.wire.mavlink.sim_protocol import pitches_as_received, state_as_received
from heli_common.world.servo_model import servo_rest
from heli_plant.rotor import RotorConstants
from heli_plant.world.model import AirConstants
from heli_sitl.engine.closed_loop import _advance, _observe

# the observation: the measured state (the plant's layout, heli_common.state), the errors
# against the reference in earth NWU (measured minus reference; 0 where the reference does
# not know a derivative), the reference's acceleration, and the command block: the built-in
# law's command this tick (residual mode) or the previous action (pitch mode), normalised
# to [-1, 1] by the pitch limits
OBS = Layout(
    "observation",
    ("state", N_STATE), ("pos_err_nwu_m", 3), ("vel_err_nwu_m_s", 3), ("acc_ref_nwu_m_s2", 3),
    ("command_norm", N_PITCH),
)  # fmt: skip
O_STATE = OBS.offset("state")
O_POS_ERR = OBS.offset("pos_err_nwu_m")
O_VEL_ERR = OBS.offset("vel_err_nwu_m_s")
O_ACC_REF = OBS.offset("acc_ref_nwu_m_s2")
O_COMMAND = OBS.offset("command_norm")
N_OBS = OBS.size

# the environment's constants, one float array (index names below)
ENV_PARAMS = Layout(
    "environment parameters",
    ("residual", 1),  # 1: the action is a residual on the built-in law's command; 0: the pitches
    ("residual_scale", 1),  # a residual of 1 moves a pitch by this fraction of its half range
    ("servos_on", 1),  # the world's servos start where the first command puts them
    ("settle_s", 1), ("max_error_m", 1), ("max_tilt_deg", 1), ("ground_m", 1), ("max_touchdown_m_s", 1),
    ("w_alive", 1), ("w_pos", 1), ("w_att", 1), ("w_effort", 1),  # the default reward's weights
)  # fmt: skip
EP_RESIDUAL = ENV_PARAMS.offset("residual")
EP_SCALE = ENV_PARAMS.offset("residual_scale")
EP_SERVOS_ON = ENV_PARAMS.offset("servos_on")
EP_SETTLE = ENV_PARAMS.offset("settle_s")
EP_MAX_ERR = ENV_PARAMS.offset("max_error_m")
EP_MAX_TILT = ENV_PARAMS.offset("max_tilt_deg")
EP_GROUND = ENV_PARAMS.offset("ground_m")
EP_TOUCHDOWN = ENV_PARAMS.offset("max_touchdown_m_s")
EP_W_ALIVE = ENV_PARAMS.offset("w_alive")
EP_W_POS = ENV_PARAMS.offset("w_pos")
EP_W_ATT = ENV_PARAMS.offset("w_att")
EP_W_EFFORT = ENV_PARAMS.offset("w_effort")
N_ENV_PARAMS = ENV_PARAMS.size

# each vehicle's own scalars (one float row per vehicle)
VEHICLE = Layout("vehicle", ("descent_m_s", 1), ("left", 1))
V_DESCENT = VEHICLE.offset("descent_m_s")  # the last tick's descent rate (the strike rule's approach)
V_LEFT = VEHICLE.offset("left")  # why the vehicle left the envelope (LEFT_*), 0 inside
N_VEHICLE = VEHICLE.size

# each vehicle's scratch of a step (one float row per vehicle: never shared between vehicles)
SCRATCH = Layout(
    "step scratch",
    ("action", N_PITCH),  # the action clipped to [-1, 1]
    ("command", N_PITCH),  # the pitches it asks for [rad]
    ("first", N_PITCH),  # the first command as the servos receive it
    ("x_prev", N_STATE),  # the state before the step (the envelope's descent rate)
    ("command_norm", N_PITCH),  # the observation's command block
)
S_ACTION = SCRATCH.offset("action")
S_COMMAND = SCRATCH.offset("command")
S_FIRST = SCRATCH.offset("first")
S_X_PREV = SCRATCH.offset("x_prev")
S_COMMAND_NORM = SCRATCH.offset("command_norm")
N_SCRATCH = SCRATCH.size

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

# why a flight left the safety envelope (autopilot.envelope's rules, in its order)
LEFT_NONE, LEFT_NON_FINITE, LEFT_TILT, LEFT_STRIKE, LEFT_ERROR = 0, 1, 2, 3, 4


@njit
def fill_observation(xc: FloatArray, ref: FloatArray, command_norm: FloatArray, obs: FloatArray) -> None:
    """The observation (layout :data:`OBS`) of measured state ``xc`` against reference row
    ``ref``, with the command block ``command_norm``, into ``obs``."""
    for k in range(N_STATE):
        obs[O_STATE + k] = xc[k]
    # the body velocity in earth NWU: Rt's rows (as scalars, no matrix made) times it
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rot_euler_entries(xc[PHI], xc[THETA], xc[PSI])
    uf, vf, wf = xc[U_F], xc[U_F + 1], xc[U_F + 2]
    v_nwu = (r00 * uf + r01 * vf + r02 * wf, r10 * uf + r11 * vf + r12 * wf, r20 * uf + r21 * vf + r22 * wf)
    for k in range(3):
        obs[O_POS_ERR + k] = xc[X_N + k] - ref[POS_0 + k]
        v = v_nwu[k]
        rv, ra = ref[VEL_0 + k], ref[ACC_0 + k]
        obs[O_VEL_ERR + k] = v - rv if math.isfinite(rv) else 0.0
        obs[O_ACC_REF + k] = ra if math.isfinite(ra) else 0.0
    for k in range(N_PITCH):
        obs[O_COMMAND + k] = command_norm[k]


@njit
def normalise_pitches(u: FloatArray, lo: FloatArray, hi: FloatArray, out: FloatArray) -> None:
    """Pitches ``u`` [rad] as [-1, 1] of the limits (the sim link's normalisation)."""
    for k in range(N_PITCH):
        out[k] = 2.0 * (u[k] - lo[k]) / (hi[k] - lo[k]) - 1.0


@njit
def command_from_action(
    action: FloatArray, base: FloatArray, lo: FloatArray, hi: FloatArray, residual: bool, scale: float,
    a_out: FloatArray, u_out: FloatArray,
) -> None:  # fmt: skip
    """The action clipped to [-1, 1] (into ``a_out``) and the pitches it asks for, not yet
    clipped to the limits (into ``u_out``): the residual ``base + scale * a * (hi - lo) / 2``
    on the built-in law's command ``base``, or the pitches ``lo + (a + 1) (hi - lo) / 2``."""
    for k in range(N_PITCH):
        a = min(max(action[k], -1.0), 1.0)
        a_out[k] = a
        half = 0.5 * (hi[k] - lo[k])
        u_out[k] = base[k] + scale * a * half if residual else lo[k] + (a + 1.0) * half


@njit
def _left_envelope(
    x: FloatArray, x_prev: FloatArray, ref: FloatArray, t1: float, t0: float, vs: FloatArray, ep: FloatArray
) -> int:
    """Why the step from ``x_prev`` (at ``t0``) to ``x`` (at ``t1``) leaves the safety envelope
    (:class:`autopilot.envelope.Envelope`'s rules, tick by tick; LEFT_NONE inside); the
    descent rate kept in ``vs`` for the next tick's strike rule."""
    for k in range(N_STATE):
        if not math.isfinite(x[k]):
            return LEFT_NON_FINITE
    c = min(max(math.cos(x[PHI]) * math.cos(x[THETA]), -1.0), 1.0)
    if math.degrees(math.acos(c)) > ep[EP_MAX_TILT]:
        return LEFT_TILT
    dt = t1 - t0
    down = (x_prev[Z_U] - x[Z_U]) / dt if dt > 0.0 else 0.0
    approach = max(down, vs[V_DESCENT])
    vs[V_DESCENT] = down
    if x[Z_U] <= ep[EP_GROUND] + 1e-6 and approach > ep[EP_TOUCHDOWN]:
        return LEFT_STRIKE
    e2 = 0.0
    for k in range(3):
        e2 += (ref[POS_0 + k] - x[X_N + k]) ** 2
    if t1 >= ep[EP_SETTLE] - 1e-9 and math.sqrt(e2) > ep[EP_MAX_ERR]:
        return LEFT_ERROR
    return LEFT_NONE


@njit
def _tick_observation(
    v: int, i: int, kc: Any, c: PlantConstants, air: AirConstants, g: RotorConstants, t: FloatArray,
    refs: FloatArray, lo: FloatArray, hi: FloatArray, in_world: bool, sensing: bool, ep: FloatArray,
    home: FloatArray, eparams: FloatArray, x: FloatArray, held: FloatArray, ws: FloatArray, wp: FloatArray,
    snp: FloatArray, sns: FloatArray, meas: FloatArray, est: FloatArray, loop_s: FloatArray,
    ctrl: FloatArray, diag: FloatArray, base: FloatArray, last_a: FloatArray, obs: FloatArray,
    xh2: FloatArray, el2: FloatArray, cmd: FloatArray,
) -> None:  # fmt: skip
    """Vehicle ``v`` at tick ``i``: what the controller sees (the estimate from the sensors, or
    the state as the sim link carries it), the built-in law's command on it (residual mode),
    the observation (its command block through ``cmd``, scratch)."""
    if sensing:  # tick i as row 1 of a two-row window (row 0 only for the first tick)
        j = 1 if i > 0 else 0
        xc = _observe(j, t[i - j : i - j + 2], x[v], held[v], c, in_world, air, wp[v], ws[v], snp[v], sns[v],
                      meas[v], home, eparams, est[v], xh2, el2, loop_s[v], g)  # fmt: skip
    else:
        xc = state_as_received(x[v])
    if ep[EP_RESIDUAL] != 0.0:
        control_law(kc, ctrl[v], xc, refs[i], False, base[v], diag[v])
        normalise_pitches(base[v], lo, hi, cmd)
    else:
        for k in range(N_PITCH):
            cmd[k] = last_a[v, k]
    fill_observation(xc, refs[i], cmd, obs[v])


@njit
def step_vehicle(
    v: int, kc: Any, c: PlantConstants, air: AirConstants, g: RotorConstants, t: FloatArray, refs: FloatArray,
    lo: FloatArray, hi: FloatArray, n_last: int, n_sub: int, dt_s: float, in_world: bool, sensing: bool,
    ep: FloatArray, servo_p: FloatArray, dryden: FloatArray, home: FloatArray, eparams: FloatArray,
    actions: FloatArray, just_reset: BoolArray, ticks: IntArray,
    x: FloatArray, held: FloatArray, ws: FloatArray, wp: FloatArray, servo_s: FloatArray, snp: FloatArray,
    sns: FloatArray, meas: FloatArray, est: FloatArray, loop_s: FloatArray, ctrl: FloatArray,
    diag: FloatArray, base: FloatArray, last_a: FloatArray, vs: FloatArray,
    obs: FloatArray, reward: FloatArray, terminated: BoolArray, truncated: BoolArray,
    record: bool, xs: FloatArray, us: FloatArray, diags: FloatArray,
    scratch: FloatArray, xh2: FloatArray, el2: FloatArray, airs2: FloatArray, applied2: FloatArray,
    rotors2: FloatArray,
) -> None:  # fmt: skip
    """Vehicle ``v``'s control tick (see :func:`batch_step`): it reads what all vehicles
    share and writes only its own rows (``scratch[v]`` and the windows ``xh2[v]``, ... among
    them), so that vehicles may be stepped on any threads in any order."""
    terminated[v] = False
    truncated[v] = False
    reward[v] = 0.0
    sc = scratch[v]
    a = sc[S_ACTION : S_ACTION + N_PITCH]
    u = sc[S_COMMAND : S_COMMAND + N_PITCH]
    cmd = sc[S_COMMAND_NORM : S_COMMAND_NORM + N_PITCH]
    if just_reset[v]:
        ticks[v] = 0
        vs[v, :] = 0.0
        last_a[v, :] = 0.0
        if record:
            xs[v, 0] = x[v]
        _tick_observation(v, 0, kc, c, air, g, t, refs, lo, hi, in_world, sensing, ep, home, eparams, x,
                          held, ws, wp, snp, sns, meas, est, loop_s, ctrl, diag, base, last_a, obs, xh2[v],
                          el2[v], cmd)  # fmt: skip
        return
    i = ticks[v]
    if i >= n_last:  # flown to its end: nothing left to step (the caller restarts it)
        truncated[v] = vs[v, V_LEFT] == LEFT_NONE
        terminated[v] = not truncated[v]
        return
    command_from_action(actions[v], base[v], lo, hi, ep[EP_RESIDUAL] != 0.0, ep[EP_SCALE], a, u)
    # what the bench does around any controller's command (UserController): clipped to
    # the limits, the clipped channels reported as saturated
    sat = 0
    for k in range(N_PITCH):
        uc = min(max(u[k], lo[k]), hi[k])
        if uc != u[k]:
            sat += 1 << k
        u[k] = uc
    diag[v, :] = np.nan
    diag[v, D_SAT_MASK] = sat
    diag[v, D_STATUS] = OK
    if record:
        us[v, i] = u
        diags[v, i] = diag[v]
    if i == 0 and ep[EP_SERVOS_ON] != 0.0:
        # the servos start where the first command puts them (closed_loop.simulate)
        first = sc[S_FIRST : S_FIRST + N_PITCH]
        for k in range(N_PITCH):
            first[k] = held[v, k]
        pitches_as_received(u, lo, hi, first)
        servo_rest(servo_s[v], first)
    x_prev = sc[S_X_PREV : S_X_PREV + N_STATE]
    for k in range(N_STATE):
        x_prev[k] = x[v, k]
    x[v] = _advance(0, t[i : i + 2], x[v], u, lo, hi, held[v], c, n_sub, dt_s, in_world, air, wp[v],
                    ws[v], servo_p, servo_s[v], dryden, airs2[v], applied2[v], loop_s[v], g, rotors2[v],
                    True)  # fmt: skip
    i += 1
    ticks[v] = i
    if record:
        xs[v, i] = x[v]
    for k in range(N_PITCH):
        last_a[v, k] = a[k]
    _tick_observation(v, i, kc, c, air, g, t, refs, lo, hi, in_world, sensing, ep, home, eparams, x, held,
                      ws, wp, snp, sns, meas, est, loop_s, ctrl, diag, base, last_a, obs, xh2[v], el2[v],
                      cmd)  # fmt: skip
    left = _left_envelope(x[v], x_prev, refs[i], t[i], t[i - 1], vs[v], ep)
    vs[v, V_LEFT] = left
    terminated[v] = left != LEFT_NONE
    truncated[v] = left == LEFT_NONE and i >= n_last
    e2 = 0.0
    for k in range(3):
        e2 += (x[v, X_N + k] - refs[i, POS_0 + k]) ** 2
    a2 = 0.0
    for k in range(N_PITCH):
        a2 += a[k] * a[k]
    cost = ep[EP_W_POS] * e2 + ep[EP_W_ATT] * (x[v, PHI] ** 2 + x[v, THETA] ** 2) + ep[EP_W_EFFORT] * a2
    reward[v] = ep[EP_W_ALIVE] * math.exp(-cost) if math.isfinite(cost) else 0.0


@njit
def batch_step(
    kc: Any, c: PlantConstants, air: AirConstants, g: RotorConstants, t: FloatArray, refs: FloatArray,
    lo: FloatArray, hi: FloatArray, n_last: int, n_sub: int, dt_s: float, in_world: bool, sensing: bool,
    ep: FloatArray, servo_p: FloatArray, dryden: FloatArray, home: FloatArray, eparams: FloatArray,
    actions: FloatArray, just_reset: BoolArray, ticks: IntArray,
    x: FloatArray, held: FloatArray, ws: FloatArray, wp: FloatArray, servo_s: FloatArray, snp: FloatArray,
    sns: FloatArray, meas: FloatArray, est: FloatArray, loop_s: FloatArray, ctrl: FloatArray,
    diag: FloatArray, base: FloatArray, last_a: FloatArray, vs: FloatArray,
    obs: FloatArray, reward: FloatArray, terminated: BoolArray, truncated: BoolArray,
    record: bool, xs: FloatArray, us: FloatArray, diags: FloatArray,
    scratch: FloatArray, xh2: FloatArray, el2: FloatArray, airs2: FloatArray, applied2: FloatArray,
    rotors2: FloatArray,
) -> None:  # fmt: skip
    """One control tick of every vehicle, in turn on the calling thread: a vehicle
    ``just_reset`` (its arrays set at tick 0) is only observed (reward 0, neither terminated
    nor truncated); every other one flies ``actions[v]`` from its tick to the next and is
    observed there, rewarded (the default reward, :data:`ENV_PARAMS`' weights, on the truth)
    and checked against the safety envelope. ``record``: the truth, commands and diagnostics
    logged per tick into ``xs[v]``, ``us[v]``, ``diags[v]`` (N rows each; placeholders
    otherwise). Scratch, one row or window per vehicle: ``scratch`` (N, :data:`N_SCRATCH`),
    ``xh2`` (N, 2, 12), ``el2`` (N, 2, the estimator's log), ``airs2`` (N, 2, 3), ``applied2``
    (N, 2, 4), ``rotors2`` (N, 2, N_ROTOR + 1)."""
    for v in range(x.shape[0]):
        step_vehicle(v, kc, c, air, g, t, refs, lo, hi, n_last, n_sub, dt_s, in_world, sensing, ep, servo_p,
                     dryden, home, eparams, actions, just_reset, ticks, x, held, ws, wp, servo_s, snp, sns,
                     meas, est, loop_s, ctrl, diag, base, last_a, vs, obs, reward, terminated, truncated,
                     record, xs, us, diags, scratch, xh2, el2, airs2, applied2, rotors2)  # fmt: skip


@njit(parallel=True)
def batch_step_parallel(
    laws: Any, n_chunks: int,
    t: FloatArray, refs: FloatArray,
    lo: FloatArray, hi: FloatArray, n_last: int, n_sub: int, dt_s: float, in_world: bool, sensing: bool,
    ep: FloatArray, servo_p: FloatArray, dryden: FloatArray, home: FloatArray, eparams: FloatArray,
    actions: FloatArray, just_reset: BoolArray, ticks: IntArray,
    x: FloatArray, held: FloatArray, ws: FloatArray, wp: FloatArray, servo_s: FloatArray, snp: FloatArray,
    sns: FloatArray, meas: FloatArray, est: FloatArray, loop_s: FloatArray, ctrl: FloatArray,
    diag: FloatArray, base: FloatArray, last_a: FloatArray, vs: FloatArray,
    obs: FloatArray, reward: FloatArray, terminated: BoolArray, truncated: BoolArray,
    record: bool, xs: FloatArray, us: FloatArray, diags: FloatArray,
    scratch: FloatArray, xh2: FloatArray, el2: FloatArray, airs2: FloatArray, applied2: FloatArray,
    rotors2: FloatArray,
) -> None:  # fmt: skip
    """:func:`batch_step` with the vehicles cut into ``n_chunks`` contiguous runs, the runs
    shared among numba's threads (as many as :func:`heli_common.jit.set_threads` set for the
    calling thread; one run a thread is the natural cut). Each vehicle's tick is the same
    function on its own rows, so the results are the serial loop's, bit for bit, for any
    number of threads or runs. ``laws``: one ``(kc, c, air, g)`` a run (:func:`shard_list`),
    each with its own handles on the arrays in it.

    Why so: numba hands a parallel loop's body its variables as a gufunc's arguments; the
    arrays arrive there without a reference count (so the views a tick takes of them cost
    no atomic add: one thread steps about 1.5 times as many vehicles a second as the serial
    kernel), but the tuples are flattened one level only, and the law's constants nest named
    tuples (TLCConstants holds a PlantConstants, ...): a typed list carries them. One item a
    run, each with its own array handles: every view of a gain matrix counts a reference on
    its handle, an atomic add, and two threads counting on one handle fought over its cache
    line (two threads then stepped no more vehicles a second than one)."""
    n = x.shape[0]
    for chunk in prange(n_chunks):
        law = laws[np.int64(chunk)]  # prange's index is unsigned, the list's signed
        for v in range(chunk * n // n_chunks, (chunk + 1) * n // n_chunks):
            step_vehicle(v, law[0], law[1], law[2], law[3], t, refs, lo, hi, n_last, n_sub, dt_s, in_world,
                         sensing, ep, servo_p, dryden, home, eparams, actions, just_reset, ticks, x, held, ws,
                         wp, servo_s, snp, sns, meas, est, loop_s, ctrl, diag, base, last_a, vs, obs, reward,
                         terminated, truncated, record, xs, us, diags, scratch, xh2, el2, airs2, applied2,
                         rotors2)  # fmt: skip


@njit
def shard_list(first: Any) -> Any:
    """A typed list holding ``first`` (:func:`batch_step_parallel`'s per-run constants); the
    others go in with :func:`shard_append` (compiled and cached here, not by numba's typed
    list methods, which compile again in every process)."""
    shards = List()
    shards.append(first)
    return shards


@njit
def shard_append(shards: Any, shard: Any) -> None:
    """``shard`` appended to a list of :func:`shard_list`."""
    shards.append(shard)
