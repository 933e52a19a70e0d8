"""The generic YAML walker: a file read as *nodes* (``yaml.compose``), never as plain
Python data, so that every problem is one line ``FILE:LINE: dotted.key: what is wrong``.

The mapping from YAML to the model follows the dataclass fields and type hints of
``model.py``, so a new field with a default there is a new optional YAML key here. The few
places where the YAML is not a mirror of the model register their builders in
``_SPECIAL_TYPES`` and ``_FIELD_BUILDERS`` (``special.py``).

Every key of a mapping and every item of a list is walked even after one fails: each
problem is noted in ``_Ctx.problems`` and the value that holds a broken key is itself
broken (it raises the first of its problems), while an unknown key is listed and leaves
the rest whole. The loader raises them all at once (``_Ctx.raise_problems``).
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import types
import typing
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from feeder_bt.config.plugins import import_near
from feeder_bt.config.tables import (
    _EXTRA_KEYS,
    _IMPLIED_FIELDS,
    ENUMS,
    LEAF_RE,
    RANGES,
    _num,
)
from feeder_bt.core.errors import ConfigError

# ============================================================================ helpers


def _one_line(s: str) -> str:
    return " ".join(str(s).split())


def _short(v: Any, limit: int = 40) -> str:
    r = repr(v)
    return r if len(r) <= limit else r[: limit - 3] + "..."


def _describe(v: Any) -> str:
    """How a wrong value is named in a message: its YAML kind and the value."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    if isinstance(v, int):
        return f"integer {_short(v)}"
    if isinstance(v, float):
        return f"number {_num(v)}"
    if isinstance(v, str):
        return f"string {_short(v)}"
    if isinstance(v, MappingNode):
        return "a mapping"
    if isinstance(v, SequenceNode):
        return "a list"
    return f"{type(v).__name__} {_short(v)}"


