"""Linear margins of the four TLC loops with a servo model in the loop (python-control).

Each TLC loop (docs/model.md, section 3) is a nominal inversion plus a PI regulator on
``command - actual`` whose error obeys ``e'' + 2 zeta w e' + w^2 e = 0``. Linearised about
hover (small angles, ``psi = 0``, the design model equal to the plant), one channel of one
loop is::

    u_k = s D(s) x_c + K_k(s) (x_c - x),      K_k(s) = (2 zeta_k w_k s + w_k^2) / s
    x   = P_k(s) u_k / s

``u_k`` is the loop's output (the next loop's command), ``x_c`` its command, ``D(s) =
w_d^2 / (s^2 + 2 zeta_d w_d s + w_d^2)`` the pseudo-differentiator that supplies the
feed-forward ``dx_c/dt`` (docs/model.md 3.3), and ``P_k`` what the loop's output reaches
the integrator ``1/s`` through:

* loop 4 (body rate, per roll / pitch / yaw): the actuator, ``P_4 = A(s) = exp(-s T) /
  (1 + tau s)`` with ``T = servo delay + dt/2``: the servo's transport delay plus half a
  control period for the zero-order hold, and the servo's first-order lag. The torque
  command reaches the rate through ``J^-1`` and ``J`` cancels (the law multiplies by the
  design ``J``); the allocation is static, so with the same servo on every pitch the torque
  sees the same ``A(s)`` as each pitch;
* loop 3 (Euler angle, per roll / pitch / yaw): the closed loop 4 of the same channel,
  ``P_3 = T_4`` (``E(gamma) = I`` and ``A3 = 0`` at hover);
* loop 2 (body velocity): x (forward) through the closed pitch loop, y (left) through the
  closed roll loop (``F_x = m g theta``, ``F_y = -m g phi`` and the inversion (25) divides by
  ``m g``: ``P_2 = T_3``); z through the collective servo only, ``P_2 = A(s)``;
* loop 1 (position, earth frame): the closed loop 2 of the same channel, ``P_1 = T_2``
  (``R_t = I`` at ``psi = 0``).

Breaking loop k at its output with every inner loop closed and every outer loop open (the
classical loop-at-a-time check of a cascade), its open loop is::

    L_k(s) = K_k(s) P_k(s) / s

and the closed loop the next outer loop sees, command ``x_c`` to ``x``, feed-forward
included, is::

    T_k(s) = P_k (s D + K_k) / (s + P_k K_k)

(``feedforward=False`` drops ``s D`` and leaves the designed second-order closed loop
``P_k K_k / (s + P_k K_k)``.) With an ideal actuator and an exact differentiator every
``T_k`` is 1 and every ``L_k`` is the design loop ``(2 zeta w s + w^2)/s^2``: crossover
``1.55 w`` and 65.5 deg of phase margin at ``zeta = 0.707``.

Approximations, all of them:

* **Decoupled SISO channels.** Every loop is analysed one channel at a time, about hover:
  the gyroscopic terms, ``A3``, ``A4`` and ``omega x V_e`` are zero there, ``E``, ``R_t`` are
  identities, the design model equals the plant (the cyclic's thrust tilt ``T_m eps`` in
  ``F_x`` and the tail thrust in ``F_y``, which the design model drops, are ignored), and the
  cross-coupling of the allocation (one torque moves several pitches) is absorbed by giving
  every pitch the same servo. Loop 1 is analysed at ``psi = 0``; with equal x and y gains (and
  equal roll and pitch gains) it is the same at any heading. Loops 1-2 z and loops 3-4 yaw are
  single loops; x/pitch and y/roll differ only through their gains.
* **Continuous time.** The 100 Hz sampling enters only as the half-sample delay of the hold
  at the actuator (``dt/2``, as in the team's check). The forward-Euler integrals and the
  strictly causal read of the pseudo-differentiators (about another ``dt/2`` on the integral
  and feed-forward paths) are neglected. :func:`loop4_discrete` gives the exact
  discrete-time loop 4 of the simulator for comparison: its end-of-step servo output leads
  the continuous model's lag by half a step, so the continuous margins are the pessimistic
  ones (by about 4 deg with servos on).
* **Small signals.** Rate limits, position limits, dead band, quantum, the tilt limit and
  the anti-windup are not in a linear model; the margins say nothing about a transient
  large enough to hit them (the simulations in docs/servo-aware-gains.md do).
* **The delay** is exact (``method="exact"``: frequency-response data on a dense grid,
  python-control's FRD margins) or a Pade approximant (``method="pade"``: rational transfer
  functions, python-control's polynomial margins). Closed-loop stability (``stable``) always
  comes from the Pade model's poles.

References: Zhu & Huo (2013) for the loops and their PD-spectral design; the loop-at-a-time
margins of a cascade and the delay margin ``PM / w_c`` are textbook (Astrom & Murray,
*Feedback Systems*, ch. 10-11, whose Python companion is python-control).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import control as ct
import numpy as np

from autopilot.tlc.gains import Gains, LoopGains
from heli_common.vehicle.airframe import Airframe
from heli_common.vehicle.plant_model import RotorPlant
from heli_common.world.config import Servos

LOOP_CHANNELS: dict[int, tuple[str, str, str]] = {
    1: ("x", "y", "z"),
    2: ("x", "y", "z"),
    3: ("roll", "pitch", "yaw"),
    4: ("roll", "pitch", "yaw"),
}
# the loop-3 channel (0 roll, 1 pitch) that realises loop 2's force on x and y; z: collective
_LOOP2_THROUGH: tuple[int | None, int | None, int | None] = (1, 0, None)

Method = Literal["exact", "pade"]
PADE_ORDER = 4  # (1 + ...)/(1 + ...) of order 4: phase error < 0.1 deg up to w T = 1.5 rad
# the frequency grid of the exact method [rad/s]: 200 points a decade, up to three times
# the 100 Hz Nyquist frequency (314 rad/s); python-control interpolates between them
OMEGA_GRID = np.logspace(-3.0, 3.0, 1201)


@dataclass(frozen=True)
class ServoModel:
    """The small-signal servo of every pitch channel: transport delay, first-order lag, and
    the control rate whose zero-order hold adds half a period of delay."""

    delay_s: float = 0.0
    tau_s: float = 0.0
    rate_hz: float = 100.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delay_s) and self.delay_s >= 0.0):
            raise ValueError(f"delay_s must be finite and >= 0, got {self.delay_s}")
        if not (math.isfinite(self.tau_s) and self.tau_s >= 0.0):
            raise ValueError(f"tau_s must be finite and >= 0, got {self.tau_s}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0.0):
            raise ValueError(f"rate_hz must be finite and > 0, got {self.rate_hz}")

    @property
    def effective_delay_s(self) -> float:
        """Transport delay plus half a control period (the hold)."""
        return self.delay_s + 0.5 / self.rate_hz

    @classmethod
    def from_servos(cls, servos: Servos, rate_hz: float = 100.0) -> ServoModel:
        """The worst channel of a world's ``[servos]`` (largest delay, largest lag)."""
        return cls(max(servos.delay_s), max(servos.tau_s), rate_hz)

    def label(self) -> str:
        return f"{self.delay_s * 1e3:g} ms + {self.tau_s * 1e3:g} ms"


