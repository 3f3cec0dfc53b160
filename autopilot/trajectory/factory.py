"""Build a trajectory from a ``[trajectory]`` TOML table: ``kind`` picks the class.

``kind = "csv"`` is the one kind read from a file rather than built from the table's keys:
``path`` names a table of samples (:mod:`autopilot.trajectory.csv_table`), relative to the
directory of the file the table is in, as a scenario's airframe and gains are.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from autopilot.trajectory.analytic import PaperSpiralCircle, StraightLine
from autopilot.trajectory.base import Trajectory
from autopilot.trajectory.csv_table import trajectory_from_csv
from autopilot.trajectory.manoeuvres import ArcTurn, FigureEight, PositionStep
from heli_common.config import ConfigError, build

KINDS: dict[str, type[Trajectory]] = {
    "paper_spiral_circle": PaperSpiralCircle,
    "straight_line": StraightLine,
    "figure_eight": FigureEight,
    "arc_turn": ArcTurn,
    "position_step": PositionStep,
}
CSV_KIND = "csv"  # the table's only other key: path


def trajectory_from_table(table: Mapping[str, Any], source: str, base_dir: Path | None = None) -> Trajectory:
    """``source`` (the file the table is in) prefixes every error; ``base_dir`` (default: the
    directory of ``source``) is where a csv kind's relative ``path`` starts."""
    kind = table.get("kind")
    if kind == CSV_KIND:
        return _csv_from_table(table, source, Path(source).parent if base_dir is None else base_dir)
    if kind not in KINDS:
        # csv apart: it takes a file, not the parameters the others take
        raise ConfigError(
            f"{source}: trajectory.kind: expected one of {', '.join(KINDS)}, got {kind!r} "
            f'(or "{CSV_KIND}", samples from a file: kind = "{CSV_KIND}" with path = "table.csv")'
        )
    rest = {k: v for k, v in table.items() if k != "kind"}
    return build(KINDS[kind], rest, f"{source}: trajectory")


def _csv_from_table(table: Mapping[str, Any], source: str, base_dir: Path) -> Trajectory:
    extra = sorted(set(table) - {"kind", "path"})
    if extra:
        raise ConfigError(
            f"{source}: trajectory: unknown key(s) {extra} for kind = {CSV_KIND!r}; expected path"
        )
    path = table.get("path")
    if not isinstance(path, str) or not path:
        raise ConfigError(f"{source}: trajectory.path: expected the table's file name, got {path!r}")
    p = base_dir / path  # an absolute path stays as it is
    if not p.is_file():
        raise ConfigError(
            f"{source}: trajectory.path: {p}: no such file ({path!r} is taken from {base_dir}, "
            "the directory of the file that names it)"
        )
    try:
        return trajectory_from_csv(p)
    except ConfigError as exc:  # the table's own error (file, line, row), named by this file
        raise ConfigError(f"{source}: trajectory.path: {exc}") from exc
