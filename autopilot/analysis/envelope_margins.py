"""Disk margins of a linearised closed loop from its loop frequency responses: loop at a time
and simultaneous (every input, or every output, perturbed at once), and the table of them over
the flight envelope that ``heli-sitl margins --envelope`` prints (heli_sitl/engine/loop_linear.py
linearises the loop; docs/tlc-rotor.md, "Margins over the envelope").

The disk margin of skew ``sigma`` (Seiler, Packard & Gahinet, "An introduction to disk
margins", IEEE Control Systems 40(5), 2020) is::

    alpha_max = 1 / max_w  mu( S(jw) + (sigma - 1)/2 I )

with ``S = (I + L)^-1`` the sensitivity at the break point. Every figure here is the
balanced one, ``sigma = 0``: ``S - I/2 = (S - T)/2``, a disk symmetric in gain (``(1 + a/2) /
(1 - a/2)`` up and down) and phase (``+/- 2 atan(a/2)``). For one loop ``mu`` is ``|.|``,
which is what python-control's :func:`control.disk_margins` computes (tests/test_margins_speed.py
holds them together). For several loops at once python-control takes ``mu`` of a diagonal
uncertainty (each channel its own complex gain) from slycot's AB13MD upper bound; slycot is
not installed here (python-control then refuses), so :func:`simultaneous_disk` computes that
same upper bound, ``min_D sigma_max(D M D^-1)`` over positive diagonal ``D``: the margins it
gives are guaranteed ones (at most the true). :func:`full_block_disk`, one full complex block
(``1 / ||(S - T)/2||_inf``, the channels cross-coupled by the perturbation), is the
smaller, cruder figure the design-point summary quotes for the four inputs.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from io import StringIO
from typing import Any

import numpy as np

SKEW = 0.0  # balanced: the disk symmetric in gain and phase

ComplexArray = np.ndarray[Any, np.dtype[Any]]  # complex responses (FloatArray elsewhere)
FloatArray = np.ndarray[Any, np.dtype[np.float64]]


@dataclass(frozen=True)
class Disk:
    """A disk margin: its size, the gain and phase it allows, where and in which channel."""

    alpha: float  # alpha_max; 0 when the closed loop is unstable
    omega_rad_s: float  # the frequency of the smallest disk (nan if none)
    channel: str  # the break point (loop at a time), or the largest entry of the worst direction

    @property
    def gain_margin_db(self) -> float:
        """The balanced disk's gain margin (+/-) [dB]."""
        if self.alpha <= 0.0:
            return 0.0
        if self.alpha >= 2.0:
            return math.inf
        return 20.0 * math.log10((1.0 + self.alpha / 2.0) / (1.0 - self.alpha / 2.0))

    @property
    def phase_margin_deg(self) -> float:
        """The balanced disk's phase margin (+/-) [deg]."""
        return 90.0 if self.alpha >= 2.0 else math.degrees(2.0 * math.atan(self.alpha / 2.0))

    def cell(self, *, where: bool = True) -> str:
        if self.alpha <= 0.0:
            return "unstable"
        at = f", {self.omega_rad_s:.1f} rad/s" if where and math.isfinite(self.omega_rad_s) else ""
        return f"{self.alpha:.2f} ({self.channel}{at})"


def skewed_sensitivity(loop: ComplexArray, skew: float = SKEW) -> ComplexArray:
    """``S + (skew - 1)/2 I`` of a square loop ``(n_w, n, n)`` (or a SISO ``(n_w,)``)."""
    if loop.ndim == 1:
        return np.asarray(1.0 / (1.0 + loop) + 0.5 * (skew - 1.0))
    eye = np.eye(loop.shape[-1])
    return np.asarray(np.linalg.inv(eye + loop) + 0.5 * (skew - 1.0) * eye)


def siso_disk(siso: ComplexArray, omega_rad_s: np.ndarray[Any, np.dtype[np.float64]], channel: str,
              skew: float = SKEW) -> Disk:  # fmt: skip
    """The disk margin of one loop's response: ``1 / max_w |S + (skew - 1)/2|``."""
    m = np.abs(skewed_sensitivity(siso, skew))
    i = int(np.argmax(m))
    return Disk(float(1.0 / m[i]), float(omega_rad_s[i]), channel)


def full_block_disk(loop: ComplexArray, omega_rad_s: np.ndarray[Any, np.dtype[np.float64]],
                    names: Sequence[str], skew: float = SKEW) -> Disk:  # fmt: skip
    """Every channel of ``loop`` perturbed at once by one full complex block (the channels
    cross-coupled by the perturbation): ``1 / max_w sigma_max(S + (skew - 1)/2 I)``, the
    smallest of the simultaneous margins. The channel named is the largest entry of the
    worst frequency's input singular direction."""
    m = skewed_sensitivity(loop, skew)
    _u, sv, vh = np.linalg.svd(m)
    i = int(np.argmax(sv[:, 0]))
    j = int(np.argmax(np.abs(vh[i, 0, :])))
    return Disk(float(1.0 / sv[i, 0]), float(omega_rad_s[i]), names[j])