IDEAL_SERVOS = ServoModel(0.0, 0.0)
DEFAULT_SERVOS = ServoModel(0.010, 0.020)  # configs/world/servos-default.toml
SLOPPY_SERVOS = ServoModel(0.020, 0.030)  # configs/world/sloppy-servos.toml
SERVO_MODELS: dict[str, ServoModel] = {
    "ideal": IDEAL_SERVOS,
    "default": DEFAULT_SERVOS,
    "sloppy": SLOPPY_SERVOS,
}


@dataclass(frozen=True)
class RotorFlapping:
    """The rotor plant's flapping in loop 4 (docs/rotor-plant.md, "Margins"): the TLC's torque
    command ``tau_c`` becomes a cyclic ``tau_c / K_d`` (the design model's moment per cyclic
    radian, ``K_d = m g h_mr``); the tip-path plane follows it with the linkage gain ``A`` and
    the time constant ``tau``, lagging the body rate; the hub spring and the thrust give
    ``K = K_beta + m g h_mr`` per radian of flapping. Roll and pitch rates then answer::

        q = (K A / K_d) tau_c / (J s (tau s + 1) + K tau)

    against the design's ``tau_c / (J s)``: loop 4's ``P_4`` gains the factor
    ``(K A / K_d) s / (tau s^2 + s + K tau / J)``. Yaw has no flapping."""

    tau_s: float
    lon_gain: float
    lat_gain: float
    k_n_m_per_rad: float  # K_beta + m g h_mr
    k_design_n_m_per_rad: float  # m g h_mr
    ixx_kg_m2: float
    iyy_kg_m2: float

    @classmethod
    def from_plant(cls, rp: RotorPlant, design: Airframe) -> RotorFlapping:
        b = design.body
        kd = b.mass_kg * b.gravity_m_s2 * b.main_hub_above_cg_m
        pb = rp.body
        k = rp.flapping.hub_stiffness_n_m_per_rad + pb.mass_kg * pb.gravity_m_s2 * pb.main_hub_above_cg_m
        return cls(rp.tau_e_s(), rp.flapping.lon_gain_rad_per_rad, rp.flapping.lat_gain_rad_per_rad, k, kd,
                   pb.ixx_kg_m2, pb.iyy_kg_m2)  # fmt: skip

    def factor(self, ch: int, s: Any) -> _Ratio:
        """The factor of loop 4's plant on channel ``ch`` (0 roll, 1 pitch)."""
        gain = self.lat_gain if ch == 0 else self.lon_gain
        j = self.ixx_kg_m2 if ch == 0 else self.iyy_kg_m2
        g = self.k_n_m_per_rad * gain / self.k_design_n_m_per_rad
        return _Ratio(s * g, s * s * self.tau_s + s + self.k_n_m_per_rad * self.tau_s / j)


