"""The trees' history: every status change of every node, and the blackboard,
recorded compactly so that a shift can be rewound (``feeder replay``, the dashboard's
timeline), as Groot2 does with BehaviorTree.CPP's transition log.

Recording (``TreeTrace``, on the tick thread): after each tick the ticked tree's statuses
are compared with the last ones (one C-level list comparison when nothing changed, which
is most ticks); only changes are kept. Nodes get small ids by their place in the tree
(``tree_nodes``: written once per run); a tree rebuilt at the next start keeps its ids.
Changes are packed into chunks of ``CHUNK_S`` virtual seconds: the status of every node
at the chunk's start (one byte each), then each change as two varints (milliseconds since
the change before, ``node_id << 2 | status``), zlib-compressed; the chunk also holds the
blackboard (summarised, every ``BOARD_EVERY_S``, changes only) and which tree was ticked.
Nothing is written on the tick's time: the event log writes closed chunks when it flushes
its batch (``EventLog.add_writer``).

Reading (``TraceView``): the state at any time is one chunk decoded up to that time.
"""

from __future__ import annotations

import bisect
import dataclasses
import enum
import json
import operator
import sqlite3
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import py_trees
from py_trees.common import Status

from feeder_bt.core.vocabulary import MISS_KINDS

CHUNK_S = 10.0              # virtual seconds per chunk (one key frame each)
BOARD_EVERY_S = 1.0         # virtual seconds between blackboard samples
PUBLISH_WALL_S = 0.2        # the live view (dashboard) is refreshed at most this often
MAX_LIVE_BYTES = 64 << 20   # in-memory history kept for the dashboard's timeline
STATUS_NAMES = ("invalid", "running", "success", "failure")
_BY_CODE = (Status.INVALID, Status.RUNNING, Status.SUCCESS, Status.FAILURE)
_STATUS = operator.attrgetter("status")

SCHEMA = """
CREATE TABLE IF NOT EXISTS tree_nodes (
    run_id INTEGER NOT NULL, id INTEGER NOT NULL, parent INTEGER, tree TEXT, name TEXT,
    kind TEXT, PRIMARY KEY (run_id, id)) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS tree_chunks (
    run_id INTEGER NOT NULL, t0 REAL NOT NULL, t1 REAL NOT NULL, base BLOB, moves BLOB,
    board BLOB);
CREATE INDEX IF NOT EXISTS tree_chunks_run_t ON tree_chunks(run_id, t0);
"""


@dataclass(frozen=True)
class Node:
    """One node of a recorded tree: ``parent`` is -1 for a root; ``tree`` is ``setup``,
    ``feeding`` or ``cleanup``; ``kind`` the py_trees shape (sequence, selector, parallel,
    decorator, leaf) and class."""

    id: int
    parent: int
    tree: str
    name: str
    kind: str


@dataclass(frozen=True)
class Chunk:
    """``CHUNK_S`` of history: statuses at ``t0`` (``base``), the changes until ``t1``
    (``moves``), and the board JSON (ticked tree, blackboard), each zlib-compressed."""

    t0: float
    t1: float
    base: bytes
    moves: bytes
    board: bytes

    @property
    def size(self) -> int:
        return len(self.base) + len(self.moves) + len(self.board)


@dataclass(frozen=True)
class TreeState:
    """The trees as they were at ``t``: the ticked tree (None between trees), each node's
    status code (index: node id; ``STATUS_NAMES``) and the blackboard."""

    t: float
    tree: str | None
    statuses: tuple[int, ...]
    board: dict[str, Any]


# ---------------------------------------------------------------------------- packing

def _varint(out: bytearray, n: int) -> None:
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)


def _unpack(data: bytes) -> list[int]:
    vals, n, shift = [], 0, 0
    for b in data:
        n |= (b & 0x7F) << shift
        if b & 0x80:
            shift += 7
        else:
            vals.append(n)
            n, shift = 0, 0
    return vals


def shape_of(node: py_trees.behaviour.Behaviour) -> str:
    """What the page draws a node as."""
    if isinstance(node, py_trees.composites.Sequence):
        return "sequence"
    if isinstance(node, py_trees.composites.Selector):
        return "selector"
    if isinstance(node, py_trees.composites.Parallel):
        return "parallel"
    if isinstance(node, py_trees.decorators.Decorator):
        return "decorator"
    return "leaf"


