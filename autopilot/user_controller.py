"""Your own controller: the contract it keeps, and how the bench flies it.

A controller is any class of this shape (plain Python, or calling numba inside)::

    class MyController:
        name = "my law"                      # optional: how records and tables name it

        def __init__(self, airframe: Airframe, rate_hz: float) -> None: ...
        def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
            '''pitches [rad], shape (4,): theta_m, theta_t, eps, eta'''
        def reset(self) -> None: ...         # forget integrals and filters
        # optional: def set_limits(self, limits: PitchLimits) -> None

``state`` is the (12,) plant state (or the navigation estimate flying from sensors): earth
NWU position, body FLU velocity, ZYX Euler angles, body FLU rates, in
:mod:`heli_common.state`'s order. ``reference`` is the (9,) :mod:`autopilot.reference`
vector: position, velocity, acceleration in earth NWU (a derivative may be NaN where the
trajectory does not know it). ``update`` is called once per control tick at ``rate_hz``;
the command is held until the next tick. The bench calls ``reset`` while the vehicle is
disarmed and after a stall.

The bench names a controller by a string, so that one class flies in-process, in the
autopilot process and in a campaign's workers: ``"tlc"``, ``"pid"``, a name an installed
package registers (entry point group ``heli_tlc_sitl.controllers``:
:mod:`autopilot.controller_names`), or ``"package.module:Class"`` /
``"path/to/file.py:Class"`` for yours.

:class:`UserController` wraps your class with what the bench guarantees around every
controller: a non-finite input never reaches your code and a non-finite or wrongly shaped
output never reaches a servo (the last valid command is held instead, as the compiled
kernels do), and the command is clipped to the pitch limits. In-process (``strict``) an
exception from your code ends the flight with its traceback; in the autopilot process it is
logged once and counted, and the last valid command is held: a bug must not crash a flying
vehicle's autopilot.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from autopilot.control import BAD_INPUT, BAD_OUTPUT, D_SAT_MASK, D_STATUS, N_DIAG, OK
from autopilot.controller_names import BUILT_IN, registered
from autopilot.reference import N_REF, REF_POS
from heli_common import user_class
from heli_common.config import ConfigError
from heli_common.state import N_PITCH, N_STATE, FloatArray
from heli_common.vehicle.airframe import Airframe, PitchLimits

log = logging.getLogger(__name__)

USER = "user"  # the kind of every controller loaded from a "module:Class" string


@runtime_checkable
class Controller(Protocol):
    """The contract of a controller you write (see the module's documentation)."""

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray: ...

    def reset(self) -> None: ...


def is_user_spec(spec: str) -> bool:
    """``"module:Class"``, ``"file.py:Class"`` or a registered name: not a built-in one."""
    return spec not in BUILT_IN and (":" in spec or spec in registered())


def normalise_spec(spec: str) -> str:
    """``spec`` checked (a built-in name, or a class that loads and keeps the contract) with a
    file path made absolute, so that another process or directory loads the same file.
    Raises :class:`ConfigError` naming what is wrong."""
    if spec in BUILT_IN:
        return spec
    if ":" not in spec:
        names = registered()
        if spec not in names:
            others = f", a registered name ({', '.join(sorted(names))})" if names else ""
            raise ConfigError(f"controller: expected 'tlc', 'pid'{others}, 'package.module:Class' or "
                              f"'path/to/file.py:Class', got {spec!r}")  # fmt: skip
        load_class(spec)  # the name stays: every process resolves it the same way
        return spec
    spec = user_class.absolute_spec(spec)
    load_class(spec)
    return spec


def user_traceback(exc: BaseException) -> str:
    """The traceback of an exception a user's controller raised, from the first frame outside
    the bench's own packages (the user's file and line first, the bench's frames that called
    it left out); the whole traceback where no such frame is found."""
    import traceback

    bench = [str(Path(__file__).resolve().parent.parent / pkg) for pkg in
             ("autopilot", "heli_common", "heli_plant", "heli_sitl", "ground")]  # fmt: skip
    frames = traceback.extract_tb(exc.__traceback__)
    first = next((i for i, f in enumerate(frames) if not any(f.filename.startswith(b) for b in bench)), None)
    if first is None:
        return "".join(traceback.format_exception(exc))
    lines = ["Traceback (most recent call last, the bench's frames above it left out):\n"]
    lines += traceback.format_list(frames[first:])
    lines += traceback.format_exception_only(type(exc), exc)
    return "".join(lines)


def load_class(spec: str) -> type[Any]:
    """The class a ``"module:Class"`` or ``"file.py:Class"`` string (or a registered name)
    names, checked against the contract (``update`` and ``reset``); :class:`ConfigError`
    names what failed."""
    if ":" not in spec and spec in (names := registered()):
        spec = names[spec]
    cls = user_class.load_class(spec, "controller")
    missing = [m for m in ("update", "reset") if not callable(getattr(cls, m, None))]
    if missing:
        raise ConfigError(f"controller {spec!r}: the class lacks {' and '.join(missing)}() (see "
                          f"autopilot.user_controller for the contract)")  # fmt: skip
    return cls


class UserController:
    """A user's controller with the guarantees every controller of the bench has; the same
    surface as :class:`~autopilot.control.KernelController` for the loops that fly it."""

    kind: ClassVar[str] = USER

    def __init__(self, spec: str | type[Any], airframe: Airframe, rate_hz: float, *, strict: bool) -> None:
        cls = load_class(spec) if isinstance(spec, str) else spec
        self.spec = spec if isinstance(spec, str) else f"{cls.__module__}:{cls.__qualname__}"
        self.airframe = airframe
        self.rate_hz = float(rate_hz)
        self.strict = strict
        self.impl = cls(airframe, self.rate_hz)
        self.name = str(getattr(self.impl, "name", cls.__name__))
        self.diag = np.full(N_DIAG, np.nan)  # attitude commands: not known of a user's law
        self.diag[D_SAT_MASK] = 0.0
        self.diag[D_STATUS] = OK
        self._last = np.zeros(N_PITCH)
        self._set_limits(airframe.limits)
        self.errors = 0  # exceptions raised by the user's code (the process flies on)

    @property
    def gains(self) -> UserController:
        """What records name as the gain set: the controller's own name."""
        return self

    def _set_limits(self, limits: PitchLimits) -> None:
        lim = np.array(limits.as_tuple(), dtype=float)
        self._lo, self._hi = lim[:, 0], lim[:, 1]

    def set_limits(self, limits: PitchLimits) -> None:
        self._set_limits(limits)
        hook = getattr(self.impl, "set_limits", None)
        if callable(hook):
            hook(limits)

    def set_gains(self, gains: object) -> None:
        """A user's controller has no gain parameters on the bench's table: nothing to do."""

    def reset(self) -> None:
        self.impl.reset()

    def warm_up(self, x: FloatArray) -> None:
        """Nothing to load ahead: a user's code compiles (if it does) on its own terms."""

    @property
    def status(self) -> int:
        return int(self.diag[D_STATUS])

    def _refuse(self, status: int) -> FloatArray:
        self.diag[D_STATUS] = status
        return self._last.copy()

    def update(
        self, t: float, x: FloatArray, ref: FloatArray, *, hold_integrators: bool = False
    ) -> FloatArray:
        """The user's pitches for state ``x`` and reference ``ref``, clipped to the limits;
        the last valid command where the input or the output is not usable."""
        if x.shape != (N_STATE,) or ref.shape != (N_REF,):
            raise ValueError(f"state must be ({N_STATE},) and reference ({N_REF},)")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(ref[REF_POS]))):
            return self._refuse(BAD_INPUT)
        try:
            raw = self.impl.update(float(t), x.copy(), ref.copy())
            u = np.asarray(raw, dtype=float).reshape(-1)
        except Exception as exc:
            if self.strict:
                raise
            self.errors += 1
            if self.errors == 1:
                log.error("controller %s raised %s: %s (holding the last valid command; logged once)",
                          self.name, type(exc).__name__, exc)  # fmt: skip
            return self._refuse(BAD_OUTPUT)
        if u.shape != (N_PITCH,) or not all(math.isfinite(v) for v in u):
            if self.strict and u.shape != (N_PITCH,):
                raise ValueError(f"controller {self.name}: update returned shape {u.shape}, not ({N_PITCH},)")
            return self._refuse(BAD_OUTPUT)
        clipped = np.clip(u, self._lo, self._hi)
        self.diag[D_SAT_MASK] = float(sum(1 << i for i in range(N_PITCH) if clipped[i] != u[i]))
        self.diag[D_STATUS] = OK
        self._last = clipped
        return np.array(clipped, dtype=float)


__all__ = ["BUILT_IN", "USER", "Controller", "UserController", "is_user_spec", "load_class", "normalise_spec"]
