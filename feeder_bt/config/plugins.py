"""Leaf classes named in a scenario by import path (``package.module:Class``): the
"at most one small leaf class" a new part may need beyond its YAML."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

from feeder_bt.core.errors import ConfigError


def import_near(mod_name: str, base: Path | None = None) -> ModuleType:
    """Import a scenario's leaf module; a project's own package (``examples.leaves`` next
    to its scenarios) is found from the current folder or the scenario's folder and its
    parent, as a user running ``feeder`` there would expect."""
    try:
        return importlib.import_module(mod_name)
    except ModuleNotFoundError as e:
        if e.name != mod_name.split(".")[0]:
            raise
        dirs = [Path.cwd()] + ([base, base.parent] if base is not None else [])
        added = [str(d.resolve()) for d in dirs if str(d.resolve()) not in sys.path]
        if not added:
            raise
        sys.path.extend(added)
        return importlib.import_module(mod_name)


def load_class(spec: str, base: Path | None = None, must_be: type | None = None) -> type:
    """The class ``package.module:Class`` names; with ``must_be``, only a subclass of it (a
    leaf class that is not one would fail at its first tick, or earlier, with a traceback)."""
    mod_name, _, cls_name = spec.partition(":")
    try:
        cls = getattr(import_near(mod_name, base), cls_name)
    except (ImportError, AttributeError) as e:
        raise ConfigError(f"cannot load leaf class {spec!r}: {e}") from None
    if must_be is not None and not (isinstance(cls, type) and issubclass(cls, must_be)):
        what = "a class" if isinstance(cls, type) else type(cls).__name__
        raise ConfigError(f"{spec!r} is {what}, not a {must_be.__name__} (a leaf class must "
                          f"subclass {must_be.__module__}.{must_be.__name__})")
    return cls