@dataclass(frozen=True)
class LoopMargins:
    """Margins of one channel of one loop, broken at the loop's output with the inner loops
    closed and the outer loops open."""

    loop: int  # 1 (position) ... 4 (body rate)
    channel: str  # x, y, z (loops 1-2) or roll, pitch, yaw (loops 3-4)
    crossover_rad_s: float  # lowest gain crossover (|L| = 1): the loop's bandwidth; nan if none
    phase_margin_deg: float  # the smallest over every gain crossover; inf if none
    phase_margin_at_rad_s: float  # the crossover where that smallest margin is
    gain_margin_db: float  # the smallest over every -180 deg crossing above 0; inf if none
    gain_margin_at_rad_s: float
    delay_margin_s: float  # extra loop delay that closes the phase margin: min PM_i / w_i
    crossovers: int  # how many gain crossovers (1 for a well-shaped loop)
    stable: bool  # this loop and every inner one closed: all poles in the open left half-plane

    @property
    def name(self) -> str:
        return f"loop {self.loop} {self.channel}"


@dataclass(frozen=True)
class MarginReport:
    """The margins of every loop and channel for one gain set and one servo model."""

    gains_name: str
    servo: ServoModel
    method: str
    feedforward: bool
    loops: tuple[LoopMargins, ...]

    def get(self, loop: int, channel: str) -> LoopMargins:
        for m in self.loops:
            if m.loop == loop and m.channel == channel:
                return m
        raise KeyError(f"no loop {loop} channel {channel!r}")

    def worst(self) -> LoopMargins:
        """The channel with the smallest phase margin (an unstable one first)."""
        return min(self.loops, key=lambda m: (m.stable, m.phase_margin_deg))

    @property
    def min_phase_margin_deg(self) -> float:
        return min(m.phase_margin_deg for m in self.loops)

    @property
    def all_stable(self) -> bool:
        return all(m.stable for m in self.loops)


# --- the loop algebra, written once for two number types: complex arrays (s = j w, exact
# delay) and numpy polynomials (s = poly1d([1, 0]), Pade delay). ``Any`` because the two
# have no common static type; every public function returns concrete types.


@dataclass(frozen=True)
class _Ratio:
    num: Any
    den: Any


@dataclass(frozen=True)
class _Stage:
    loop: _Ratio  # L_k = K_k P_k / s
    closed: _Ratio  # T_k, what the next outer loop sees
    char: Any  # characteristic polynomial of this closure (polynomial backend only)


