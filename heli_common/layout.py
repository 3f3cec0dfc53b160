"""Flat array layouts declared once: named blocks, their offsets and sizes generated.

The compiled code works on flat float64 arrays; a layout names each block once, in order,
and the offsets follow, so no module numbers an array by hand::

    ROTOR = Layout("rotor", ("a1_rad", 1), ("b1_rad", 1), ("omega_rad_s", 1))
    A1 = ROTOR.offset("a1_rad")           # 0
    N_ROTOR = ROTOR.size                   # 3
"""

from __future__ import annotations


class Layout:
    """Named, contiguous blocks of a flat array (name, size), in declaration order."""

    def __init__(self, name: str, *blocks: tuple[str, int], start: int = 0) -> None:
        self.name = name
        self._offsets: dict[str, int] = {}
        self._sizes: dict[str, int] = {}
        at = start
        for block, size in blocks:
            if block in self._offsets:
                raise ValueError(f"layout {name}: block {block!r} declared twice")
            if size < 1:
                raise ValueError(f"layout {name}: block {block!r} needs a size >= 1, got {size}")
            self._offsets[block] = at
            self._sizes[block] = size
            at += size
        self.start = start
        self.end = at

    @property
    def size(self) -> int:
        return self.end - self.start

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._offsets)

    def offset(self, block: str) -> int:
        try:
            return self._offsets[block]
        except KeyError:
            have = ", ".join(self._offsets)
            raise KeyError(f"layout {self.name}: no block {block!r}; it has {have}") from None

    def size_of(self, block: str) -> int:
        self.offset(block)
        return self._sizes[block]