def summarise(value: Any, depth: int = 0) -> Any:
    """A blackboard value as short JSON: scalars as they are, a dataclass by its scalar
    fields, anything else by its type (an image is never copied)."""
    if value is None or isinstance(value, bool | int | str):
        return value if not isinstance(value, str) else value[:120]
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, enum.Enum):
        return str(value.value)
    if hasattr(value, "item") and getattr(value, "ndim", 1) == 0:       # numpy scalar
        return summarise(value.item(), depth)
    if dataclasses.is_dataclass(value) and not isinstance(value, type) and depth == 0:
        # for people, not Python: "Frame: latch 8012345, t 12.3, index 4"; fields that are
        # not plain values (an image, a list) and empty ones are left out
        fields = {f.name: summarise(getattr(value, f.name), 1)
                  for f in dataclasses.fields(value)}
        inner = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in fields.items()
                          if isinstance(v, bool | int | float)
                          or (isinstance(v, str) and v and not v.startswith("<")))
        return f"{type(value).__name__}: {inner}"[:160] if inner else type(value).__name__
    if isinstance(value, list | tuple) and depth == 0:
        return f"[{len(value)} items]"
    return f"<{type(value).__name__}>"


def board_now(board: Any) -> dict[str, Any]:
    """A cell's blackboard (``Cell.board``), summarised, by its plain keys."""
    return {k: summarise(v) for k, v in sorted(board.items().items())}


# ---------------------------------------------------------------------------- recording