def _close(p: _Ratio, lg: LoopGains, ch: int, d: _Ratio, s: Any, feedforward: bool) -> _Stage:
    """Close one channel of a loop around the plant ``p`` (numerator, denominator):
    L = Nk Np / (s^2 Dp); T = Np (s^2 Nd + Nk Dd) / (Dd (s^2 Dp + Np Nk))."""
    zeta, w = lg.zeta[ch], lg.omega_rad_s[ch]
    nk = s * (2.0 * zeta * w) + w * w  # K = nk / s
    num, s_int = p.num, s  # the plant's integrator 1/s ...
    if isinstance(num, np.poly1d) and num.coeffs.size > 1 and num.coeffs[-1] == 0.0:
        # ... cancelled by a plant zero at the origin (the rotor's flapping makes loop 4 a
        # rate-command plant): divide it out, or the polynomials keep a spurious pole at 0
        num, s_int = np.poly1d(num.coeffs[:-1]), 1.0
    char = s * s_int * p.den + num * nk
    loop = _Ratio(nk * num, s * s_int * p.den)
    if feedforward:
        closed = _Ratio(num * (s * s * d.num + nk * d.den), d.den * char)
    else:
        closed = _Ratio(num * nk, char)
    return _Stage(loop, closed, char)


def _cascade(
    gains: Gains, s: Any, actuator: _Ratio, d: _Ratio, feedforward: bool, rotor: RotorFlapping | None = None
) -> dict[tuple[int, int], _Stage]:
    """Every (loop, channel) stage, loop 4 first, each outer loop around the closed inner one;
    with ``rotor``, loop 4's roll and pitch plants carry its flapping."""
    stages: dict[tuple[int, int], _Stage] = {}
    for ch in range(3):
        p4 = actuator
        if rotor is not None and ch < 2:
            f = rotor.factor(ch, s)
            p4 = _Ratio(actuator.num * f.num, actuator.den * f.den)
        stages[4, ch] = _close(p4, gains.loop4_attitude_dynamics, ch, d, s, feedforward)
    for ch in range(3):
        stages[3, ch] = _close(stages[4, ch].closed, gains.loop3_attitude_kinematics, ch, d, s, feedforward)
    for ch, through in enumerate(_LOOP2_THROUGH):
        plant = actuator if through is None else stages[3, through].closed
        stages[2, ch] = _close(plant, gains.loop2_position_dynamics, ch, d, s, feedforward)
    for ch in range(3):
        stages[1, ch] = _close(stages[2, ch].closed, gains.loop1_position_kinematics, ch, d, s, feedforward)
    return stages


def _differentiator_poly(gains: Gains) -> _Ratio:
    wd, zd = gains.differentiator.omega_rad_s, gains.differentiator.zeta
    return _Ratio(np.poly1d([wd * wd]), np.poly1d([1.0, 2.0 * zd * wd, wd * wd]))


def _actuator_poly(servo: ServoModel, order: int) -> _Ratio:
    num, den = ct.pade(servo.effective_delay_s, order)
    return _Ratio(np.poly1d(num), np.polymul(np.poly1d(den), np.poly1d([servo.tau_s, 1.0])))


def _polynomial_stages(
    gains: Gains, servo: ServoModel, feedforward: bool, order: int, rotor: RotorFlapping | None = None
) -> dict[tuple[int, int], _Stage]:
    s = np.poly1d([1.0, 0.0])
    return _cascade(gains, s, _actuator_poly(servo, order), _differentiator_poly(gains), feedforward, rotor)


def _frequency_stages(
    gains: Gains, servo: ServoModel, feedforward: bool, omega: np.ndarray[Any, np.dtype[np.float64]],
    rotor: RotorFlapping | None = None,
) -> dict[tuple[int, int], _Stage]:  # fmt: skip
    s = 1j * omega
    actuator = _Ratio(np.exp(-s * servo.effective_delay_s), 1.0 + servo.tau_s * s)
    dp = _differentiator_poly(gains)
    d = _Ratio(dp.num(s), dp.den(s))
    return _cascade(gains, s, actuator, d, feedforward, rotor)


def _hurwitz(p: np.poly1d) -> bool:
    roots = np.roots(np.trim_zeros(p.coeffs, "f"))
    return bool(np.all(roots.real < 0.0))


