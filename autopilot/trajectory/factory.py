"""Build a trajectory from a ``[trajectory]`` TOML table: ``kind`` picks the class."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from autopilot.trajectory.analytic import PaperSpiralCircle, StraightLine
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.manoeuvres import ArcTurn, FigureEight, PositionStep
from heli_common.config import ConfigError, build

KINDS: dict[str, type[Trajectory]] = {
    "paper_spiral_circle": PaperSpiralCircle,
    "straight_line": StraightLine,
    "figure_eight": FigureEight,
    "arc_turn": ArcTurn,
    "position_step": PositionStep,
}


def trajectory_from_table(table: Mapping[str, Any], source: str) -> Trajectory:
    kind = table.get("kind")
    if kind not in KINDS:
        raise ConfigError(
            f"{source}: trajectory.kind: expected one of {', '.join(KINDS)}, got {kind!r}"
        )
    rest = {k: v for k, v in table.items() if k != "kind"}
    return build(KINDS[kind], rest, f"{source}: trajectory")
