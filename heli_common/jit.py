"""A typed wrapper around numba's njit, with a cache that cannot go stale.

The plant and the control law are scalar numerics called thousands of times a second;
numba compiles them once and caches the machine code on disk so a tick costs
microseconds. numba's cache only checks the source file of the function itself, not of
the functions it inlines from other modules, so an edit to, say, the differentiator
would leave the controller kernel running old code. The cache directory is therefore
keyed on a hash of every module that holds compiled code. ``NUMBA_DISABLE_JIT=1`` runs
the same code as plain Python for debugging; ``NUMBA_CACHE_DIR`` overrides the location.

``@njit(parallel=True)`` compiles a kernel whose :data:`prange` loops run on numba's thread
pool (cached as well); :func:`max_threads` is how many threads it may use, and
:func:`set_threads` how many the calling thread's parallel kernels use.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast, overload

import numba

F = TypeVar("F", bound=Callable[..., Any])

_ROOT = Path(__file__).resolve().parent.parent
_JIT_PACKAGES = ("heli_common", "heli_plant", "heli_sitl", "autopilot")


def _source_hash() -> str:
    """Hash of every module that holds compiled code (those that use ``@njit``)."""
    h = hashlib.sha256(numba.__version__.encode())
    for pkg in _JIT_PACKAGES:
        for f in sorted((_ROOT / pkg).rglob("*.py")):
            text = f.read_bytes()
            # the constants' layout, and this module's compile options
            if b"@njit" in text or f.name in ("airframe.py", "jit.py"):
                h.update(str(f.relative_to(_ROOT)).encode())
                h.update(text)
    return h.hexdigest()[:16]


if not os.environ.get("NUMBA_CACHE_DIR"):
    _base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    setattr(numba.config, "CACHE_DIR", str(_base / "heli-tlc-sitl" / f"numba-{_source_hash()}"))  # noqa: B010


# numba's OpenMP pool (its threading layer here) waits for the next parallel call in one of
# three ways. Left to itself (GOMP_SPINCOUNT 300,000), a worker spins milliseconds after each
# call: where the cores are shared it takes the core the calling thread needs (two threads
# stepping 256 vehicles used 4 times the CPU of one and ran 4 times slower). Passive (0), it
# sleeps at once, and waking it costs each call ~70 us on this kind of virtual machine (a
# call of 11 us of work a thread: 80 us passive, 13 us spinning): a 256-vehicle step of the Gymnasium
# env took 465 us, 79 % of the cores' pace. A spin of 10,000 (~0.1-0.3 ms here) bridges the
# Python between two steps and then sleeps: 344 us (110 %); beside two busy processes 302,000
# env-steps/s against passive's 198,000 and one thread's 225,000 (CPU a step +10 %).
# Read when the OpenMP library loads (at the first parallel call); the user's own setting of
# either variable wins.
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "10000")


@overload
def njit(fn: F, /) -> F: ...


@overload
def njit(*, parallel: bool = False) -> Callable[[F], F]: ...


def njit(fn: F | None = None, /, *, parallel: bool = False) -> F | Callable[[F], F]:
    """Compile ``fn`` in nopython mode, cached, keeping its static signature for mypy
    (``@njit``, or ``@njit(parallel=True)`` for a kernel with :data:`prange` loops: their
    iterations run on numba's threads, so they must not write what another iteration reads).

    numpy's error model: a float division by zero gives inf or NaN, as in numpy, instead of
    a branch to raise ZeroDivisionError at every division (the kernels divide in their
    inner loops; the control law and the estimator refuse non-finite results themselves).
    The same bits wherever no division by zero happens."""

    def compile_(f: F) -> F:
        return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy", parallel=parallel)(f))

    return compile_(fn) if fn is not None else compile_


# a loop over independent iterations, run on numba's threads in a parallel kernel (range elsewhere)
prange: Callable[..., range] = numba.prange


def max_threads() -> int:
    """The threads a parallel kernel may use: the cores this process may run on (its CPU
    affinity), at most numba's thread pool (NUMBA_NUM_THREADS)."""
    return max(1, min(len(os.sched_getaffinity(0)), int(numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]


def set_threads(n: int) -> int:
    """The parallel kernels called from this thread use ``n`` threads (1 to
    ``numba.config.NUMBA_NUM_THREADS``); returns the number they used before."""
    before = int(numba.get_num_threads())
    if n != before:
        numba.set_num_threads(n)
    return before
