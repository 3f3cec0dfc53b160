"""The names ``--controller`` takes, importable without the controllers themselves (a
command's parser is built by every process, the plant's too, which flies no controller)."""

from __future__ import annotations

BUILT_IN = ("tlc", "pid")
CONTROLLER_HELP = ("tlc (the paper's TLC), pid (the cascaded PID baseline, configs/gains_pid.toml), "
                   "or your own class as package.module:Class or path/to/file.py:Class "
                   "(docs/controllers.md)")  # fmt: skip
