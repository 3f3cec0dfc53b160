"""ROS 2 message definitions (``.msg`` text) and their CDR layout: the ``ros2msg`` schemas and
``cdr`` payloads of an MCAP file (:mod:`autopilot.mcap_log`).

What it is: :func:`parse` reads ``.msg`` text into fields; :func:`schema_text` joins a root
definition and its dependencies as MCAP's ``ros2msg`` schema encoding wants them (the root's
text, then per dependency a line of 80 ``=`` and ``MSG: pkg/Name``); :func:`encode` writes one
message as a CDR payload (the 4-byte little-endian encapsulation header, then the fields,
each primitive aligned to its size counted from after the header, as ROS 2's XCDR1 does) and
returns, beside the bytes, where every primitive landed (``"transforms[0].rotation.w" ->
(offset in the payload, numpy dtype)``).

How it is used: a message whose strings and sequence lengths do not change from tick to tick
(a frame id, three transforms) has the same size and layout every tick. The writer encodes it
once as a template and then writes a whole flight's varying numbers straight into the
template's offsets with numpy, every tick at once; nothing is encoded per message in Python.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Field", "Offsets", "encode", "parse", "schema_text"]

# the CDR primitives: numpy dtype (little endian) and size, which is also the alignment
PRIMITIVES: dict[str, str] = {
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2",
    "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8",
    "float32": "<f4", "float64": "<f8",
}  # fmt: skip
ENCAPSULATION_CDR_LE = b"\x00\x01\x00\x00"
SEPARATOR = "=" * 80
_FIELD = re.compile(r"^\s*([A-Za-z][\w/]*)(\[(\d*)\])?\s+([a-z][a-z0-9_]*)(\s+.*)?$")
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")

# (offset in the payload, numpy dtype) of each primitive, by its path in the message
Offsets = dict[str, tuple[int, str]]


@dataclass(frozen=True)
class Field:
    """One field of a ``.msg``: ``type`` a primitive, ``string`` or a ``pkg/Name``;
    ``array`` None (one value), -1 (a sequence, ``type[]``) or the fixed length (``type[N]``)."""

    name: str
    type: str
    array: int | None = None


def valid_name(name: str) -> bool:
    """A ROS 2 field name: lower case letters, digits and underscores, a letter first."""
    return bool(_NAME.match(name)) and "__" not in name and not name.endswith("_")


@functools.cache
def parse(text: str) -> tuple[Field, ...]:
    """The fields of one ``.msg`` text (comments, blank lines and constants skipped)."""
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue  # a comment, a blank line or a constant (uint8 KNOWN=3)
        m = _FIELD.match(line)
        if m is None:
            raise ValueError(f"not a .msg field: {raw!r}")
        typ, arr, n, name = m.group(1), m.group(2), m.group(3), m.group(4)
        fields.append(Field(name, typ, None if arr is None else (int(n) if n else -1)))
    return tuple(fields)


def schema_text(root: str, texts: Mapping[str, str]) -> str:
    """MCAP's ``ros2msg`` schema for ``root`` (a key of ``texts``, ``pkg/Name``): its text, then
    each definition it uses, directly or not, once, in the order first met."""
    order: list[str] = []

    def visit(name: str) -> None:
        for f in parse(texts[name]):
            if f.type in texts and f.type not in order and f.type != root:
                order.append(f.type)
                visit(f.type)

    visit(root)
    parts = [texts[root].strip()]
    parts += [f"{SEPARATOR}\nMSG: {dep}\n{texts[dep].strip()}" for dep in order]
    return "\n".join(parts) + "\n"


class _Out:
    def __init__(self) -> None:
        self.buf = bytearray(ENCAPSULATION_CDR_LE)
        self.offsets: Offsets = {}

    def align(self, size: int) -> None:
        self.buf += b"\x00" * (-(len(self.buf) - len(ENCAPSULATION_CDR_LE)) % size)

    def prim(self, path: str, dtype: str, value: Any) -> None:
        dt = np.dtype(dtype)
        self.align(dt.itemsize)
        self.offsets[path] = (len(self.buf), dtype)
        self.buf += np.array(value, dtype=dt).tobytes()

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += int(v).to_bytes(4, "little")


def encode(texts: Mapping[str, str], root: str, value: Mapping[str, Any]) -> tuple[bytes, Offsets]:
    """``value`` (nested dicts and lists by field name; a missing field is zero, empty or
    empty-string; a sequence of numbers or of one-primitive messages may be a numpy array, a
    row per element) as a CDR payload of ``root``, and where each primitive of it lies
    (the elements of sequences longer than one excepted)."""
    out = _Out()
    defs = {k: parse(v) for k, v in texts.items()}

    def one(path: str, typ: str, v: Any) -> None:
        if typ in PRIMITIVES:
            out.prim(path, PRIMITIVES[typ], 0 if v is None else v)
        elif typ == "string":
            data = ("" if v is None else str(v)).encode() + b"\x00"
            out.u32(len(data))
            out.buf += data
        else:
            message(path + ".", typ, v or {})

    def _flat(typ: str) -> tuple[str, tuple[str, ...]] | None:
        """(dtype, field names) when ``typ`` is one primitive or a message of one primitive only."""
        if typ in PRIMITIVES:
            return PRIMITIVES[typ], ()
        fields = defs.get(typ, ())
        kinds = {PRIMITIVES.get(f.type) if f.array is None else None for f in fields}
        if len(kinds) == 1 and None not in kinds:
            return kinds.pop() or "", tuple(f.name for f in fields)
        return None

    def message(prefix: str, typ: str, v: Mapping[str, Any]) -> None:
        for f in defs[typ]:
            item = v.get(f.name)
            path = prefix + f.name
            if f.array is None:
                one(path, f.type, item)
                continue
            flat = _flat(f.type)
            if flat is not None and isinstance(item, np.ndarray):
                # numbers (or points, one per row) already in an array: packed as they are
                if f.array == -1:
                    out.u32(item.shape[0])
                elif item.shape[0] != f.array:
                    raise ValueError(f"{path}: {item.shape[0]} values for {f.type}[{f.array}]")
                out.align(np.dtype(flat[0]).itemsize)
                out.buf += np.ascontiguousarray(item, dtype=flat[0]).tobytes()
                continue
            items = list(item) if item is not None else []
            if f.array == -1:
                out.u32(len(items))
            elif len(items) != f.array:
                items = items or [None] * f.array
                if len(items) != f.array:
                    raise ValueError(f"{path}: {len(items)} values for {f.type}[{f.array}]")
            if flat is not None and len(items) > 1:
                # a long sequence of numbers or of points (a path): packed at once, its elements'
                # offsets not listed (a sequence's length changes the layout: no template field)
                dtype, names = flat
                out.align(np.dtype(dtype).itemsize)
                rows = [[0 if x is None else x] if not names else [(x or {}).get(k, 0) for k in names]
                        for x in items]  # fmt: skip
                out.buf += np.array(rows, dtype=dtype).tobytes()
                continue
            for i, x in enumerate(items):
                one(f"{path}[{i}]", f.type, x)

    message("", root, value)
    return bytes(out.buf), out.offsets