_LOG_D_BOUND = 30.0  # |log d| of a scaling; a channel nothing couples to goes to the bound


def _osborne(m: ComplexArray, sweeps: int = 30) -> FloatArray:
    """Log scalings ``x`` that balance ``|D M D^-1|``'s off-diagonal rows against columns
    (Osborne's iteration), for one matrix ``(n, n)`` or a stack ``(n_w, n, n)`` at once: a good
    start for the scaled bound, and an upper bound of it."""
    a = np.abs(m)
    n = a.shape[-1]
    a[..., np.arange(n), np.arange(n)] = 0.0
    x = np.zeros(a.shape[:-1])
    for _ in range(sweeps):
        for i in range(n):
            e = np.exp(x - x[..., i : i + 1])
            r = np.sum(a[..., i, :] / e, axis=-1)  # row i of D A D^-1: d_i a_ij / d_j
            c = np.sum(a[..., :, i] * e, axis=-1)  # column i: d_j a_ji / d_i
            ok = (r > 1e-300) & (c > 1e-300)
            step = 0.5 * np.log(np.where(ok, c, 1.0) / np.where(ok, r, 1.0))
            x[..., i] = np.clip(x[..., i] + step, -_LOG_D_BOUND, _LOG_D_BOUND)
    return np.asarray(x)


def _scaled(m: ComplexArray, x: FloatArray) -> tuple[float, FloatArray, FloatArray]:
    """``sigma_max(D M D^-1)`` with ``D = diag(exp x)``, its gradient in ``x`` and the input
    direction ``v``: d sigma / d x_i = sigma (|u_i|^2 - |v_i|^2)."""
    d = np.exp(x)
    u, sv, vh = np.linalg.svd(d[:, None] * m / d[None, :])
    uu, vv = np.abs(u[:, 0]) ** 2, np.abs(vh[0, :]) ** 2
    return float(sv[0]), sv[0] * (uu - vv), vv


def mu_upper_bound(m: ComplexArray, x0: FloatArray | None = None) -> tuple[float, FloatArray]:
    """The upper bound ``min_D sigma_max(D M D^-1)`` (D positive diagonal) of the structured
    singular value of ``M`` for a diagonal complex perturbation, what slycot's AB13MD bounds
    for python-control's MIMO disk margin: Osborne's balancing, then L-BFGS on the log
    scalings (the bound is convex in them), from ``x0`` if given (the result is then at most
    ``sigma_max`` with those scalings). Returns the bound and the worst input direction."""
    from scipy.optimize import minimize

    x0 = _osborne(m) if x0 is None else x0
    n = m.shape[0]
    res = minimize(lambda x: _scaled(m, x)[:2], x0, jac=True, method="L-BFGS-B",
                   bounds=[(-_LOG_D_BOUND, _LOG_D_BOUND)] * n,
                   options={"maxiter": 200, "gtol": 1e-10})  # fmt: skip
    best = min((x0, np.asarray(res.x)), key=lambda x: _scaled(m, x)[0])
    s, _g, v = _scaled(m, best)
    return s, v


def simultaneous_disk(loop: ComplexArray, omega_rad_s: np.ndarray[Any, np.dtype[np.float64]],
                      names: Sequence[str], skew: float = SKEW) -> Disk:  # fmt: skip
    """Every channel of ``loop`` perturbed at once, each by its own complex gain (a diagonal
    perturbation, python-control's structure): ``1 / max_w mu(S + (skew - 1)/2 I)`` with ``mu``
    its D-scaled upper bound (:func:`mu_upper_bound`), so the margin is a guaranteed one (at
    most the true). Frequencies are bounded from the top by their Osborne-scaled value (an
    upper bound of the optimised one) and optimised until none left can exceed the worst found.
    The channel named is the largest entry of the worst input direction."""
    m = skewed_sensitivity(loop, skew)
    if m.ndim == 1 or m.shape[-1] == 1:
        return _siso_from_m(m.reshape(-1), omega_rad_s, names[0])
    xs = _osborne(m, 10)
    d = np.exp(xs)
    rough = np.linalg.norm(d[:, :, None] * m / d[:, None, :], 2, axis=(1, 2))
    worst, at, direction = -1.0, 0, np.zeros(m.shape[-1])
    for i in np.argsort(rough)[::-1]:
        if rough[i] <= worst:
            break
        s, v = mu_upper_bound(m[i], xs[i])
        if s > worst:
            worst, at, direction = s, int(i), v
    return Disk(float(1.0 / worst), float(omega_rad_s[at]), names[int(np.argmax(direction))])


def _siso_from_m(m: ComplexArray, omega_rad_s: np.ndarray[Any, np.dtype[np.float64]], channel: str) -> Disk:
    a = np.abs(m)
    i = int(np.argmax(a))
    return Disk(float(1.0 / a[i]), float(omega_rad_s[i]), channel)


