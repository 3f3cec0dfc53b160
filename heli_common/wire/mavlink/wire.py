"""Values as MAVLink carries them: float32 rounding, parameter encodings, signing keys.

One place for what both ends of a link must agree on (the vehicle's parameter table and
mission store, and the ground client), so the two can never drift apart.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import development as mavlink

PARAM_INT32: int = mavlink.MAV_PARAM_TYPE_INT32
PARAM_REAL32: int = mavlink.MAV_PARAM_TYPE_REAL32


class SigningKeyError(ValueError):
    """A signing key file that is missing or not 32 bytes / 64 hex digits."""


def f32(value: float) -> float:
    """The float32 the wire will carry (inf for what overflows float32)."""
    with np.errstate(over="ignore"):
        return float(np.float32(value))


def f32_text(value: float) -> str:
    """The shortest decimal that reads back to the same float32 (``0.707`` where
    ``%.9g`` prints ``0.707000017``): what a float32 on the wire was meant to say."""
    if math.isnan(value):
        return "nan"
    return str(np.format_float_positional(np.float32(value), unique=True, trim="-"))


def encode_param(value: float, param_type: int, bytewise: bool) -> float:
    """The float ``param_value`` that carries ``value`` of ``param_type``.

    Byte-wise: an INT32's bytes reinterpreted as a float32. C-cast: the integer's value
    converted to float (exact up to 2**24). REAL32 is itself either way."""
    if param_type == PARAM_INT32:
        if not (math.isfinite(value) and float(value).is_integer()):
            raise ValueError(f"{value} is not an integer")
        if bytewise:
            return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
        return float(int(value))
    return float(value)


def decode_param(param_value: float, param_type: int, bytewise: bool) -> float:
    """The number a received ``param_value`` of ``param_type`` stands for."""
    if param_type == PARAM_INT32 and bytewise:
        return float(struct.unpack("<i", struct.pack("<f", param_value))[0])
    return float(param_value)


def read_signing_key(path: Path | str) -> bytes:
    """A MAVLink 2 signing key file: 32 raw bytes, or 64 hex digits (whitespace ignored)."""
    try:
        raw = Path(path).read_bytes().strip()
    except OSError as exc:
        raise SigningKeyError(f"{path}: signing key: {exc.strerror or exc}") from exc
    if len(raw) == 64:
        try:
            return bytes.fromhex(raw.decode("ascii"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise SigningKeyError(f"{path}: signing key: not 64 hex digits") from exc
    if len(raw) != 32:
        raise SigningKeyError(
            f"{path}: signing key: expected 32 bytes or 64 hex digits, got {len(raw)} bytes"
        )
    return raw
