"""Scenario overlays: a partial scenario merged over a scenario before it is validated.

``feeder run SCENARIO --overlay OVERLAY.yaml`` runs the scenario with the overlay's values
(``feeder tune`` writes its best settings as one). The merge is done on the parsed YAML,
before the loader reads any value, so the loader checks the merged scenario like any other
and a mistake in a value or key the overlay gave is reported at the overlay's file and line.

Merge rules: a mapping in the overlay merges key by key into the scenario's; anything else
(a value, a list) replaces the scenario's. One exception: an ``adjust`` section that names
an ``algorithm`` replaces the scenario's ``adjust.params`` as a whole, because an adjuster's
parameters only mean something to that adjuster.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode

from feeder_bt.core.errors import ConfigError

#: Sections whose ``params`` go with their ``algorithm`` (the overlay's replaces them whole).
_PARAMS_WITH_ALGORITHM = ("adjust",)


def _key(node: Node) -> str | None:
    return node.value if isinstance(node, ScalarNode) else None


def _merge(base: MappingNode, over: MappingNode, path: str, taken: set[str]) -> MappingNode:
    """A new mapping node: ``base`` with ``over``'s entries merged in; ``taken`` collects
    the dotted paths whose value now comes from the overlay."""
    pairs = list(base.value)
    over_keys = {_key(k) for k, _ in over.value}
    if path in _PARAMS_WITH_ALGORITHM and "algorithm" in over_keys:
        pairs = [(k, v) for k, v in pairs if _key(k) != "params"]
    index = {_key(k): i for i, (k, _) in enumerate(pairs) if _key(k) is not None}
    for knode, vnode in over.value:
        key = _key(knode)
        sub = f"{path}.{key}" if path else str(key)
        i = index.get(key) if key is not None else None
        if (i is not None and isinstance(vnode, MappingNode)
                and isinstance(pairs[i][1], MappingNode) and key != "<<"):
            pairs[i] = (pairs[i][0], _merge(pairs[i][1], vnode, sub, taken))
            continue
        taken.add(sub)
        if i is not None:
            pairs[i] = (knode, vnode)
        else:
            index[key] = len(pairs)
            pairs.append((knode, vnode))
    return MappingNode(base.tag, pairs, base.start_mark, base.end_mark, base.flow_style)


def _from_overlay(path: str, taken: set[str]) -> bool:
    """Whether the value at dotted ``path`` (``a.b[2].c``) was given by the overlay."""
    p = path
    while p:
        if p in taken:
            return True
        p = p[: p.rindex("[")] if p.endswith("]") else p.rpartition(".")[0]
    return False


def apply_overlay(root: MappingNode, overlay: str | Path, ctx: Any,
                  compose: Callable[[Path, Any], MappingNode], make_ctx: Callable[[str], Any]
                  ) -> MappingNode:
    """The scenario's root node with the overlay file merged in.

    ``ctx`` is the loader's context for the scenario: its errors about values the overlay
    gave are re-addressed to the overlay's file (their lines already are the overlay's).
    ``compose``/``make_ctx`` are the loader's own file reader, so that a missing file or a
    YAML syntax error in the overlay reads like any other.
    """
    opath = Path(overlay)
    over = compose(opath, make_ctx(str(opath)))
    taken: set[str] = set()
    merged = _merge(root, over, "", taken)
    blame_overlay(ctx, taken, str(opath))
    return merged


def blame_overlay(ctx: Any, taken: set[str], file: str) -> None:
    """A problem at a key the overlay (or world file) gave points at that file and its
    line, not at the file it was laid over: for this load only (the instance's ``error``)."""
    inner = ctx.error

    def error(path: str, what: str, line: int | None = None) -> ConfigError:
        e = inner(path, what, line)
        if not _from_overlay(path, taken):
            return e
        return ConfigError(e.what, file=file, line=e.line, key=e.key)

    ctx.error = error


def write_overlay(path: str | Path, data: dict[str, Any], header: str = "") -> None:
    """Write an overlay mapping as YAML, with ``header`` as comment lines above it."""
    text = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    text += yaml.safe_dump(data, sort_keys=False, default_flow_style=False)
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"cannot write overlay: {e.strerror or e}", file=str(p)) from None