def open_loop(
    gains: Gains,
    servo: ServoModel,
    loop: int,
    channel: str,
    *,
    method: Method = "exact",
    feedforward: bool = True,
    pade_order: int = PADE_ORDER,
    omega: np.ndarray[Any, np.dtype[np.float64]] | None = None,
) -> ct.FrequencyResponseData | ct.TransferFunction:
    """The open loop ``L_k`` of one loop and channel: frequency-response data with the exact
    delay (``method="exact"``, on ``omega`` or :data:`OMEGA_GRID`, interpolating between the
    points) or a transfer function with a Pade delay (``method="pade"``)."""
    ch = LOOP_CHANNELS[loop].index(channel)
    if method == "pade":
        st = _polynomial_stages(gains, servo, feedforward, pade_order)[loop, ch]
        return ct.tf(st.loop.num.coeffs, st.loop.den.coeffs)
    w = OMEGA_GRID if omega is None else np.asarray(omega, dtype=float)
    st = _frequency_stages(gains, servo, feedforward, w)[loop, ch]
    return ct.frd(np.asarray(st.loop.num / st.loop.den, dtype=complex), w, smooth=True)


def _margins(
    sys: ct.FrequencyResponseData | ct.TransferFunction, loop: int, channel: str, stable: bool
) -> LoopMargins:
    gm, pm, _sm, wpc, wgc, _wms = ct.stability_margins(sys, returnall=True)
    gm, pm = np.atleast_1d(gm).astype(float), np.atleast_1d(pm).astype(float)
    wpc, wgc = np.atleast_1d(wpc).astype(float), np.atleast_1d(wgc).astype(float)
    # A PI regulator around an integrator (type 2) has its phase tend to -180 deg as w -> 0,
    # where |L| is huge; rounding makes it touch -180 there. Not a margin: crossings below 1 %
    # of the lowest gain crossover are dropped.
    low = 0.01 * float(np.min(wgc)) if wgc.size else 0.0
    keep = wpc > max(low, 1e-9)
    gm, wpc = gm[keep], wpc[keep]
    if wgc.size:
        order = np.argsort(wgc)
        wgc, pm = wgc[order], pm[order]
        i = int(np.argmin(pm))
        crossover, pm_min, pm_at = float(wgc[0]), float(pm[i]), float(wgc[i])
        delay_margin = float(np.min(np.maximum(np.radians(pm), 0.0) / wgc))
    else:
        crossover, pm_min, pm_at, delay_margin = math.nan, math.inf, math.nan, math.inf
    if gm.size:
        j = int(np.argmin(gm))
        gm_db, gm_at = float(20.0 * np.log10(gm[j])), float(wpc[j])
    else:
        gm_db, gm_at = math.inf, math.nan
    return LoopMargins(
        loop=loop, channel=channel, crossover_rad_s=crossover, phase_margin_deg=pm_min,
        phase_margin_at_rad_s=pm_at, gain_margin_db=gm_db, gain_margin_at_rad_s=gm_at,
        delay_margin_s=delay_margin, crossovers=int(wgc.size), stable=stable,
    )  # fmt: skip


def _inner_chain(loop: int, ch: int) -> list[tuple[int, int]]:
    """This (loop, channel) and every closure inside it."""
    chain = [(loop, ch)]
    while loop < 4:
        if loop == 2:
            through = _LOOP2_THROUGH[ch]
            if through is None:
                break
            ch = through
        loop += 1
        chain.append((loop, ch))
    return chain


def loop_margins(
    gains: Gains,
    servo: ServoModel,
    *,
    method: Method = "exact",
    feedforward: bool = True,
    pade_order: int = PADE_ORDER,
    loops: Iterable[tuple[int, str]] | None = None,
    rotor: RotorFlapping | None = None,
) -> MarginReport:
    """Margins of loops 1-4, every channel (or only ``loops``, (loop, channel) pairs), for
    ``gains`` flying through ``servo``.

    ``method="exact"``: the exact delay, margins from python-control's frequency-response
    (FRD) interpolation on :data:`OMEGA_GRID`; ``"pade"``: a Pade delay of ``pade_order``,
    margins from python-control's polynomial method. ``feedforward``: the inner closed loops
    include the pseudo-differentiator feed-forward, as the controller does.
    """
    wanted = (
        [(k, c) for k in (1, 2, 3, 4) for c in LOOP_CHANNELS[k]] if loops is None else list(loops)
    )
    poly = _polynomial_stages(gains, servo, feedforward, pade_order, rotor)
    freq = _frequency_stages(gains, servo, feedforward, OMEGA_GRID, rotor) if method == "exact" else None
    out: list[LoopMargins] = []
    for loop, name in wanted:
        ch = LOOP_CHANNELS[loop].index(name)
        stable = all(_hurwitz(poly[key].char) for key in _inner_chain(loop, ch))
        if freq is None:
            st = poly[loop, ch]
            sys: ct.FrequencyResponseData | ct.TransferFunction = ct.tf(
                st.loop.num.coeffs, st.loop.den.coeffs
            )
        else:
            fs = freq[loop, ch]
            sys = ct.frd(np.asarray(fs.loop.num / fs.loop.den, dtype=complex), OMEGA_GRID)
        out.append(_margins(sys, loop, name, stable))
    return MarginReport(
        gains_name=gains.name, servo=servo, method=method, feedforward=feedforward, loops=tuple(out)
    )


