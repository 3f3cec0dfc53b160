"""A typed wrapper around numba's njit, with a cache that cannot go stale.

The plant and the control law are scalar numerics called thousands of times a second;
numba compiles them once and caches the machine code on disk so a tick costs
microseconds. numba's cache only checks the source file of the function itself, not of
the functions it inlines from other modules, so an edit to, say, the differentiator
would leave the controller kernel running old code. The cache directory is therefore
keyed on a hash of every module that holds compiled code. ``NUMBA_DISABLE_JIT=1`` runs
the same code as plain Python for debugging; ``NUMBA_CACHE_DIR`` overrides the location.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

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


def njit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached, keeping its static signature for mypy.

    numpy's error model: a float division by zero gives inf or NaN, as in numpy, instead of
    a branch to raise ZeroDivisionError at every division (the kernels divide in their
    inner loops; the control law and the estimator refuse non-finite results themselves).
    The same bits wherever no division by zero happens."""
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy")(fn))