class TreeTrace:
    """Follows one cell's ticked trees; ``after_tick()`` is called by the run loop."""

    SCHEMA = SCHEMA

    def __init__(self, cell: Any, live: bool = False, logged: bool = True) -> None:
        self.cell = cell
        self.live = live                          # keep history in memory for the dashboard
        self.logged = logged                      # keep closed chunks for the event log
        self.nodes: list[Node] = []
        self._ids: dict[tuple[str, tuple[int, ...]], int] = {}
        self._last: bytearray = bytearray()       # status code per node id
        self._root: Any = None
        self._pairs: list[tuple[int, Any]] = []   # (id, node) of the ticked tree
        self._plain: list[Any] = []
        self._node_ids: list[int] = []
        self._prev: list[Status] = []
        self._part: str | None = None
        now = cell.clock.now()
        self._open(now, None)
        self._next_board = now
        self._board: dict[str, Any] = {}
        self.closed: list[Chunk] = []             # for the event log
        self.written_chunks = 0
        self.written_nodes = 0
        self.transitions = 0
        self.live_chunks: tuple[Chunk, ...] = ()
        self.live_bytes = 0
        self.published: TraceView | None = None
        self._next_publish = 0.0
        self.marks: list[tuple[float, str]] = []  # (t, state or fault) for the timeline
        cell.listeners.append(self._on_state)

    # -------------------------------------------------------------- per tick
    def after_tick(self) -> None:
        cell = self.cell
        now = cell.clock.now()
        if now >= self._t0 + CHUNK_S:
            self._close(now)
        root = cell.root
        if root is not self._root:
            if self._root is not None:
                self._scan(now)                   # a halt left them INVALID: record it
            self._attach(root)
            self._part = self._part_of(root)
            self._switches.append([round(now, 3), self._part])
        if root is not None:
            statuses = list(map(_STATUS, self._plain))
            if statuses != self._prev:
                self._scan(now, statuses)
        if now >= self._next_board:
            self._sample_board(now)
        if self.live and time.monotonic() >= self._next_publish:
            self.publish()

    def _scan(self, now: float, statuses: list[Status] | None = None) -> None:
        """Record the nodes whose status differs from the last scan's (``_prev`` always
        says what ``_last`` holds for the ticked tree's nodes)."""
        if statuses is None:
            statuses = list(map(_STATUS, self._plain))
        ms = round((now - self._t0) * 1000)
        last, ids = self._last, self._node_ids
        for i, (st, was) in enumerate(zip(statuses, self._prev, strict=True)):
            if st is not was:
                nid = ids[i]
                code = (1 if st is Status.RUNNING else 2 if st is Status.SUCCESS
                        else 3 if st is Status.FAILURE else 0)
                last[nid] = code
                _varint(self._moves, ms - self._ms)
                _varint(self._moves, nid << 2 | code)
                self._ms = ms
                self.transitions += 1
        self._prev = statuses

    def _attach(self, root: Any) -> None:
        self._root = root
        if root is None:
            self._pairs, self._plain, self._prev, self._node_ids = [], [], [], []
            return
        part = self._part_of(root)
        pairs: list[tuple[int, Any]] = []
        stack: list[tuple[Any, tuple[int, ...]]] = [(root, ())]
        while stack:                              # pre-order: a parent before its children
            node, path = stack.pop()
            key = (part, path)
            nid = self._ids.get(key)
            if nid is None:
                nid = len(self.nodes)
                parent = self._ids[(part, path[:-1])] if path else -1
                self._ids[key] = nid
                self.nodes.append(Node(nid, parent, part or "?", node.name,
                                       f"{shape_of(node)}:{type(node).__name__}"))
                self._last.append(0)
            pairs.append((nid, node))
            kids = list(getattr(node, "children", ()))
            stack.extend((kid, (*path, i)) for i, kid in reversed(list(enumerate(kids))))
        self._pairs, self._plain = pairs, [n for _, n in pairs]
        self._node_ids = [nid for nid, _ in pairs]
        self._prev = [_BY_CODE[self._last[nid]] for nid in self._node_ids]

    def _part_of(self, root: Any) -> str | None:
        if root is None:
            return None
        if root is self.cell.feeding:
            return "feeding"
        return "setup" if self.cell.state.value == "STARTING" else "cleanup"

    def _sample_board(self, now: float) -> None:
        self._next_board = now + BOARD_EVERY_S
        board = board_now(self.cell.board)
        changed = {k: v for k, v in board.items() if self._board.get(k, ...) != v}
        changed.update({k: None for k in self._board if k not in board})
        if changed:
            self._board_changes.append([round(now, 3), changed])
            self._board = board

    def _on_state(self, old: Any, new: Any) -> None:
        now = self.cell.clock.now()
        self.marks.append((round(now, 3), new.value))
        if new.value in ("FAULTING", "FAULT") and self.cell.fault_reason:
            self.marks.append((round(now, 3), f"fault: {self.cell.fault_reason}"))

    # -------------------------------------------------------------- chunks
    def _open(self, t0: float, part: str | None) -> None:
        self._t0, self._ms = t0, 0
        self._base = bytes(getattr(self, "_last", b""))
        self._moves = bytearray()
        self._switches: list[list[Any]] = []
        self._board_base = dict(getattr(self, "_board", {}))
        self._board_changes: list[list[Any]] = []
        self._part0 = part

    def _freeze(self, t1: float) -> Chunk:
        board = {"tree": self._part0, "switches": self._switches, "bb": self._board_base,
                 "changes": self._board_changes}
        return Chunk(self._t0, t1, zlib.compress(self._base), zlib.compress(bytes(self._moves)),
                     zlib.compress(json.dumps(board, separators=(",", ":"),
                                              default=str).encode()))

    def _close(self, now: float) -> None:
        chunk = self._freeze(now)
        if self.logged:
            self.closed.append(chunk)
        if self.live:
            chunks, size = (*self.live_chunks, chunk), self.live_bytes + chunk.size
            while size > MAX_LIVE_BYTES and len(chunks) > 1:
                size -= chunks[0].size
                chunks = chunks[1:]
            self.live_chunks, self.live_bytes = chunks, size
        self._open(now, self._part)

    def seal(self) -> None:
        """Close the open chunk (the run is ending), so that it is written."""
        now = self.cell.clock.now()
        if self._root is not None:
            self._scan(now)
        if self._moves or self._switches or self._board_changes or now > self._t0:
            self._close(max(now, self._t0))

    def publish(self) -> TraceView:
        """An immutable view for the web thread: the kept chunks and the open one."""
        self._next_publish = time.monotonic() + PUBLISH_WALL_S
        now = self.cell.clock.now()
        view = TraceView(tuple(self.nodes), (*self.live_chunks, self._freeze(now)),
                         tuple(self.marks))
        self.published = view
        return view

    # -------------------------------------------------------------- the event log
    def pending(self) -> bool:
        return bool(self.closed) or self.written_nodes < len(self.nodes)

    def write(self, conn: sqlite3.Connection, run_id: int) -> None:
        """In the event log's transaction: new nodes, then closed chunks."""
        new = self.nodes[self.written_nodes:]
        conn.executemany("INSERT OR IGNORE INTO tree_nodes VALUES (?,?,?,?,?,?)",
                         [(run_id, n.id, n.parent, n.tree, n.name, n.kind) for n in new])
        self.written_nodes += len(new)
        chunks, self.closed = self.closed, []
        conn.executemany("INSERT INTO tree_chunks VALUES (?,?,?,?,?,?)",
                         [(run_id, c.t0, c.t1, c.base, c.moves, c.board) for c in chunks])
        self.written_chunks += len(chunks)


