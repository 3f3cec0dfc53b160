"""A class named by a string, from the user's own code: ``"package.module:Class"``,
``"path/to/file.py:Class"`` or a name an installed package registers in an entry point group.

One loader for every role the bench lets a user fill (a controller, a plant), so that one
class loads the same way in-process, in the bench's processes and on campaign workers.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from typing import Any

from heli_common.config import ConfigError


def registered(group: str, reserved: tuple[str, ...] = ()) -> dict[str, str]:
    """The names installed packages register in the entry point ``group``, name ->
    ``"module:Class"`` (read each time: a test or a session may install one); a ``reserved``
    (built-in) name is never shadowed."""
    from importlib.metadata import entry_points

    return {ep.name: ep.value for ep in entry_points(group=group) if ep.name not in reserved}


def is_class_spec(spec: str) -> bool:
    """``"module:Class"`` or ``"file.py:Class"`` (not a bare name)."""
    return ":" in spec


def absolute_spec(spec: str) -> str:
    """``"file.py:Class"`` with the file made absolute (another process or directory loads the
    same file); anything else unchanged."""
    where, _, cls = spec.rpartition(":")
    return f"{Path(where).resolve()}:{cls}" if where.endswith(".py") else spec


def load_class(spec: str, what: str) -> type[Any]:
    """The class ``"module:Class"`` or ``"file.py:Class"`` names (``what`` names the role in
    errors: "controller", "plant"); :class:`ConfigError` names what failed."""
    where, _, name = spec.rpartition(":")
    if not where or not name:
        raise ConfigError(f"{what}: expected 'module:Class' or 'file.py:Class', got {spec!r}")
    try:
        module = _import(where, what)
    except ConfigError:
        raise
    except Exception as exc:  # the user's module raised on import: say so, with its own words
        raise ConfigError(f"{what} {spec!r}: importing {where} raised {type(exc).__name__}: {exc}") from exc
    cls = getattr(module, name, None)
    if not isinstance(cls, type):
        raise ConfigError(f"{what} {spec!r}: {where} has no class {name!r}")
    return cls


def _import(where: str, what: str) -> Any:
    if where.endswith(".py"):
        path = Path(where).resolve()
        if not path.is_file():
            raise ConfigError(f"{what}: no file {path}")
        mod_name = f"heli_user_{what}_{abs(hash(str(path)))}"
        if mod_name in sys.modules:
            return sys.modules[mod_name]
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:
            raise ConfigError(f"{what}: cannot load {path} as a module")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module  # before exec: dataclasses and pickling look it up
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[mod_name]
            raise
        return module
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as exc:
        if exc.name != where.split(".")[0] or str(Path.cwd()) in sys.path:
            raise ConfigError(f"{what}: cannot import {where}: {exc}") from exc
    # a console script's path starts at its own directory, not the working one, where a
    # user's package usually sits: look there too, as `python -m` would
    sys.path.insert(0, str(Path.cwd()))
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as exc:
        raise ConfigError(f"{what}: cannot import {where}: {exc}") from exc
