"""``scenarios/lense.yaml: file not found (did you mean scenarios/lenses.yaml?)``: the
nearest existing name beside a path that is not there, for the one-line errors."""

from __future__ import annotations

import difflib
from pathlib import Path


def nearest(path: str | Path) -> str | None:
    """The existing file or folder whose name is closest to ``path``'s (in its folder, or
    with the folder itself mended), written as ``path`` was; None if none is close."""
    p = Path(path)
    parent = p.parent
    if not parent.is_dir():                  # a mistyped folder: mend it first
        fixed = nearest(parent) if str(parent) not in ("", ".") else None
        if fixed is None:
            return None
        parent = Path(fixed)
        if (parent / p.name).exists():
            return str(parent / p.name)
    try:
        names = sorted(c.name for c in parent.iterdir())
    except OSError:
        return None
    close = difflib.get_close_matches(p.name, names, n=1, cutoff=0.8)   # a typo, not a guess
    if not close:
        return None
    return str(parent / close[0]) if str(parent) != "." or str(p.parent) != "." else close[0]


def hint(path: str | Path) -> str:
    """`` (did you mean X?)`` for a missing ``path``, or nothing."""
    near = nearest(path)
    return f" (did you mean {near}?)" if near else ""