# --- the servo-aware design: the fastest cascade the servo allows


def slowest_decay_rate(zeta: float, omega_rad_s: float) -> float:
    """The slowest decay rate [1/s] of ``e'' + 2 zeta w e' + w^2 e = 0``: ``zeta w`` up to
    critical damping, ``w (zeta - sqrt(zeta^2 - 1))`` above it."""
    if zeta <= 1.0:
        return zeta * omega_rad_s
    return omega_rad_s * (zeta - math.sqrt(zeta * zeta - 1.0))


def round_down(w: float) -> float:
    """``w`` rounded down to a multiple of 0.05 of its decade (4.83 -> 4.8, 0.523 -> 0.52)."""
    q = 0.05 * 10.0 ** math.floor(math.log10(w))
    return round(math.floor(w / q + 1e-9) * q, 10)


def _with_loop(gains: Gains, loop: int, omega: float, zeta: float | None, channels: Sequence[int]) -> Gains:
    lg = gains.loops()[loop - 1]
    w, z = list(lg.omega_rad_s), list(lg.zeta)
    for ch in channels:
        w[ch] = omega
        if zeta is not None:
            z[ch] = zeta
    new = LoopGains(zeta=(z[0], z[1], z[2]), omega_rad_s=(w[0], w[1], w[2]))
    if loop == 1:
        return dataclasses.replace(gains, loop1_position_kinematics=new)
    if loop == 2:
        return dataclasses.replace(gains, loop2_position_dynamics=new)
    if loop == 3:
        return dataclasses.replace(gains, loop3_attitude_kinematics=new)
    return dataclasses.replace(gains, loop4_attitude_dynamics=new)


ZETA4_GRID = tuple(round(0.70 + 0.05 * k, 2) for k in range(13))  # 0.70, 0.75 ... 1.30


@dataclass(frozen=True)
class DesignStep:
    """One loop of :func:`servo_aware_gains`: the bandwidth chosen and the margins it has."""

    loop: int
    zeta: float
    omega_rad_s: float  # rounded down
    limit: str  # what stopped it: "phase margin", "separation (omega)", "separation (crossover)"
    margins: LoopMargins