def _suggest(word: str, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _parent(path: str) -> str:
    if path.endswith("]"):
        return path[: path.rindex("[")]
    return path.rpartition(".")[0]


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _required(f: dataclasses.Field) -> bool:
    return f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING


def _optional_of(tp: Any) -> tuple[bool, Any]:
    """(accepts None, the type without None) for ``X | None``; (False, tp) otherwise."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return len(args) < len(typing.get_args(tp)), args[0]
        raise TypeError(f"unsupported union in model: {tp}")
    return False, tp


# ============================================================================ the walker


def _scalar_with_default(f: dataclasses.Field, tp: Any) -> bool:
    """A field of one number, word or flag that the dataclass can fill by itself."""
    has_default = (f.default is not dataclasses.MISSING
                   or f.default_factory is not dataclasses.MISSING)
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    return has_default and (tp in (int, float, str, bool) or (len(args) == 1 and args[0] in (
        int, float, str, bool)))


class _Gather:
    """Runs independent steps (the keys of a mapping, the items of a list): each failure is
    noted in the file's problems and the next step still runs; ``done`` then raises the
    first failure, so the enclosing value is known to be broken."""

    def __init__(self, ctx: _Ctx, node: Node | None = None) -> None:
        self.ctx = ctx
        # a duplicate or unreadable key of the mapping walked: an entry was left out, so
        # what is built from the rest is not what the file says
        self.failed: ConfigError | None = ctx.bad_keys.get(id(node))

    @contextmanager
    def step(self, breaks: bool = True) -> Iterator[None]:
        """``breaks=False``: a failure is listed but leaves the enclosing value whole."""
        try:
            yield
        except ConfigError as e:
            self.ctx.note(e)
            if breaks and self.failed is None:
                self.failed = e

    def fail(self, e: ConfigError) -> None:
        """A failure found without raising (a missing key)."""
        self.ctx.note(e)
        self.failed = self.failed or e

    def done(self) -> None:
        if self.failed is not None:
            raise self.failed


class _Ctx:
    """One file being read: its name for messages, the line of every dotted key, and every
    problem found so far (``problems``; ``raise_problems`` reports them all at once)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.lines: dict[str, int] = {}       # path -> line of the value (scalar/flow) or key
        self.key_lines: dict[str, int] = {}   # path -> line of the key itself
        self.nodes: dict[str, Node] = {}      # path -> value node
        self.adjust_params: dict[str, float] = {}   # effective adjuster parameters
        self._entries: dict[int, list[tuple[str, Node, Node]]] = {}
        self._constructor = yaml.constructor.SafeConstructor()
        self.problems: list[ConfigError] = []   # every problem found, each noted once
        self._noted: set[int] = set()
        # sections in which a bad value was replaced by its default to go on checking: a
        # check across that section's keys would judge the default, not the file
        self.stood_in: set[str] = set()
        self._own: set[int] = set()
        # dotted key -> the unknown-key error that suggested it ("did you mean"): that
        # key's "missing" is the same mistake, not a second one
        self.suggested: dict[str, ConfigError] = {}
        self.bad_keys: dict[int, ConfigError] = {}   # mapping node -> its first bad key

    # ---------------------------------------------------------------- errors and lines

    def error(self, path: str, what: str, line: int | None = None) -> ConfigError:
        if line is None:
            line = self.line(path)
        return ConfigError(_one_line(what), file=self.file, line=line, key=path or None)

    def note(self, e: ConfigError, own: bool = False) -> ConfigError:
        """List a problem (once: an error re-raised up through the walk is the same one).
        A problem in a section where a default stood in for a bad value is left out unless
        it is a key's ``own`` mistake: a check across the section would judge the default."""
        if own:
            self._own.add(id(e))
        elif id(e) not in self._own and self._judges_a_default(e.key or ""):
            return e
        if id(e) not in self._noted:
            self._noted.add(id(e))
            self.problems.append(e)
        return e

    def add_problem(self, path: str, what: str, line: int | None = None) -> None:
        """List a problem and go on checking (``raise self.error(...)`` stops instead)."""
        self.note(self.error(path, what, line=line))

    def _judges_a_default(self, path: str) -> bool:
        """Is ``path`` in a section where a bad value stood in by its default?"""
        return any(path == s or path.startswith(s + ".") or path.startswith(s + "[")
                   for s in self.stood_in)

    @contextmanager
    def standing_in(self, path: str | None) -> Iterator[None]:
        """A failure of ``path`` below is its own mistake, listed, and the field's default
        stands in: the section holding it (the key alone at the file's top) is then not
        judged across keys."""
        try:
            yield
        except ConfigError as e:
            if path is not None:
                self._own.add(id(e))
                self.stood_in.add(_parent(path) or path)
            raise

    def gather(self, node: Node | None = None) -> _Gather:
        """Steps over the entries of ``node`` (a mapping whose bad keys break it too)."""
        return _Gather(self, node)

    def collect(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """``fn(*args)``, or None when it raised a ConfigError (then listed)."""
        try:
            return fn(*args, **kwargs)
        except ConfigError as e:
            self.note(e)
            return None

    def raise_problems(self, more: Iterable[ConfigError] = ()) -> None:
        """Raise every problem of this file (in file order), then ``more`` (another file's,
        such as a scenario's cell), as one error; nothing when there is none."""
        seen: set[str] = set()
        mine = []
        for e in sorted(self.problems, key=lambda e: e.line or 0):
            if str(e) not in seen:            # the same words on the same line: once
                seen.add(str(e))
                mine.append(e)
        problems = mine + list(more)
        if problems:
            raise ConfigError.of(problems)

    def line(self, path: str) -> int | None:
        """The line of ``path``, or of its nearest ancestor that was written in the file."""
        p = path
        while p:
            if p in self.lines:
                return self.lines[p]
            p = _parent(p)
        return self.lines.get("", 1)

    def _record(self, path: str, value: Node, key: Node | None = None) -> None:
        flow = isinstance(value, ScalarNode) or getattr(value, "flow_style", False)
        vline = value.start_mark.line + 1
        kline = key.start_mark.line + 1 if key is not None else vline
        self.lines[path] = vline if flow or key is None else kline
        self.key_lines[path] = kline
        self.nodes[path] = value

    # ---------------------------------------------------------------- scalars

    def scalar(self, node: Node, path: str) -> Any:
        """The Python value of a scalar node (YAML 1.1 safe types)."""
        if not isinstance(node, ScalarNode):
            raise self.error(path, f"expected a single value, got {_describe(node)}")
        try:
            return self._constructor.construct_object(node, deep=True)
        except Exception as e:  # a bad tag or timestamp: still one line, never a traceback
            raise self.error(path, f"cannot read value: {e}") from None

    def number(self, node: Node, path: str, integer: bool = False) -> float | int:
        v = self.scalar(node, path)
        if isinstance(v, str) and not integer and node.style is None:
            # PyYAML reads 1e3 (no dot) as a string; a plain scalar that is a number is one.
            try:
                v = float(v)
            except ValueError:
                pass
        if isinstance(v, bool) or not isinstance(v, int | float):
            want = "an integer" if integer else "a number"
            raise self.error(path, f"expected {want}, got {_describe(v)}")
        if isinstance(v, float):
            if not math.isfinite(v):
                raise self.error(path, f"must be a finite number, got {_num(v)}")
            if integer:
                if not v.is_integer():
                    raise self.error(path, f"expected an integer, got {_describe(v)}")
                return int(v)
        if isinstance(v, int) and not integer:
            try:
                return float(v)
            except OverflowError:
                raise self.error(path, f"number too large: {_short(v)}") from None
        return v

    # ---------------------------------------------------------------- collections

    def entries(self, node: Node, path: str) -> list[tuple[str, Node, Node]]:
        """The (key, key node, value node) of a mapping in file order.

        Rejects non-mappings, non-string keys and duplicate keys; resolves ``<<`` merges.
        """
        if not isinstance(node, MappingNode):
            v = node if not isinstance(node, ScalarNode) else self.scalar(node, path)
            raise self.error(path, f"expected a mapping, got {_describe(v)}")
        cached = self._entries.get(id(node))
        if cached is not None:
            return cached
        seen: dict[str, Node] = {}
        explicit: list[tuple[str, Node, Node]] = []
        has_merge = False
        for knode, vnode in node.value:
            if knode.tag == "tag:yaml.org,2002:merge":
                has_merge = True
                continue
            key = self.collect(self._key, knode, path)
            if key is None:                   # listed; the entry is left out
                self.bad_keys.setdefault(id(node), self.problems[-1])
                continue
            sub = _join(path, key)
            if key in seen:
                self.add_problem(sub, f"duplicate key {key!r} (first at line "
                                      f"{seen[key].start_mark.line + 1})",
                                 line=knode.start_mark.line + 1)
                self.bad_keys.setdefault(id(node), self.problems[-1])
                continue
            seen[key] = knode
            explicit.append((key, knode, vnode))
        result = explicit
        if has_merge:
            try:
                self._constructor.flatten_mapping(node)
            except yaml.YAMLError as e:
                raise self.error(path, f"bad merge (<<): {getattr(e, 'problem', e)}",
                                 line=node.start_mark.line + 1) from None
            merged: dict[str, tuple[str, Node, Node]] = {}
            for knode, vnode in node.value:   # merged keys first, explicit keys win
                key = self.collect(self._key, knode, path)
                if key is not None:
                    merged[key] = (key, knode, vnode)
            result = list(merged.values())
        self._entries[id(node)] = result
        for key, knode, vnode in result:
            self._record(_join(path, key), vnode, knode)
        return result

    def _key(self, knode: Node, path: str) -> str:
        line = knode.start_mark.line + 1
        if not isinstance(knode, ScalarNode):
            raise self.error(path, f"keys must be plain names, got {_describe(knode)}",
                             line=line)
        k = self.scalar(knode, path)
        if not isinstance(k, str):
            raise self.error(path, f"key {knode.value!r} is read as {_describe(k)}; keys "
                                   f"must be names (quote it: '{knode.value}')", line=line)
        if not k:
            raise self.error(path, "empty key", line=line)
        return k

    def items(self, node: Node, path: str) -> list[Node]:
        if not isinstance(node, SequenceNode):
            v = node if not isinstance(node, ScalarNode) else self.scalar(node, path)
            raise self.error(path, f"expected a list, got {_describe(v)}")
        for i, item in enumerate(node.value):
            self._record(f"{path}[{i}]", item)
        return list(node.value)

    def unknown(self, key: str, path: str, known: Iterable[str], what: str = "key") -> NoReturn:
        raise self.unknown_error(key, path, known, what)

    def unknown_error(self, key: str, path: str, known: Iterable[str], what: str = "key"
                      ) -> ConfigError:
        known = sorted(known)
        close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        hint = _suggest(key, known) or (f" (known: {', '.join(known)})" if known else "")
        e = self.error(_join(path, key), f"unknown {what} {key!r}{hint}",
                       line=self.key_lines.get(_join(path, key)))
        if close:
            self.suggested.setdefault(_join(path, close[0]), e)
        return e

    def missing(self, path: str, key: str, node: Node) -> ConfigError:
        """A required key is missing; when a misspelling of it was found, that is the error."""
        if _join(path, key) in self.suggested:
            return self.suggested[_join(path, key)]
        line = self.key_lines.get(path, node.start_mark.line + 1)
        where = f" in {path}" if path else ""
        return self.error(_join(path, key), f"missing required key {key!r}{where}", line=line)

    # ---------------------------------------------------------------- typed values

    def build(self, tp: Any, node: Node, path: str) -> Any:
        """Build a value of model type ``tp`` from ``node``, following the type hint."""
        nullable, tp = _optional_of(tp)
        if isinstance(node, ScalarNode) and node.tag == "tag:yaml.org,2002:null":
            if nullable:
                return None
            raise self.error(path, "must not be empty (null)")
        special = _SPECIAL_TYPES.get(tp)
        if special is not None:
            return special(self, node, path)
        if dataclasses.is_dataclass(tp):
            return self.dataclass(tp, node, path)
        if tp is bool:
            v = self.scalar(node, path)
            if not isinstance(v, bool):
                raise self.error(path, f"expected true or false, got {_describe(v)}")
            return v
        if tp is float:
            return self.number(node, path)
        if tp is int:
            return self.number(node, path, integer=True)
        if tp is str:
            v = self.scalar(node, path)
            if not isinstance(v, str):
                raise self.error(path, f"expected a string, got {_describe(v)}")
            try:
                v.encode("utf-8")
            except UnicodeEncodeError as e:     # a YAML escape such as "\ud800"
                raise self.error(path, f"not valid text: a lone surrogate "
                                       f"{v[e.start]!a} at character {e.start + 1}") from None
            return v
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin is tuple:
            items = self.items(node, path)
            if len(items) != len(args):
                raise self.error(path, f"expected a list of {len(args)} values, "
                                       f"got {len(items)}")
            g, values = self.gather(), []
            for i, (a, n) in enumerate(zip(args, items, strict=True)):
                with g.step():
                    values.append(self.build(a, n, f"{path}[{i}]"))
            g.done()
            return tuple(values)
        if origin is list:
            g, values = self.gather(), []
            for i, n in enumerate(self.items(node, path)):
                with g.step():
                    values.append(self.build(args[0], n, f"{path}[{i}]"))
            g.done()
            return values
        if origin is dict:
            vt = args[1]
            named = dataclasses.is_dataclass(vt) and "name" in {
                f.name for f in dataclasses.fields(vt)}
            entries = self.entries(node, path)
            g, out = self.gather(node), {}
            for key, _, vnode in entries:
                sub = _join(path, key)
                with g.step():
                    out[key] = (self.dataclass(vt, vnode, sub, name=key) if named
                                else self.build(vt, vnode, sub))
            g.done()
            return out
        raise TypeError(f"loader cannot map model type {tp!r} at {path}")

    def dataclass(self, cls: type, node: Node, path: str, name: str | None = None,
                  fill: dict[str, Any] | None = None) -> Any:
        """Build dataclass ``cls`` from a mapping: its fields are the YAML keys.

        ``name`` fills a ``name`` field from the enclosing mapping key; ``fill`` gives
        loader-filled fields (``Path`` ones).
        """
        hints = _hints(cls)
        implied = _IMPLIED_FIELDS.get(cls, frozenset())
        fields = {f.name: f for f in dataclasses.fields(cls)
                  if hints[f.name] is not Path and f.name not in implied
                  and not (name is not None and f.name == "name")}
        extra = _EXTRA_KEYS.get(cls, frozenset())
        kwargs: dict[str, Any] = dict(fill or {})
        if name is not None and "name" in hints:
            kwargs["name"] = name
        given = set()
        entries = self.entries(node, path)
        g = self.gather(node)                 # every key is checked, not only the first
        for key, _, vnode in entries:
            sub = _join(path, key)
            if key in extra:
                continue
            if key not in fields:             # listed; the other keys still make the value
                self.note(self.unknown_error(key, path, list(fields) + list(extra)), own=True)
                continue
            given.add(key)
            # a bad number or word where the field has a default is listed, and the default
            # stands in, so that the checks across keys still run on the rest of the file
            stands_in = _scalar_with_default(fields[key], hints[key])
            with g.step(breaks=not stands_in), self.standing_in(sub if stands_in else None):
                builder = _FIELD_BUILDERS.get((cls, key))
                if builder is not None:
                    kwargs.update(builder(self, vnode, sub))
                    continue
                value = self.build(hints[key], vnode, sub)
                self.check_field(cls, key, value, sub)
                kwargs[key] = value
        for fname, f in fields.items():
            if fname not in given and _required(f):
                g.fail(self.missing(path, fname, node))
        g.done()
        return cls(**kwargs)

    def check_field(self, cls: type, fname: str, value: Any, path: str) -> None:
        """Per-field checks from the tables: enumerations, ranges, ``leaf`` import paths."""
        allowed = ENUMS.get((cls, fname))
        if allowed is not None and value not in allowed:
            raise self.error(path, f"must be one of {', '.join(allowed)}, got {value!r}"
                                   f"{_suggest(str(value), allowed)}")
        rng = RANGES.get((cls, fname))
        if rng is not None and value is not None and not rng.contains(value):
            raise self.error(path, f"must be {rng.describe()}, got {_num(value)}")
        if fname == "leaf" and value is not None:
            self.check_leaf(value, path)

    def check_leaf(self, spec: str, path: str) -> None:
        """A leaf is ``package.module:Class``; import it now so a typo fails at load time."""
        if not LEAF_RE.match(spec):
            raise self.error(path, f"must be an import path 'package.module:Class', "
                                   f"got {_short(spec)}")
        mod_name, cls_name = spec.split(":")
        try:
            mod = import_near(mod_name, Path(self.file).parent)
        except BaseException as e:  # noqa: BLE001 - any failure of foreign code is one line
            if isinstance(e, KeyboardInterrupt):
                raise
            raise self.error(path, f"cannot import module {mod_name!r} for leaf {spec!r}: "
                                   f"{type(e).__name__}: {e}") from None
        obj = getattr(mod, cls_name, None)
        if obj is None:
            raise self.error(path, f"module {mod_name!r} has no class {cls_name!r} "
                                   f"(leaf {spec!r}){_suggest(cls_name, dir(mod))}")
        if not inspect.isclass(obj):
            raise self.error(path, f"{spec!r} is a {type(obj).__name__}, not a class")


# Builders of the places where the YAML is not a mirror of the model (``special.py``
# registers them): by model type, and by (dataclass, field) for a field read specially.
_SPECIAL_TYPES: dict[type, Callable[[_Ctx, Node, str], Any]] = {}
_FIELD_BUILDERS: dict[tuple[type, str], Callable[[_Ctx, Node, str], dict[str, Any]]] = {}
