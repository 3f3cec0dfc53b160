"""Counter-based Gaussian noise: ``normal(seed, stream, k)`` is a pure function of three integers.

Why counter-based rather than a generator object: a compiled plant step must be repeatable
from the run's seed alone, in any process, whatever the order in which the random processes
are advanced, and with no hidden global state (numba's ``np.random`` state is per thread
and not shared with numpy's). Hashing ``(seed, stream, k)`` gives the k-th deviate of one
process directly, so skipping, replaying or adding a process never shifts another one.

The hash is SplitMix64 (Steele, Lea & Flood 2014, finaliser variant 13 of Stafford): the
seed, then the stream, then the counter are folded in through the bijective 64-bit mixer,
and the next two SplitMix64 outputs from that key give two uniforms in (0, 1), turned into
two independent N(0, 1) deviates by Box-Muller. Compiled, the arithmetic is on uint64 and
wraps; under ``NUMBA_DISABLE_JIT=1`` the same code runs on Python ints, masked to 64 bits,
so both give bit-identical integers (and the same floats, from the same libm).

Stream ids name the random processes; each process owns one id and counts its own ``k``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba.extending import overload

from heli_common.jit import njit

# --- stream ids: one per random process -------------------------------------------------
STREAM_TURB_U = 1  # Dryden longitudinal (along the mean wind)
STREAM_TURB_V = 2  # Dryden lateral
STREAM_TURB_W = 3  # Dryden vertical
STREAM_TURB_INIT = 4  # stationary initial state of the Dryden filters
STREAM_GUST = 5  # reserved: randomised discrete gusts
# 6-15 reserved for further world processes (air, servos); sensors start at 16.
STREAM_SENSOR_BASE = 16

MASK64 = 0xFFFFFFFFFFFFFFFF
_GOLDEN = 0x9E3779B97F4A7C15  # 2^64 / golden ratio, the SplitMix64 increment
_GOLDEN2 = (2 * _GOLDEN) & MASK64
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB
_TWO_PI = 2.0 * math.pi
_INV_2_52 = 1.0 / 4503599627370496.0  # 2^-52


def _u64(x: int) -> int:
    """The 64-bit two's-complement pattern of ``x`` (plain Python: a non-negative int)."""
    return x & MASK64


def _u64_compiled(x: Any) -> Callable[[Any], Any]:
    """In compiled code an int64 becomes uint64 by reinterpretation (same bits)."""

    def impl(x: Any) -> Any:
        return np.uint64(x)

    return impl


# numba would type ``int64 & <uint64 literal>`` as int64 and ``uint64 + int64`` as float64,
# either of which breaks the wrap-around; every integer (constants too) therefore enters the
# arithmetic through _u64, which compiled code implements as a cast to uint64 (plain Python
# keeps the masking one above).
overload(_u64)(_u64_compiled)


@njit
def _mix64(z: int) -> int:
    """SplitMix64 finaliser: a bijection of 64-bit words with full avalanche."""
    z = _u64(z)
    z = ((z ^ (z >> 30)) * _u64(_MIX1)) & MASK64
    z = ((z ^ (z >> 27)) * _u64(_MIX2)) & MASK64
    return z ^ (z >> 31)


@njit
def _key(seed: int, stream: int, k: int) -> int:
    """Fold seed, stream and counter into one 64-bit key (each step a bijection of the key)."""
    g = _u64(_GOLDEN)
    h = _mix64((_u64(seed) + g) & MASK64)
    h = _mix64(((h ^ _u64(stream)) + g) & MASK64)
    return _mix64(((h ^ _u64(k)) + g) & MASK64)


@njit
def _unit_open(z: int) -> float:
    """Top 52 bits of a word as a uniform on the open interval (0, 1), exact in float64."""
    return ((_u64(z) >> 12) + 0.5) * _INV_2_52


@njit
def normal_pair(seed: int, stream: int, k: int) -> tuple[float, float]:
    """Two independent N(0, 1) deviates for counter ``k`` of ``stream`` (Box-Muller)."""
    h = _key(seed, stream, k)
    u1 = _unit_open(_mix64((h + _u64(_GOLDEN)) & MASK64))
    u2 = _unit_open(_mix64((h + _u64(_GOLDEN2)) & MASK64))
    r = math.sqrt(-2.0 * math.log(u1))
    return r * math.cos(_TWO_PI * u2), r * math.sin(_TWO_PI * u2)


@njit
def normal(seed: int, stream: int, k: int) -> float:
    """The standard normal deviate number ``k`` of ``stream`` under ``seed`` (first of the pair)."""
    return normal_pair(seed, stream, k)[0]
