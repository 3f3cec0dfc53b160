"""The controllers' one contract: ``update(t, state, reference) -> pitches``, no I/O, no clock.

A controller is a compiled kernel over a flat state vector plus a frozen tuple of
constants built from the airframe, its gains and the control rate. :class:`KernelController`
owns the state, the diagnostics and the rebuilding of constants; a controller supplies the
kernel (``kernel(constants, state, x, ref, hold_integrators, out, diag) -> status``), the
size of its state and how its constants are made.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from numba.extending import overload

from autopilot.reference import N_REF, REF_POS
from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import N_PITCH, N_STATE, POS, FloatArray
from heli_common.vehicle.airframe import Airframe, PitchLimits

# diagnostics written each tick, the same for every controller
DIAG = Layout(
    "controller diagnostics",
    ("phi_c", 1), ("theta_c", 1), ("psi_c", 1),  # the attitude commanded [rad]
    ("tm", 1),  # main-rotor thrust commanded [N]
    ("sat_mask", 1), ("tilt_limited", 1), ("status", 1),
)  # fmt: skip
D_PHI_C = DIAG.offset("phi_c")
D_THETA_C = DIAG.offset("theta_c")
D_PSI_C = DIAG.offset("psi_c")
D_TM = DIAG.offset("tm")
D_SAT_MASK = DIAG.offset("sat_mask")
D_TILT_LIMITED = DIAG.offset("tilt_limited")
D_STATUS = DIAG.offset("status")
N_DIAG = DIAG.size

# status codes
OK, BAD_INPUT, BAD_OUTPUT = 0, 1, 2

G = TypeVar("G")


# --- what every kernel does around its law: refuse a tick, or commit one


@njit
def all_finite(v: FloatArray) -> bool:
    for i in range(v.shape[0]):  # noqa: SIM110 (numba compiles no generator inside all())
        if not math.isfinite(v[i]):
            return False
    return True


@njit
def refuse(st: FloatArray, last_u: int, out: FloatArray, diag: FloatArray, status: int) -> int:
    """A tick without a valid command: the last valid one again (zero pitch before the
    first), the state untouched, ``status`` in the diagnostics."""
    out[:] = st[last_u : last_u + N_PITCH]
    diag[D_STATUS] = status
    return status


@njit
def commit(
    st: FloatArray, s: FloatArray, last_u: int, u: FloatArray, out: FloatArray, diag: FloatArray,
    phi_c: float, theta_c: float, psi_c: float, tm: float, sat_mask: int, tilt_limited: bool,
) -> int:  # fmt: skip
    """A valid tick: the new state ``s`` (with ``u`` as its last valid command) replaces
    ``st``, ``u`` goes out, the diagnostics are written."""
    s[last_u : last_u + N_PITCH] = u
    st[:] = s
    out[:] = u
    diag[D_PHI_C], diag[D_THETA_C], diag[D_PSI_C] = phi_c, theta_c, psi_c
    diag[D_TM] = tm
    diag[D_SAT_MASK] = sat_mask
    diag[D_TILT_LIMITED] = tilt_limited
    diag[D_STATUS] = OK
    return OK
Kernel = Callable[[Any, FloatArray, FloatArray, FloatArray, bool, FloatArray, FloatArray], int]

# --- one dispatch for every compiled law: by the type of its constants

_LAWS: dict[type, Kernel] = {}


def register_law(constants_type: type, kernel: Kernel) -> None:
    """Make ``kernel`` the law :func:`control_law` runs for constants of ``constants_type``
    (a NamedTuple: each compiled controller registers its own, once, at import)."""
    _LAWS[constants_type] = kernel


def control_law(
    kc: Any, state: FloatArray, x: FloatArray, ref: FloatArray, hold: bool, out: FloatArray, diag: FloatArray
) -> int:
    """The registered law for ``kc``'s type, one tick. Compiled code that calls this (the
    in-process loop) is compiled once per law, the call resolved when it is typed: a direct
    call, no branch on which law, and the machine code cached as any other (numba cannot
    cache a function that takes another compiled function as an argument)."""
    return _LAWS[type(kc)](kc, state, x, ref, hold, out, diag)


@overload(control_law)
def _control_law_typed(
    kc: Any, state: Any, x: Any, ref: Any, hold: Any, out: Any, diag: Any
) -> Any:
    law = _LAWS.get(getattr(kc, "instance_class", None))  # type: ignore[arg-type]
    if law is None:
        return None

    # numba requires the typing function's signature, annotations included
    def impl(kc: Any, state: Any, x: Any, ref: Any, hold: Any, out: Any, diag: Any) -> Any:
        return law(kc, state, x, ref, hold, out, diag)

    return impl


class KernelController(ABC, Generic[G]):
    """A controller with its state; one ``update`` per control tick. The caller owns time
    and calls ``update`` once per control period (zero-order hold on the output)."""

    #: the name the command lines and records use ("tlc", "pid")
    kind: ClassVar[str]
    n_state: ClassVar[int]

    def __init__(self, airframe: Airframe, gains: G, rate_hz: float = 100.0) -> None:
        self.airframe = airframe
        self.gains = gains
        self.rate_hz = float(rate_hz)
        self.constants = self._make_constants()
        self.state = np.zeros(self.n_state)
        self.diag = np.zeros(N_DIAG)
        self._out = np.zeros(N_PITCH)

    @abstractmethod
    def _make_constants(self) -> Any:
        """The kernel's constants from ``airframe``, ``gains`` and ``rate_hz``."""

    @staticmethod
    @abstractmethod
    def kernel() -> Kernel:
        """The compiled control law."""

    @property
    def dt_s(self) -> float:
        return float(self.constants.dt_s)

    def reset(self) -> None:
        """Forget integrals and filter states; the next update re-initialises them."""
        self.state[:] = 0.0

    def set_gains(self, gains: G) -> None:
        """New gains take effect from the next update; integrals and filters are kept."""
        self.gains = gains
        self.constants = self._make_constants()

    def set_limits(self, limits: PitchLimits) -> None:
        """New pitch limits from the next update."""
        self.airframe = dataclasses.replace(self.airframe, limits=limits)
        self.constants = self._make_constants()

    def update(
        self, t: float, x: FloatArray, ref: FloatArray, *, hold_integrators: bool = False
    ) -> FloatArray:
        """Pitches [rad] (theta_m, theta_t, eps, eta) for measured state ``x`` (NWU/FLU) and
        reference ``ref`` (pos, vel, acc in NWU; vel/acc may be NaN where unknown).

        ``t`` is the tick time; the laws are time-invariant given ``ref`` and do not read it.
        Returns a new array; a non-finite input yields the last valid command.
        """
        if x.shape != (N_STATE,) or ref.shape != (N_REF,):
            raise ValueError(f"state must be ({N_STATE},) and reference ({N_REF},)")
        self.kernel()(self.constants, self.state, x, ref, hold_integrators, self._out, self.diag)
        return self._out.copy()

    def trial_update(self, t: float, x: FloatArray, ref: FloatArray) -> FloatArray:
        """The command :meth:`update` would give now, with nothing of this controller changed
        (the kernel on copies of its state): what a copy of the whole controller gave, for
        the price of three small arrays (a deep copy cost ~0.4 ms, each campaign flight)."""
        if x.shape != (N_STATE,) or ref.shape != (N_REF,):
            raise ValueError(f"state must be ({N_STATE},) and reference ({N_REF},)")
        out = self._out.copy()
        self.kernel()(self.constants, self.state.copy(), x, ref, False, out, self.diag.copy())
        return out

    def warm_up(self, x: FloatArray) -> None:
        """Run the kernel once on throwaway copies (a hold at ``x``): numba loads compiled
        code on a function's first call, tens of milliseconds that a real-time loop's first
        tick must not pay. Nothing of this controller changes."""
        ref = np.zeros(N_REF)
        ref[REF_POS] = x[POS]
        self.kernel()(self.constants, self.state.copy(), x, ref, False, self._out.copy(), self.diag.copy())

    @property
    def status(self) -> int:
        return int(self.diag[D_STATUS])
