"""Where a gain set is designed to fly: the plant and the servos its stability claim is for.

Every shipped gain file names its design point in a ``[design]`` table; at that point the
whole closed loop, linearised about hover (``heli-sitl margins``, heli_sitl/engine/loop_linear.py),
must be stable with a balanced disk margin of at least :data:`MIN_DISK_MARGIN` at every loop
break point (tests/test_loop_linear.py checks each file). Elsewhere a set may fly, but its
header says what the margins are there, and nothing is claimed.
"""

from __future__ import annotations

from dataclasses import dataclass

from heli_common.config import spec

#: the robustness every shipped gain set proves at its design point: +/- 6 dB, +/- 36 deg
MIN_DISK_MARGIN = 0.66


@dataclass(frozen=True)
class DesignPoint:
    plant: str = spec(default="paper")  # a plant preset (configs/plant/) or a path
    servos: str = spec(default="ideal")  # a world preset whose servos ("ideal": none)