@dataclass(frozen=True)
class EnvelopeRow:
    """One operating point's margins."""

    speed_m_s: float
    spectral_radius: float  # the closed loop's largest |lambda|, delay included
    input_at_a_time: Disk  # the worst pitch input, that channel opened, every other closed
    output_at_a_time: Disk  # the worst measured state, likewise
    inputs_at_once: Disk  # all four pitches at once, each its own gain (diagonal, D-scaled bound)
    outputs_at_once: Disk  # every measured state at once, likewise
    inputs_full_block: Disk  # all four pitches at once, one full complex block

    @property
    def stable(self) -> bool:
        return self.spectral_radius < 1.0


@dataclass(frozen=True)
class EnvelopeTable:
    """The margins of one gain set on one plant with one servo model over speed."""

    gains: str
    plant: str
    servos: str
    delay_ticks: int
    rate_hz: float
    rows: tuple[EnvelopeRow, ...]

    def row(self, speed_m_s: float) -> EnvelopeRow:
        for r in self.rows:
            if abs(r.speed_m_s - speed_m_s) < 1e-9:
                return r
        raise KeyError(f"no row at {speed_m_s} m/s")

    def header(self) -> str:
        ms = self.delay_ticks * 1e3 / self.rate_hz
        delay = f"{self.delay_ticks} tick{'s' if self.delay_ticks != 1 else ''} ({ms:g} ms)"
        return (f"{self.gains} on the {self.plant} plant, servos {self.servos}, level flight north at "
                f"20 m; computation delay {delay}; ideal sensing (the true state, no gyro filter, "
                f"no navigation filter); servo rate limits linearised out; balanced disk margins "
                f"(skew 0)")  # fmt: skip

    def markdown(self) -> str:
        lines = [
            f"{self.header()}:",
            "",
            "| speed [m/s] | max abs(lambda) | loop at a time, worst input | loop at a time, worst state "
            "| all 4 inputs at once | all 12 states at once |",
            "|---|---|---|---|---|---|",
        ]
        for r in self.rows:
            if math.isnan(r.spectral_radius):
                lines.append(f"| {r.speed_m_s:g} | no equilibrium found | | | | |")
                continue
            flag = "" if r.stable else " **unstable**"
            lines.append(f"| {r.speed_m_s:g} | {r.spectral_radius:.4f}{flag} | "
                         f"{r.input_at_a_time.cell()} | {r.output_at_a_time.cell()} | "
                         f"{r.inputs_at_once.cell()} | {r.outputs_at_once.cell()} |")  # fmt: skip
        return "\n".join(lines)

    def comment(self) -> str:
        """The table as a gain file's comment lines (one row a line)."""
        lines = [f"# {self.header()}:"]
        for r in self.rows:
            if math.isnan(r.spectral_radius):
                lines.append(f"#   {r.speed_m_s:4g} m/s: no equilibrium found")
                continue
            lines.append(f"#   {r.speed_m_s:4g} m/s: input {r.input_at_a_time.cell(where=False)}, "
                         f"state {r.output_at_a_time.cell(where=False)}, "
                         f"all inputs {r.inputs_at_once.cell(where=False)}, "
                         f"all states {r.outputs_at_once.cell(where=False)}"
                         + ("" if r.stable else
                            f" UNSTABLE (max |lambda| {r.spectral_radius:.4f})"))  # fmt: skip
        return "\n".join(lines)


CSV_COLUMNS = ("gains", "plant", "servos", "delay_ticks", "skew", "speed_m_s", "spectral_radius", "stable",
               "input_at_a_time", "input_at_a_time_channel", "input_at_a_time_rad_s",
               "state_at_a_time", "state_at_a_time_channel", "state_at_a_time_rad_s",
               "inputs_at_once", "inputs_at_once_channel", "inputs_at_once_rad_s",
               "states_at_once", "states_at_once_channel", "states_at_once_rad_s",
               "inputs_full_block", "inputs_full_block_channel", "inputs_full_block_rad_s")  # fmt: skip


def envelope_csv(tables: Sequence[EnvelopeTable]) -> str:
    buf = StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for t in tables:
        for r in t.rows:
            cells: list[object] = [t.gains, t.plant, t.servos, t.delay_ticks, SKEW, r.speed_m_s,
                                   f"{r.spectral_radius:.6f}", r.stable]  # fmt: skip
            for d in (r.input_at_a_time, r.output_at_a_time, r.inputs_at_once, r.outputs_at_once,
                      r.inputs_full_block):
                cells += [f"{d.alpha:.4f}", d.channel, f"{d.omega_rad_s:.3f}"]
            w.writerow(cells)
    return buf.getvalue()


__all__ = ["CSV_COLUMNS", "SKEW", "Disk", "EnvelopeRow", "EnvelopeTable", "envelope_csv", "full_block_disk",
           "mu_upper_bound", "simultaneous_disk",
           "siso_disk", "skewed_sensitivity"]  # fmt: skip
