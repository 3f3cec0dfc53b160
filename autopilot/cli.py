"""heli-autopilot: the autopilot process (see ``heli-autopilot --help``)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("heli-autopilot: not built yet", file=sys.stderr)
    return 2