# ---------------------------------------------------------------------------- reading

class TraceView:
    """A recorded history, in memory (live) or from the event log: ``at(t)`` rebuilds the
    trees and the blackboard as they were at time ``t``."""

    def __init__(self, nodes: Sequence[Node], chunks: Sequence[Chunk],
                 marks: Sequence[tuple[float, str]] = (),
                 load: Callable[[int], Chunk] | None = None) -> None:
        self.nodes = tuple(nodes)
        self.chunks = chunks          # with ``load``: (t0, t1) pairs, bodies loaded on demand
        self.marks = tuple(marks)
        self._load = load
        self._t0s = [c[0] if isinstance(c, tuple) else c.t0 for c in chunks]
        self._cache: dict[int, Chunk] = {}

    @property
    def span(self) -> tuple[float, float]:
        """(first, last) time recorded; (0, 0) when nothing was."""
        if not self.chunks:
            return 0.0, 0.0
        first, last = self.chunks[0], self.chunks[-1]
        return (first[0] if isinstance(first, tuple) else first.t0,
                last[1] if isinstance(last, tuple) else last.t1)

    def _chunk(self, i: int) -> Chunk:
        c = self.chunks[i]
        if isinstance(c, Chunk):
            return c
        if i not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[i] = self._load(i)           # type: ignore[misc]
        return self._cache[i]

    def at(self, t: float) -> TreeState:
        """The state after every change recorded at or before ``t``."""
        n = len(self.nodes)
        if not self.chunks:
            return TreeState(t, None, (0,) * n, {})
        i = max(0, bisect.bisect_right(self._t0s, t + 1e-9) - 1)
        c = self._chunk(i)
        codes = bytearray(zlib.decompress(c.base))
        codes.extend(b"\0" * (n - len(codes)))
        vals = _unpack(zlib.decompress(c.moves))
        limit = (t - c.t0) * 1000 + 0.5
        ms = 0
        for k in range(0, len(vals), 2):
            ms += vals[k]
            if ms > limit:
                break
            code = vals[k + 1]
            codes[code >> 2] = code & 3
        board = json.loads(zlib.decompress(c.board))
        tree = board["tree"]
        for st, part in board["switches"]:
            if st > t + 1e-6:
                break
            tree = part
        bb = dict(board["bb"])
        for st, changed in board["changes"]:
            if st > t + 1e-6:
                break
            for k, v in changed.items():
                if v is None and k not in bb:
                    continue
                bb[k] = v
        return TreeState(t, tree, tuple(codes[:n]), bb)


def read_trace(conn: sqlite3.Connection, run_id: int) -> TraceView:
    """The recorded trees of one run of an event log (no rows: an empty view)."""
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if "tree_chunks" not in tables:
        return TraceView((), ())
    nodes = [Node(*r) for r in conn.execute(
        "SELECT id, parent, tree, name, kind FROM tree_nodes WHERE run_id=? ORDER BY id",
        (run_id,))]
    index = conn.execute("SELECT rowid, t0, t1 FROM tree_chunks WHERE run_id=? ORDER BY t0",
                         (run_id,)).fetchall()
    rowids = [r[0] for r in index]

    def load(i: int) -> Chunk:
        row = conn.execute("SELECT t0, t1, base, moves, board FROM tree_chunks WHERE rowid=?",
                           (rowids[i],)).fetchone()
        return Chunk(*row)

    marks: list[tuple[float, str]] = []
    for t, kind, data in conn.execute(
            "SELECT t, kind, data FROM events WHERE run_id=? AND kind IN ('state', 'fault') "
            "ORDER BY rowid", (run_id,)):
        d = json.loads(data or "{}")
        word = "miss" if d.get("kind") in MISS_KINDS else "fault"     # vocabulary.py
        marks.append((t, d.get("new", "?") if kind == "state"
                       else f"{word}: {d.get('message', '?')}"))
    return TraceView(nodes, [(r[1], r[2]) for r in index], marks, load)
