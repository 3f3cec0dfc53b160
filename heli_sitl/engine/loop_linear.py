"""The whole closed loop linearised numerically: one control tick's Jacobian, its
eigenvalues, and disk margins at every loop break point.

One tick of the bench's own loop (the controller kernel, the pitches held, the plant's
compiled step with its servos and rotor) is a map ``z_k+1 = F(z_k)`` of the plant's state,
the rotor plant's states, the servos' states and the controller's state. About a hover
equilibrium ``z* = F(z*)`` its Jacobian (central differences) gives the closed-loop
eigenvalues (stable iff every ``|lambda| < 1``), and its blocks (controller: measured state ->
pitches; plant: pitches -> state) the discrete-time loop transfer at each break point: every
pitch channel at the plant's input, and every measured state the controller reads.
Each break point's balanced disk margin (loop-at-a-time: that channel opened, every other
closed) is computed as python-control's :func:`control.disk_margins` does, on frequency
responses from one batched solve (tests/test_loop_linear.py holds the two together), and the
multivariable margin at the plant input beside them. Nothing is approximated but the
linearisation itself: the rotor, the thrust tilt, the servos' delay and lag, the sampling and
the differentiators are all in it.

Servos: delay (to the nearest control period, as the flights realise it at the control rate)
and lag linearise exactly; the rate limit,
quantum and dead band are small-signal inactive and left out (the flights keep them).

Over the envelope (:func:`envelope_margins`, ``heli-sitl margins --envelope``): the same tick
about trimmed level flight at speed, in a frame moving with the reference
(:class:`MovingTickMap`), with a computation delay of whole ticks on the controller's output
(:func:`delayed`), and the simultaneous margins of autopilot.analysis.envelope_margins beside
the loop-at-a-time ones.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import control as ct
import numpy as np
from scipy.optimize import least_squares

from autopilot.analysis.envelope_margins import (
    Disk,
    EnvelopeRow,
    EnvelopeTable,
    full_block_disk,
    simultaneous_disk,
    siso_disk,
)
from autopilot.control import N_DIAG, KernelController
from autopilot.reference import N_REF
from heli_common.state import N_PITCH, N_STATE, PITCH_NAMES, STATE_NAMES, FloatArray
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import PlantModel
from heli_common.world.config import Servos, World
from heli_common.world.servo_model import SS_FIFO, SS_RING_INDEX
from heli_plant.model import accept_pitches
from heli_plant.rotor import N_ROTOR
from heli_plant.trim import hover_rotor_state, jacobian, trim
from heli_plant.world.model import WS_ROTOR, WorldModel, world_plant_step

HOVER_ALT_M = 20.0
OMEGA_RAD_S = np.logspace(-2.0, math.log10(math.pi * 100.0) - 1e-3, 600)


@dataclass(frozen=True)
class BreakPoint:
    """The balanced disk margin of one loop break point (loop-at-a-time)."""

    name: str  # "input eps" (a pitch at the plant's input) or "state q_rad_s" (a measurement)
    disk_margin: float  # alpha_max: the disk's size; 0 when the loop is unstable
    gain_margin_db: float  # the disk's gain margin (+/-) [dB]
    phase_margin_deg: float  # the disk's phase margin (+/-) [deg]


@dataclass(frozen=True)
class LoopLinearization:
    """One tick's Jacobian about hover, its eigenvalues and the disk margins."""

    plant: str
    controller: str
    servos: str
    eigenvalues: FloatArray  # complex, the discrete-time map's
    spectral_radius: float  # max |lambda|; < 1 is stable
    dominant_rad_s: complex  # the continuous equivalent ln(lambda)/dt of the largest |lambda|
    break_points: tuple[BreakPoint, ...]
    input_multiloop: BreakPoint  # all four pitches perturbed at once (python-control's MIMO margin)

    @property
    def stable(self) -> bool:
        return self.spectral_radius < 1.0

    def worst(self) -> BreakPoint:
        return min(self.break_points, key=lambda b: b.disk_margin)

    def summary(self) -> str:
        """One line, as gain files state it in their headers."""
        if not self.stable:
            w_rad_s = self.dominant_rad_s.imag
            return (f"{self.plant} plant, servos {self.servos or 'ideal'}: UNSTABLE "
                    f"(max |lambda| {self.spectral_radius:.4f}, {w_rad_s:.1f} rad/s)")  # fmt: skip
        w = self.worst()
        return (f"{self.plant} plant, servos {self.servos or 'ideal'}: stable, worst disk margin "
                f"{w.disk_margin:.2f} ({w.gain_margin_db:.1f} dB, {w.phase_margin_deg:.0f} deg) "
                f"at {w.name}; "
                f"all four inputs at once {self.input_multiloop.disk_margin:.2f}")  # fmt: skip


