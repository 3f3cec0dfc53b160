"""heli-ground: the ground-station script (see ``heli-ground --help``)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("heli-ground: not built yet", file=sys.stderr)
    return 2
