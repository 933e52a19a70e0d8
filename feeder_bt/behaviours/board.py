"""One cell's blackboard.

py_trees keeps a single store per process (``Blackboard.storage``). So that two cells can
share a process, each cell's keys live there under its own prefix (``/cells/3/speeds/...``)
and every client a leaf registers remaps the plain keys it declares onto them
(``register_key(remap_to=...)``, py_trees' own mechanism): a leaf still reads
``/speeds/horizontal_mm_s``, and never another cell's. The root board (no prefix) is what
a tree built outside a cell uses: ``feeder tree`` and the tick-level tests.
"""

from __future__ import annotations

import itertools
import uuid
import weakref
from collections.abc import Iterable
from typing import Any

import py_trees
from py_trees.blackboard import Blackboard, Client
from py_trees.common import Access

#: where the cells' boards live in py_trees' store
CELLS = "/cells"


class Board:
    """A cell's keys, its clients' registration, and the cell's own reads and writes."""

    _numbers = itertools.count(1)

    def __init__(self, prefix: str | None = None) -> None:
        self.prefix = f"{CELLS}/{next(Board._numbers)}" if prefix is None else prefix
        self._clients: list[uuid.UUID] = []
        self._writer = Client(name=f"cell {self.prefix}" if self.prefix else "cell")
        self._clients.append(self._writer.unique_identifier)
        if self.prefix:     # a cell's board goes with its cell, and takes its keys along
            weakref.finalize(self, _drop, self.prefix, self._clients)
            _CELL_BOARDS.add(self)

    def where(self, key: str) -> str:
        """Where ``key`` is kept in py_trees' store."""
        return self.prefix + key

    # ------------------------------------------------------------------ leaves
    def client(self, owner: py_trees.behaviour.Behaviour, read: Iterable[str] = (),
               write: Iterable[str] = ()) -> Client:
        """The leaf's client, registering exactly the keys it declares, on this board."""
        bb = _Client(name=owner.name)     # what attach_blackboard_client makes, quicker
        owner.blackboards.append(bb)
        for key in read:
            bb.register_key(key=key, access=Access.READ, remap_to=self.where(key))
        for key in write:
            bb.register_key(key=key, access=Access.WRITE, remap_to=self.where(key))
        self._clients.append(bb.unique_identifier)
        return bb

    # ------------------------------------------------------------------ the cell's own
    def get(self, key: str, default: Any = None) -> Any:
        """The value of ``key`` now (``default`` if it was never set)."""
        return Blackboard.storage.get(self.where(key), default)

    def set(self, key: str, value: Any) -> None:
        """Write ``key`` as the cell (the operator's speeds, a restart's part in hand)."""
        if not self._writer.is_registered(key, Access.WRITE):
            self._writer.register_key(key=key, access=Access.WRITE, remap_to=self.where(key))
        self._writer.set(key, value)

    def items(self) -> dict[str, Any]:
        """Every key of this board and its value, by the plain key."""
        n = len(self.prefix)
        store = Blackboard.storage
        return {k[n:]: v for k, v in list(store.items()) if self._mine(k)}

    def reset(self, values: dict[str, Any]) -> None:
        """Fresh for a run: the last run's keys and leaves' clients gone, ``values`` set."""
        if self.prefix:
            _drop(self.prefix, self._clients, keep=self._writer.unique_identifier)
        else:
            _drop_root()
            self._clients[:] = [self._writer.unique_identifier]
            Blackboard.clients[self._writer.unique_identifier] = self._writer.name
        for key, value in values.items():
            self.set(key, value)

    def _mine(self, stored: str) -> bool:
        if self.prefix:
            return stored.startswith(self.prefix + "/")
        return not _in_a_cell(stored)


class _Client(Client):
    """py_trees' client, whose ``get`` of a plain key it has read before goes straight to
    the store: py_trees checks the client's access and resolves the remapping on every
    read (a few microseconds, about 200,000 reads in a simulated hour of lenses). The first
    read of each key takes py_trees' way, with its checks and errors; a key unregistered
    is forgotten, and with py_trees' activity stream on every read takes py_trees' way."""

    def get(self, name: str) -> Any:
        if Blackboard.activity_stream is None:
            where = super().__getattribute__("_fast").get(name)
            if where is not None:
                try:
                    return Blackboard.storage[where]
                except KeyError:
                    pass                    # py_trees' own error, below
        value = super().get(name)
        if "." not in name:
            absolute = Blackboard.absolute_name(super().__getattribute__("namespace"), name)
            super().__getattribute__("_fast")[name] = \
                super().__getattribute__("remappings")[absolute]
        return value

    def unregister_key(self, key: str, clear: bool = True,
                       update_namespace_cache: bool = True) -> None:
        super().__getattribute__("_fast").clear()
        super().unregister_key(key, clear=clear, update_namespace_cache=update_namespace_cache)

    def __init__(self, *, name: str) -> None:
        super().__init__(name=name)
        object.__setattr__(self, "_fast", {})


def _in_a_cell(stored: str) -> bool:
    return stored.startswith(CELLS + "/")


def _drop(prefix: str, clients: list[uuid.UUID], keep: uuid.UUID | None = None) -> None:
    """Take a board's keys and its leaves' clients out of py_trees' registries."""
    for uid in list(clients):
        if uid == keep:
            continue
        Blackboard.clients.pop(uid, None)
    clients[:] = [keep] if keep is not None else []
    for k in [k for k in list(Blackboard.storage) if k.startswith(prefix + "/")]:
        Blackboard.storage.pop(k, None)
    for k in [k for k in list(Blackboard.metadata) if k.startswith(prefix + "/")]:
        meta = Blackboard.metadata.get(k)
        if meta is None:
            continue
        if keep is None:
            Blackboard.metadata.pop(k, None)
        else:       # the cell's own client keeps its registration
            for access in (meta.read, meta.write, meta.exclusive):
                access.difference_update(access - {keep})


def _drop_root() -> None:
    """``Blackboard.clear()`` for everything outside the cells' boards."""
    for k in [k for k in list(Blackboard.storage) if not _in_a_cell(k)]:
        Blackboard.storage.pop(k, None)
    for k in [k for k in list(Blackboard.metadata) if not _in_a_cell(k)]:
        Blackboard.metadata.pop(k, None)
    cells = {uid for board in list(_CELL_BOARDS) for uid in board._clients}
    for uid in [uid for uid in list(Blackboard.clients) if uid not in cells]:
        Blackboard.clients.pop(uid, None)


_CELL_BOARDS: weakref.WeakSet[Board] = weakref.WeakSet()


#: the board of trees built outside a cell (``feeder tree``, tick-level tests)
ROOT = Board(prefix="")