def servo_aware_gains(
    base: Gains,
    servo: ServoModel = SLOPPY_SERVOS,
    *,
    pm_min_deg: float = 46.0,
    separation: float = 3.0,
    zeta4_grid: Sequence[float] = ZETA4_GRID,
    name: str = "servo-aware",
) -> tuple[Gains, tuple[DesignStep, ...]]:
    """The fastest cascade ``servo`` allows, from the inside out (roll, pitch and yaw of loops
    3-4 and x, y of loops 1-2 together; z of loops 1-2, the zetas of loops 1-3 and the
    differentiator kept from ``base``):

    1. loop 4: for each damping in ``zeta4_grid`` the largest ``w4`` with at least
       ``pm_min_deg`` of phase margin (bisection); the damping whose error dynamics then decay
       fastest (:func:`slowest_decay_rate`) wins;
    2. loops 3, 2, 1 in turn, each around the closed inner loops: the largest ``w`` with at
       least ``pm_min_deg`` of phase margin, a stable closure, ``w`` at most the inner loop's
       ``w / separation`` and a crossover at most the inner loop's crossover ``/ separation``.

    Each ``w`` is rounded down (:func:`round_down`) before the next loop is designed around
    it. Margins by the Pade method with feed-forward (the exact method agrees within 0.1 deg).
    """

    def margins(g: Gains, loop: int) -> LoopMargins:
        ch = "roll" if loop >= 3 else "x"
        return loop_margins(g, servo, method="pade", loops=[(loop, ch)]).loops[0]

    def largest(ok: Callable[[float], bool], hi: float) -> float:
        lo = 1e-3 * hi
        if not ok(lo):
            raise ValueError("no bandwidth meets the margins")
        if ok(hi):
            return hi
        while hi > 1.0005 * lo:
            mid = math.sqrt(lo * hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo

    steps: list[DesignStep] = []
    g = dataclasses.replace(base, name=name)
    attitude, horizontal = (0, 1, 2), (0, 1)
    w_max = base.loop4_attitude_dynamics.omega_rad_s[0]
    best: tuple[float, float, float] | None = None  # (decay rate, zeta, omega)
    for z4 in zeta4_grid:
        def ok4(w: float, z4: float = z4, g: Gains = g) -> bool:
            m = margins(_with_loop(g, 4, w, z4, attitude), 4)
            return m.stable and m.phase_margin_deg >= pm_min_deg

        w4 = round_down(largest(ok4, w_max))
        rate = slowest_decay_rate(z4, w4)
        if best is None or rate > best[0] + 1e-12:
            best = (rate, z4, w4)
    assert best is not None
    _, z4, w4 = best
    g = _with_loop(g, 4, w4, z4, attitude)
    steps.append(DesignStep(4, z4, w4, "phase margin", margins(g, 4)))
    for loop, chans in ((3, attitude), (2, horizontal), (1, horizontal)):
        inner = steps[-1]
        zeta = g.loops()[loop - 1].zeta[0]
        cap = inner.omega_rad_s / separation
        xover_cap = inner.margins.crossover_rad_s / separation

        def ok(
            w: float, loop: int = loop, chans: tuple[int, ...] = chans, xcap: float = xover_cap, g: Gains = g
        ) -> bool:
            m = margins(_with_loop(g, loop, w, None, chans), loop)
            return m.stable and m.phase_margin_deg >= pm_min_deg and m.crossover_rad_s <= xcap

        w = round_down(largest(ok, cap))
        g = _with_loop(g, loop, w, None, chans)
        m = margins(g, loop)
        if w >= round_down(cap):
            limit = "separation (omega)"
        elif m.phase_margin_deg < pm_min_deg + 1.0:
            limit = "phase margin"
        else:
            limit = "separation (crossover)"
        steps.append(DesignStep(loop, zeta, w, limit, m))
    return g, tuple(steps)


def loop4_discrete(zeta: float, omega_rad_s: float, servo: ServoModel) -> ct.TransferFunction:
    """Loop 4 alone (one channel) exactly as the simulator realises it at one plant step per
    control tick, in discrete time (``dt = 1/rate_hz``): the regulator ``2 zeta w e[k] + w^2
    I[k]`` with the forward-Euler integral ``I[k] = dt sum_{j<k} e[j]``; the servo's FIFO delay
    of ``round(delay/dt)`` ticks and its lag ``y[k] = y[k-1] + a (v[k] - y[k-1])``, ``a = 1 -
    exp(-dt/tau)``, whose output (the end-of-step position) the plant holds over the step; the
    rate integrating that held torque, ``w[k+1] = w[k] + dt y[k]``."""
    dt = 1.0 / servo.rate_hz
    z = ct.tf([1.0, 0.0], [1.0], dt)
    regulator = 2.0 * zeta * omega_rad_s + omega_rad_s**2 * dt / (z - 1.0)
    a = 1.0 if servo.tau_s == 0.0 else -math.expm1(-dt / servo.tau_s)
    lag = a * z / (z - (1.0 - a))
    steps = round(servo.delay_s / dt)
    delay = ct.tf([1.0], [1.0] + [0.0] * steps, dt)
    result: ct.TransferFunction = regulator * lag * delay * (dt / (z - 1.0))
    return result


def loop4_discrete_margins(gains: Gains, servo: ServoModel, channel: str = "roll") -> LoopMargins:
    """Margins of :func:`loop4_discrete` for one loop-4 channel of ``gains``. A -180 deg
    crossing exactly at the Nyquist frequency (where the ideal-servo loop is real) counts."""
    ch = LOOP_CHANNELS[4].index(channel)
    lg = gains.loop4_attitude_dynamics
    sys = loop4_discrete(lg.zeta[ch], lg.omega_rad_s[ch], servo)
    stable = bool(np.all(np.abs(ct.poles(ct.feedback(sys, 1))) < 1.0))
    with warnings.catch_warnings():  # python-control notes that it falls back to FRD
        warnings.simplefilter("ignore", UserWarning)
        m = _margins(sys, 4, channel, stable)
    at_nyquist = complex(sys(-1.0))
    if at_nyquist.real < 0.0 and abs(at_nyquist.imag) < 1e-9 * abs(at_nyquist):
        gm_db = -20.0 * math.log10(abs(at_nyquist))
        if gm_db < m.gain_margin_db:
            m = dataclasses.replace(m, gain_margin_db=gm_db, gain_margin_at_rad_s=math.pi * servo.rate_hz)
    return m


def _fmt(v: float, spec: str) -> str:
    if math.isinf(v):
        return "inf"
    if math.isnan(v):
        return "-"
    return format(v, spec)


def format_table(reports: Iterable[MarginReport], *, merge_channels: bool = True) -> str:
    """A Markdown table of the reports. With ``merge_channels``, channels of a loop whose
    margins print the same share one row (``roll/pitch/yaw``)."""
    head = (
        "| gains | servos (delay + lag) | loop | channel | crossover [rad/s] | PM [deg] | "
        "GM [dB] | delay margin [ms] | closed loop stable |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|---|"]
    for r in reports:
        rows: list[tuple[list[str], tuple[str, ...]]] = []
        for m in r.loops:
            cells = (
                _fmt(m.crossover_rad_s, ".2f"),
                _fmt(m.phase_margin_deg, ".1f")
                + (f" (of {m.crossovers} crossovers)" if m.crossovers > 1 else ""),
                _fmt(m.gain_margin_db, ".1f"),
                _fmt(m.delay_margin_s * 1e3, ".0f"),
                "yes" if m.stable else "**no**",
            )
            if merge_channels and rows and rows[-1][1] == (str(m.loop), *cells):
                rows[-1][0].append(m.channel)
            else:
                rows.append(([m.channel], (str(m.loop), *cells)))
        for channels, row in rows:
            lines.append(
                f"| {r.gains_name} | {r.servo.label()} | {row[0]} | {'/'.join(channels)} | "
                + " | ".join(row[1:])
                + " |"
            )
    lines += [
        "",
        "PM: the smallest phase margin over the loop's gain crossovers ('of 3 crossovers': |L| crosses 1 "
        "three times; a negative PM: the phase is past -180 deg at one of them). Closed loop stable: "
        "this loop and every inner one closed, all poles in the left half-plane. A loop can show a "
        "comfortable PM and still be unstable when its open loop is itself unstable (an inner loop "
        "that does not close): the margin of an unstable loop is no margin, so stability is judged "
        "on the poles, never on PM alone.",
    ]
    return "\n".join(lines)


def print_table(reports: Sequence[MarginReport], *, merge_channels: bool = True) -> None:
    print(format_table(reports, merge_channels=merge_channels))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m autopilot.analysis.margins [GAINS ...]``: the table for each gain file."""
    import argparse
    import sys

    from heli_common.config import ConfigError

    p = argparse.ArgumentParser(
        prog="python -m autopilot.analysis.margins",
        description="each TLC loop opened alone behind the three servo models: its gain and phase "
                    "margins (heli-sitl margins --loops prints the same)",
    )  # fmt: skip
    defaults = ["gains_paper.toml", "gains_servo_aware.toml"]
    p.add_argument("gains", nargs="*", metavar="GAINS", default=defaults,
                   help="gain files or names in configs/ (default: gains_paper.toml gains_servo_aware.toml)")
    args = p.parse_args(argv)
    try:
        reports = [loop_margins(Gains.load(g), sv) for g in args.gains for sv in SERVO_MODELS.values()]
    except (ConfigError, OSError) as e:
        print(f"python -m autopilot.analysis.margins: {e}", file=sys.stderr)
        return 2
    print_table(reports)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