@dataclass
class TickMap:
    """``F(z)``: one control tick of ``controller`` on the plant, about a held reference."""

    controller: KernelController[Any]
    world: WorldModel
    ref: FloatArray
    lo: FloatArray
    hi: FloatArray
    n_servo: int

    @property
    def sizes(self) -> tuple[int, int, int, int]:
        return N_STATE, N_ROTOR if self.world.rotor.on else 0, self.n_servo, self.controller.n_state

    def split(self, z: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        a, b, c, _ = self.sizes
        return z[:a], z[a : a + b], z[a + b : a + b + c], z[a + b + c :]

    def plant_step(self, x: FloatArray, r: FloatArray, s: FloatArray, held: FloatArray) -> FloatArray:
        w = self.world
        ws = w.ws.copy()
        if r.size:
            ws[WS_ROTOR : WS_ROTOR + N_ROTOR] = r
        servo_s = w.servo_s.copy()
        servo_s[1 : 1 + s.size] = s
        dt = self.controller.dt_s
        servo_s[SS_RING_INDEX] = 0.0
        y, _ = world_plant_step(0.0, x, held, w.constants, w.air, dt, 1, False, w.wp, ws, w.servo_p, servo_s,
                                w.dryden, w.rotor)  # fmt: skip
        rr = ws[WS_ROTOR : WS_ROTOR + N_ROTOR] if r.size else r
        return np.concatenate([y, rr, canonical_fifo(servo_s)[1 : 1 + s.size]])

    def control(self, c: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = c.copy()
        out = np.empty(N_PITCH)
        k = self.controller
        k.kernel()(k.constants, st, x, self.ref, False, out, np.zeros(N_DIAG))
        held = np.empty(N_PITCH)
        accept_pitches(out, self.lo, self.hi, held)
        return held, st

    def __call__(self, z: FloatArray) -> FloatArray:
        x, r, s, c = self.split(z)
        held, st = self.control(c, x)
        return np.concatenate([self.plant_step(x, r, s, held), st])


def canonical_fifo(servo_s: FloatArray) -> FloatArray:
    """The servos' state with its delay ring rotated so that the next slot to write is slot 0:
    the ring's index then is the same after every tick, so a tick is one map of the state
    whatever the delay (a delay of several ticks turns the ring by one slot each tick)."""
    out = servo_s.copy()
    fifo = out[SS_FIFO:].reshape(-1, N_PITCH)
    if fifo.shape[0]:
        out[SS_FIFO:] = np.roll(fifo, -int(servo_s[SS_RING_INDEX]), axis=0).ravel()
    out[SS_RING_INDEX] = 0.0
    return out


def _jacobian(f: Any, z0: FloatArray) -> FloatArray:
    return jacobian(f, z0, 1e-7)


def build_tick_map(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos
) -> tuple[TickMap, FloatArray]:
    """The tick map at a hover of the plant's own trim, and a start for its fixed point."""
    sv = dataclasses.replace(servos, rate_rad_s=(0.0,) * 4, quantum_rad=(0.0,) * 4, deadband_rad=(0.0,) * 4)
    tr = trim(model, design, altitude_m=HOVER_ALT_M)
    x0 = tr.x[:N_STATE].copy()
    r0 = np.array(hover_rotor_state(model, design)) if model.rotor is not None else None
    world = WorldModel.build(World(servos=sv), design, x0, model.rotor, r0)
    limits = np.array(design.limits.as_tuple())
    world.prepare(controller.dt_s, tr.u, limits)
    ref = np.zeros(N_REF)
    ref[0:3] = x0[0:3]
    ref[3:] = 0.0
    n_servo = world.servo_s.size - 1 if sv.on else 0  # positions, targets, delay line
    tm = TickMap(controller, world, ref, limits[:, 0], limits[:, 1], n_servo)
    ctrl = controller.state.copy()
    controller.kernel()(controller.constants, ctrl, x0, ref, False, np.empty(N_PITCH), np.zeros(N_DIAG))
    z0 = np.concatenate([x0, [] if r0 is None else r0, world.servo_s[1 : 1 + n_servo], ctrl])
    return tm, z0


FIXED_POINT_TOL = 1e-9  # |F(z*) - z*| accepted as an equilibrium


def fixed_point(tm: TickMap, z0: FloatArray) -> tuple[FloatArray, float]:
    """``z* = F(z*)`` and its residual: solved (least squares) from the plant's trim with the
    controller started there, and from where 30 s of flight from it came to rest (an
    unstable loop only settles into a limit cycle, if at all); the better of the two."""

    def solve(start: FloatArray) -> tuple[FloatArray, float]:
        sol = least_squares(lambda v: tm(v) - v, start, xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=400)
        z = np.asarray(sol.x)
        return z, float(np.max(np.abs(tm(z) - z)))

    best = solve(z0)
    if best[1] <= FIXED_POINT_TOL:
        return best
    z = z0.copy()
    for _ in range(3000):
        z_new = tm(z)
        if not np.all(np.isfinite(z_new)) or np.max(np.abs(z_new[:N_STATE] - z0[:N_STATE])) > 5.0:
            return best
        z = z_new
    flown = solve(z)
    return flown if flown[1] < best[1] else best


@dataclass(frozen=True)
class Discrete:
    """A discrete-time state-space system ``x+ = a x + b u, y = c x + d u`` (period ``dt``)."""

    a: FloatArray
    b: FloatArray
    c: FloatArray
    d: FloatArray
    dt: float

    def response(self, omega_rad_s: FloatArray) -> FloatArray:
        """The frequency response ``(n_w, n_out, n_in)`` at ``z = exp(j omega dt)``: one batched
        solve (python-control's horner solves one frequency at a time, 40x slower here)."""
        n = self.a.shape[0]
        z = np.exp(1j * omega_rad_s * self.dt)
        if n == 0:
            return np.broadcast_to(self.d, (z.size, *self.d.shape)).astype(complex)
        m = z[:, None, None] * np.eye(n) - self.a
        x = np.linalg.solve(m, np.broadcast_to(self.b, (z.size, *self.b.shape)))
        return np.asarray(self.c @ x + self.d)

    def to_control(self) -> ct.StateSpace:
        return ct.ss(self.a, self.b, self.c, self.d, self.dt)


@dataclass(frozen=True)
class LoopBlocks:
    """The closed loop's two halves about hover: the controller (measured state -> pitches)
    and the plant with rotor and servos (pitches -> state), and the whole tick's eigenvalues."""

    controller: Discrete
    plant: Discrete
    eigenvalues: FloatArray

    @property
    def stable(self) -> bool:
        return bool(np.max(np.abs(self.eigenvalues)) < 1.0)

    def loops(self, omega_rad_s: FloatArray = OMEGA_RAD_S) -> tuple[FloatArray, FloatArray]:
        """The loop transfers ``(n_w, n, n)`` broken at the plant's input (``u -> x -> u``) and
        at the measurements (``x -> u -> x``), negative feedback convention."""
        k = self.controller.response(omega_rad_s)
        p = self.plant.response(omega_rad_s)
        return -(k @ p), -(p @ k)


def loop_at_a_time(loop: FloatArray, i: int) -> FloatArray:
    """Channel ``i`` of a square loop ``(n_w, n, n)`` opened, every other closed: the SISO loop
    ``w -> y_i`` with ``u = w e_i - (y with its i-th entry zeroed)``, i.e.
    ``[(I + L O)^-1 L]_ii`` with ``O = I - e_i e_i^T``."""
    n = loop.shape[-1]
    others = np.eye(n)
    others[i, i] = 0.0
    closed = np.linalg.solve(np.eye(n) + loop @ others, loop)
    return np.asarray(closed[:, i, i])


def balanced_disk(name: str, siso: FloatArray) -> BreakPoint:
    """The balanced (skew 0) disk margin of a SISO loop's frequency response:
    ``1 / max_w |S - 1/2|``, ``S = 1 / (1 + L)``, as :func:`control.disk_margins` computes it
    (tests/test_loop_linear.py holds the two together)."""
    s = 1.0 / (1.0 + siso)
    return _from_alpha(name, float(1.0 / np.max(np.abs(s - 0.5))))


def _blocks(
    tm: TickMap, z: FloatArray, jac: FloatArray, keep: np.ndarray[Any, np.dtype[np.bool_]], dt: float
) -> LoopBlocks:
    """The closed loop's eigenvalues over the ``keep`` states, and its two blocks about the
    equilibrium ``z``: the plant p = (x, rotor, servos) with input u, and the controller
    (its kept states) with input x."""
    lam: FloatArray = np.asarray(np.linalg.eigvals(jac[np.ix_(keep, keep)]))  # complex in general
    nx, nr, ns, _nc = tm.sizes
    npl = nx + nr + ns
    x, _r, _s, c = tm.split(z)
    held, _ = tm.control(c, x)

    def plant_of(v: FloatArray) -> FloatArray:
        return tm.plant_step(v[:nx], v[nx : nx + nr], v[nx + nr : npl], v[npl:])

    jp = _jacobian(plant_of, np.concatenate([z[:npl], held]))
    ap, bp = jp[:, :npl], jp[:, npl:]

    def ctrl_of(v: FloatArray) -> FloatArray:
        u, st = tm.control(v[nx:], v[:nx])
        return np.concatenate([u, st])

    jc = _jacobian(ctrl_of, np.concatenate([x, c]))
    kc = keep[npl:]
    dc, cc = jc[:N_PITCH, :nx], jc[:N_PITCH, nx:][:, kc]
    bc, ac = jc[N_PITCH:, :nx][kc], jc[N_PITCH:, nx:][np.ix_(kc, kc)]
    cp = np.zeros((nx, npl))
    cp[:, :nx] = np.eye(nx)
    return LoopBlocks(Discrete(ac, bc, cc, dc, dt), Discrete(ap, bp, cp, np.zeros((nx, N_PITCH)), dt), lam)


def loop_blocks(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos
) -> LoopBlocks:
    """The controller and plant blocks of ``controller`` on ``model`` at hover, with ``servos``."""
    tm, z0 = build_tick_map(controller, model, design, servos)
    z, residual = fixed_point(tm, z0)
    if residual > FIXED_POINT_TOL:
        raise ValueError(
            f"{controller.kind} on the {model.kind} plant: no hover equilibrium found "
            f"(|F(z) - z| = {residual:.1e})"
        )
    jac = _jacobian(tm, z)
    # states the tick only holds (z_i+ = z_i and nothing else: the yaw command of a hover
    # reference, whose every value is an equilibrium) are references, not dynamics
    eye = np.eye(jac.shape[0])
    keep = np.array([not np.allclose(jac[i], eye[i], rtol=0.0, atol=1e-10) for i in range(jac.shape[0])])
    return _blocks(tm, z, jac, keep, controller.dt_s)


def linearize_loop(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos,
    servos_name: str = "",
) -> LoopLinearization:  # fmt: skip
    """The closed loop of ``controller`` on ``model`` at hover, with ``servos`` (delay and lag)."""
    blocks = loop_blocks(controller, model, design, servos)
    lam = blocks.eigenvalues
    k = int(np.argmax(np.abs(lam)))
    dominant = complex(np.log(complex(lam[k])) / controller.dt_s)
    if not blocks.stable:  # a disk margin presumes a stable loop: none at all
        groups = (("input", PITCH_NAMES), ("state", STATE_NAMES))
        zero = tuple(BreakPoint(f"{kind} {nm}", 0.0, 0.0, 0.0) for kind, names in groups for nm in names)
        multi = BreakPoint("input all four", 0.0, 0.0, 0.0)
    else:
        loop_in, loop_out = blocks.loops()
        zero = tuple(balanced_disk(f"input {nm}", loop_at_a_time(loop_in, i))
                     for i, nm in enumerate(PITCH_NAMES))  # fmt: skip
        zero += tuple(balanced_disk(f"state {nm}", loop_at_a_time(loop_out, j))
                      for j, nm in enumerate(STATE_NAMES))  # fmt: skip
        multi = _multiloop_disk("input all four", loop_in)
    return LoopLinearization(model.kind, controller.kind, servos_name, lam, float(np.max(np.abs(lam))),
                             dominant, zero, multi)  # fmt: skip


def _multiloop_disk(name: str, loop: FloatArray) -> BreakPoint:
    """All channels perturbed at once by one full complex block (no slycot: the unstructured
    bound of the balanced disk margin, ``1 / max_w sigma_max((I - L)(I + L)^-1 / 2)``, a
    conservative one next to the diagonal structure's mu)."""
    n = loop.shape[-1]
    eye = np.eye(n)
    t = (0, 2, 1)  # X (I + L) = I - L, solved transposed
    s0 = 0.5 * np.linalg.solve((eye + loop).transpose(t), (eye - loop).transpose(t)).transpose(t)
    worst = float(np.max(np.linalg.norm(s0, 2, axis=(1, 2))))
    return _from_alpha(name, 1.0 / worst)


def _from_alpha(name: str, alpha: float) -> BreakPoint:
    """A balanced disk of size ``alpha``: gain (1 + a/2)/(1 - a/2), phase 2 atan(a/2)."""
    if alpha >= 2.0:
        return BreakPoint(name, alpha, math.inf, 90.0)
    return BreakPoint(name, alpha, float(20.0 * math.log10((1 + alpha / 2) / (1 - alpha / 2))),
                      float(math.degrees(2.0 * math.atan(alpha / 2))))  # fmt: skip


def servo_model(name: str) -> tuple[str, Servos]:
    """A world preset's servos (``ideal``: none)."""
    if name == "ideal":
        return "ideal", Servos()
    return name, World.load(name).servos




# --- margins over the flight envelope: trimmed level flight at speed, a computation delay,
# and the simultaneous (all inputs / all outputs at once) disk margins beside the loop-at-a-time
# ones (issue 44, item 4; docs/tlc-rotor.md, "Margins over the envelope")


@dataclass
class MovingTickMap(TickMap):
    """One tick in a frame that moves with the reference: level flight north at ``speed_m_s``
    with the reference's position advancing ``speed dt`` a tick. The loop is translation
    invariant (calm air, no ground effect at 20 m, every law acts on position differences), so
    the tick minus the translation, ``F(z) - shift``, is a time-invariant map whose fixed point
    is the trimmed flight and whose Jacobian is the real loop's at every tick of it. ``shift``
    moves the north position and every controller state that moves with it (the
    pseudo-differentiator of the position command, found by :func:`_translation`)."""

    shift: FloatArray | None = None

    def __call__(self, z: FloatArray) -> FloatArray:
        out = super().__call__(z)
        return out if self.shift is None else out - self.shift


def _translation(controller: KernelController[Any], x0: FloatArray, ref: FloatArray) -> FloatArray:
    """How each controller state moves when the vehicle and its reference move 1 m north:
    the difference of the controller's first tick at two positions (its filters start at the
    command; an integral or a rate does not move)."""

    def first(dx: float) -> FloatArray:
        st = controller.state.copy()
        st[:] = 0.0
        x, r = x0.copy(), ref.copy()
        x[0] += dx
        r[0] += dx
        controller.kernel()(controller.constants, st, x, r, False, np.empty(N_PITCH), np.zeros(N_DIAG))
        return st

    g = first(1.0) - first(0.0)
    rounded = np.round(g)
    if not np.allclose(g, rounded, atol=1e-6):
        raise ValueError(f"{controller.kind}: its state is not translation invariant ({g})")
    return rounded


def build_tick_map_at(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos, speed_m_s: float
) -> tuple[MovingTickMap, FloatArray]:
    """The tick map in trimmed level flight north at ``speed_m_s`` (0: the hover of
    :func:`build_tick_map`, the same map) and a start for its fixed point: the plant's trim
    (heli_plant.trim) with the reference ``p0 + V t`` north, velocity ``V``, no acceleration."""
    sv = dataclasses.replace(servos, rate_rad_s=(0.0,) * 4, quantum_rad=(0.0,) * 4, deadband_rad=(0.0,) * 4)
    tr = trim(model, design, speed_m_s=speed_m_s, altitude_m=HOVER_ALT_M)
    x0 = tr.x[:N_STATE].copy()
    r0 = tr.x[N_STATE:].copy() if model.rotor is not None else None
    world = WorldModel.build(World(servos=sv), design, x0, model.rotor, r0)
    limits = np.array(design.limits.as_tuple())
    world.prepare(controller.dt_s, tr.u, limits)
    ref = np.zeros(N_REF)
    ref[0:3] = x0[0:3]
    ref[3] = speed_m_s  # earth NWU: north
    n_servo = world.servo_s.size - 1 if sv.on else 0
    nr = N_ROTOR if world.rotor.on else 0
    g = _translation(controller, x0, ref)
    shift = np.concatenate([np.eye(N_STATE)[0], np.zeros(nr + n_servo), g]) * speed_m_s * controller.dt_s
    tm = MovingTickMap(controller, world, ref, limits[:, 0], limits[:, 1], n_servo,
                       shift if speed_m_s != 0.0 else None)  # fmt: skip
    ctrl = controller.state.copy()
    ctrl[:] = 0.0
    controller.kernel()(controller.constants, ctrl, x0, ref, False, np.empty(N_PITCH), np.zeros(N_DIAG))
    z0 = np.concatenate([x0, [] if r0 is None else r0, world.servo_s[1 : 1 + n_servo], ctrl])
    return tm, z0


CONTINUATION_STEP_M_S = 2.5


def _equilibrium_at(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos, speed_m_s: float
) -> tuple[MovingTickMap, FloatArray, float]:
    """The fixed point of the moving tick map at ``speed_m_s``: from the plant's trim, else by
    continuation in speed (steps of at most 2.5 m/s from hover, each started from the last two
    solutions extrapolated: the equilibrium drifts with speed, a heading offset and loop 1's
    integral among it, and a far start can leave the solver in a local minimum)."""
    tm, z0 = build_tick_map_at(controller, model, design, servos, speed_m_s)
    z, residual = fixed_point(tm, z0)
    if residual <= FIXED_POINT_TOL or speed_m_s == 0.0:
        return tm, z, residual
    n = max(2, math.ceil(abs(speed_m_s) / CONTINUATION_STEP_M_S))
    sols: list[FloatArray] = []
    for v in np.linspace(0.0, speed_m_s, n + 1):
        tm_v, z0_v = build_tick_map_at(controller, model, design, servos, float(v))
        start = z0_v if not sols else sols[-1] if len(sols) == 1 else 2.0 * sols[-1] - sols[-2]
        z_v, res_v = fixed_point(tm_v, start)
        if res_v > FIXED_POINT_TOL:
            return tm, z, residual  # the continuation broke off: the direct attempt's failure
        sols.append(z_v)
    return tm_v, sols[-1], res_v


def loop_blocks_at(
    controller: KernelController[Any], model: PlantModel, design: Airframe, servos: Servos,
    speed_m_s: float = 0.0,
) -> LoopBlocks:  # fmt: skip
    """:func:`loop_blocks` about trimmed level flight at ``speed_m_s`` (0: hover, the same
    blocks): the controller (measured state -> pitches) and the plant (pitches -> state)."""
    tm, z, residual = _equilibrium_at(controller, model, design, servos, speed_m_s)
    if residual > FIXED_POINT_TOL:
        raise ValueError(f"{controller.kind} on the {model.kind} plant: no equilibrium in level flight at "
                         f"{speed_m_s:g} m/s (|F(z) - z| = {residual:.1e})")  # fmt: skip
    jac = _jacobian(tm, z)
    eye = np.eye(jac.shape[0])
    keep = np.array([not np.allclose(jac[i], eye[i], rtol=0.0, atol=1e-10) for i in range(jac.shape[0])])
    nx, nr, ns, _nc = tm.sizes
    keep &= ~_reference_states(jac, nx + nr + ns)
    return _blocks(tm, z, jac, keep, controller.dt_s)


def _reference_states(jac: FloatArray, n_plant: int) -> np.ndarray[Any, np.dtype[np.bool_]]:
    """The controller states no plant state reaches (the reference's own filters: the
    pseudo-differentiator of the position command, the yaw command that integrates the
    path's turn rate): a state is one if its row depends only on such states. They are
    dynamics of the reference, not of the loop (the yaw command's integrator is an eigenvalue
    1 in flight along a path), and no loop transfer passes through them."""
    n = jac.shape[0]
    ref = np.zeros(n, dtype=bool)
    ref[n_plant:] = True
    while True:
        driven = np.array([ref[i] and bool(np.any(np.abs(jac[i, ~ref]) > 1e-10)) for i in range(n)])
        if not driven.any():
            return ref
        ref &= ~driven


def delayed(blocks: LoopBlocks, ticks: int) -> LoopBlocks:
    """The loop with ``ticks`` control periods of computation delay between the controller and
    the servos (the pitches computed from tick k's measurement reach the hold at tick k +
    ticks): the controller's output through ``z^-ticks``, exact in discrete time. The
    eigenvalues are the assembled closed loop's (with 0 ticks, the tick Jacobian's)."""
    if ticks < 0:
        raise ValueError(f"ticks must be >= 0, got {ticks}")
    if ticks == 0:
        return blocks
    k, p = blocks.controller, blocks.plant
    nc, nu = k.a.shape[0], k.c.shape[0]
    n = nc + ticks * nu
    a = np.zeros((n, n))
    a[:nc, :nc] = k.a
    a[nc : nc + nu, :nc] = k.c  # the first slot takes this tick's output
    for j in range(1, ticks):  # each slot passes to the next
        a[nc + j * nu : nc + (j + 1) * nu, nc + (j - 1) * nu : nc + j * nu] = np.eye(nu)
    b = np.vstack([k.b, k.d, np.zeros(((ticks - 1) * nu, k.b.shape[1]))])
    c = np.zeros((nu, n))
    c[:, nc + (ticks - 1) * nu :] = np.eye(nu)
    kd = Discrete(a, b, c, np.zeros_like(k.d), k.dt)
    return LoopBlocks(kd, p, closed_loop_eigenvalues(kd, p))


def closed_loop_eigenvalues(k: Discrete, p: Discrete) -> FloatArray:
    """The eigenvalues of plant ``p`` and controller ``k`` in negative-free feedback as the
    tick composes them (``u = k(y)``, ``y = p(u)``, ``p`` strictly proper)."""
    a = np.block([[p.a + p.b @ k.d @ p.c, p.b @ k.c], [k.b @ p.c, k.a]])
    return np.asarray(np.linalg.eigvals(a))


DEFAULT_SPEEDS_M_S = (0.0, 2.5, 5.0, 7.5, 10.0)
COMPUTATION_DELAY_TICKS = 1


def envelope_row(blocks: LoopBlocks, speed_m_s: float, omega_rad_s: FloatArray = OMEGA_RAD_S) -> EnvelopeRow:
    """The disk margins of one linearised loop (delay already in ``blocks``): loop at a time at
    each pitch input and each measured state, and all inputs / all states at once. An unstable
    closed loop has none (0)."""
    rho = float(np.max(np.abs(blocks.eigenvalues)))
    if rho >= 1.0:
        none = Disk(0.0, math.nan, "-")
        return EnvelopeRow(speed_m_s, rho, none, none, none, none, none)
    loop_in, loop_out = blocks.loops(omega_rad_s)
    ins = [siso_disk(loop_at_a_time(loop_in, i), omega_rad_s, nm) for i, nm in enumerate(PITCH_NAMES)]
    outs = [siso_disk(loop_at_a_time(loop_out, j), omega_rad_s, nm) for j, nm in enumerate(STATE_NAMES)]
    return EnvelopeRow(speed_m_s, rho, min(ins, key=lambda d: d.alpha), min(outs, key=lambda d: d.alpha),
                       simultaneous_disk(loop_in, omega_rad_s, PITCH_NAMES),
                       simultaneous_disk(loop_out, omega_rad_s, STATE_NAMES),
                       full_block_disk(loop_in, omega_rad_s, PITCH_NAMES))  # fmt: skip


def envelope_margins(
    make_controller: Callable[[], KernelController[Any]], model: PlantModel, design: Airframe, servos: Servos,
    *, speeds_m_s: Sequence[float] = DEFAULT_SPEEDS_M_S, delay_ticks: int = COMPUTATION_DELAY_TICKS,
    gains_name: str = "", servos_name: str = "",
) -> EnvelopeTable:  # fmt: skip
    """The table of :func:`envelope_row` over ``speeds_m_s`` (trimmed level flight north), each
    with ``delay_ticks`` of computation delay; a fresh controller from ``make_controller`` at
    each speed."""
    rows = []
    rate_hz = 100.0
    for v in speeds_m_s:
        c = make_controller()
        rate_hz = 1.0 / c.dt_s
        try:
            blocks = delayed(loop_blocks_at(c, model, design, servos, float(v)), delay_ticks)
        except ValueError:  # no equilibrium: no margins (the row says so)
            none = Disk(0.0, math.nan, "-")
            rows.append(EnvelopeRow(float(v), math.nan, none, none, none, none, none))
            continue
        rows.append(envelope_row(blocks, float(v)))
    return EnvelopeTable(gains_name, model.kind, servos_name or "ideal",
                         delay_ticks, rate_hz, tuple(rows))  # fmt: skip


__all__ = ["BreakPoint", "Discrete", "LoopBlocks", "LoopLinearization", "MovingTickMap", "TickMap",
           "balanced_disk", "build_tick_map_at", "closed_loop_eigenvalues", "delayed", "envelope_margins",
           "envelope_row", "linearize_loop", "loop_at_a_time", "loop_blocks", "loop_blocks_at",
           "servo_model"]  # fmt: skip
