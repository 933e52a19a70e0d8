"""Leaf classes named in a scenario by import path (``package.module:Class``): the
"at most one small leaf class" a new part may need beyond its YAML."""

from __future__ import annotations

import importlib

from ..errors import ConfigError


def load_class(spec: str) -> type:
    mod_name, _, cls_name = spec.partition(":")
    try:
        return getattr(importlib.import_module(mod_name), cls_name)
    except (ImportError, AttributeError) as e:
        raise ConfigError(f"cannot load leaf class {spec!r}: {e}") from None
