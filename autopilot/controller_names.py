"""The names ``--controller`` takes, importable without the controllers themselves (a
command's parser is built by every process, the plant's too, which flies no controller).

One registry: the built-in compiled controllers by name, and every other package's
controllers by name through the entry point group :data:`ENTRY_POINT_GROUP` (in its
``pyproject.toml``: ``[project.entry-points."heli_tlc_sitl.controllers"]`` then
``my-law = "my_package.laws:MyLaw"``), beside the ``module:Class`` and ``file.py:Class``
strings (autopilot.user_controller has the contract a class keeps).
"""

from __future__ import annotations

BUILT_IN = ("tlc", "pid")
ENTRY_POINT_GROUP = "heli_tlc_sitl.controllers"
CONTROLLER_HELP = ("tlc (the paper's TLC), pid (the cascaded PID baseline, configs/gains_pid.toml), "
                   f"a controller another package registers by name (entry point group {ENTRY_POINT_GROUP}), "
                   "or your own class as package.module:Class or path/to/file.py:Class "
                   "(docs/controllers.md)")  # fmt: skip


def registered() -> dict[str, str]:
    """The controllers installed packages register, name -> ``"module:Class"`` (read from the
    entry points each time: a test or a session may install one; a built-in name is never
    shadowed)."""
    from heli_common.user_class import registered as in_group

    return in_group(ENTRY_POINT_GROUP, BUILT_IN)
