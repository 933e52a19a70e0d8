"""The SQLite event log (thesis 8.2.1.4): one time-stamped record of every run, from which
``feeder report`` and the operator UI draw their tables and plots.

Writing must never slow the tick: the Stats listener only appends to a list, and rows go
to the database in batches when the run loop calls ``periodic_flush()`` between ticks.
One connection, used only by the thread that created it (the run loop's).
"""

from __future__ import annotations

import datetime as _dt
import enum
import json
import sqlite3
import sys
import time
from pathlib import Path
from typing import Any

from feeder_bt.behaviours.base import Event, Stats
from feeder_bt.core.didyoumean import hint
from feeder_bt.core.errors import FeederError

SCHEMA_VERSION = 1
FLUSH_EVERY = 5000          # buffered events that force a flush
FLUSH_WALL_S = 2.0          # wall seconds between flushes otherwise

# Operator access events, recorded by the operator UI: the kind, and the words
# `feeder report` counts them under. ``user`` is who (``-`` for nobody, ``(unknown name)``
# for a name that is not a user); ``ip`` where from; ``why`` the reason.
ACCESS_KINDS = {
    "login_failed": "failed logins",
    "login_locked": "lock-outs",
    "login_refused": "logins refused while locked",
    "command_refused": "refused commands",
    "request_refused": "refused requests",
    "control_released": "control released",
    "session_ended": "sessions ended",
    "access_suppressed": "not recorded (flood)",
}

SAMPLE_COLUMNS = ("t", "queue", "horizontal_mm_s", "incline_pct", "robot_speed_pct",
                  "retrieved")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY, scenario TEXT, cell TEXT, seed INTEGER, hal TEXT,
    started TEXT, ended TEXT, options TEXT, report TEXT);
CREATE TABLE IF NOT EXISTS events (
    run_id INTEGER NOT NULL REFERENCES runs(id), t REAL NOT NULL, kind TEXT NOT NULL,
    data TEXT);
CREATE INDEX IF NOT EXISTS events_run_kind ON events(run_id, kind);
CREATE TABLE IF NOT EXISTS samples (
    run_id INTEGER NOT NULL REFERENCES runs(id), t REAL NOT NULL, queue INTEGER,
    horizontal_mm_s REAL, incline_pct REAL, robot_speed_pct REAL, retrieved INTEGER,
    extra TEXT);
CREATE INDEX IF NOT EXISTS samples_run_t ON samples(run_id, t);
"""


class EventLogError(FeederError):
    """The database cannot be opened, is not a feeder event log, or is damaged."""

    exit_code = 2


def _jsonable(value: Any) -> Any:
    """numpy scalars, enums, exceptions: whatever a leaf put in an event, as JSON."""
    if hasattr(value, "item"):                      # numpy scalar
        return value.item()
    if isinstance(value, enum.Enum):
        return value.value
    return str(value)


def _dumps(obj: Any) -> str:
    return json.dumps(obj, default=_jsonable, separators=(",", ":"))


def _extra(sample: dict[str, Any]) -> str | None:
    """Sample keys without a column of their own (an adjuster may add some) as JSON."""
    rest = {k: v for k, v in sample.items() if k not in SAMPLE_COLUMNS}
    return _dumps(rest) if rest else None


def _now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).astimezone().isoformat(timespec="seconds")


def _check_feeder_db(conn: sqlite3.Connection, path: str | Path) -> None:
    """Refuse a database that holds tables but not ours (never write into someone else's)."""
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    except sqlite3.DatabaseError as e:
        raise EventLogError(f"{path}: not an SQLite database ({e})") from None
    if tables and not {"runs", "events", "samples", "meta"} <= tables:
        raise EventLogError(f"{path}: not a feeder event log (tables: "
                            f"{', '.join(sorted(tables)) or 'none'})")


class EventLog:
    """Buffered writer of one or more runs' events and samples to an SQLite file."""

    def __init__(self, path: str | Path, flush_every: int = FLUSH_EVERY,
                 flush_wall_s: float = FLUSH_WALL_S) -> None:
        self.path = Path(path)
        self.flush_every, self.flush_wall_s = flush_every, flush_wall_s
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._conn: sqlite3.Connection | None = sqlite3.connect(self.path, timeout=10.0)
        except (OSError, sqlite3.Error) as e:
            raise EventLogError(f"{self.path}: cannot open the event log: {e}") from None
        try:
            _check_feeder_db(self._conn, self.path)
        except EventLogError:
            self._conn.close()
            raise
        try:
            self._conn.execute("PRAGMA journal_mode=WAL")     # readers never block the run
            self._conn.execute("PRAGMA synchronous=NORMAL")   # no fsync per batch
            with self._conn:
                self._conn.executescript(_SCHEMA)
                self._conn.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)",
                                   (str(SCHEMA_VERSION),))
        except sqlite3.Error as e:
            self._conn.close()
            raise EventLogError(f"{self.path}: cannot write the event log: {e}") from None
        self.run_id: int | None = None
        self._events: list[tuple[float, str, dict[str, Any]]] = []
        self._stats: Stats | None = None
        self._timeline_idx = 0
        self._samples: list[dict[str, float]] = []
        self._writers: list[Any] = []       # more tables, written in the same batches
        self._next_flush = time.monotonic() + flush_wall_s

    # ------------------------------------------------------------------ run lifecycle
    def start_run(self, meta: dict[str, Any]) -> int:
        """Open a run row: ``scenario``, ``cell``, ``seed``, ``hal``; the rest is options."""
        known = ("scenario", "cell", "seed", "hal")
        options = {k: v for k, v in meta.items() if k not in known}
        cur = self._execute(
            "INSERT INTO runs (scenario, cell, seed, hal, started, options) VALUES (?,?,?,?,?,?)",
            (*(meta.get(k) for k in known), _now_iso(), _dumps(options)))
        self.run_id = cur.lastrowid if cur is not None else None
        return self.run_id or 0

    def attach(self, cell: Any) -> None:
        """Follow ``cell``'s statistics; they are replaced at each start, so rebind then."""
        self._bind(cell.stats)
        cell.listeners.append(lambda old, new: self._bind(cell.stats))

    def add_writer(self, writer: Any) -> None:
        """Another recorder writing its own tables in this log's batches (the trees'
        history, ``treelog.TreeTrace``): it has ``SCHEMA``, ``seal()``, ``pending()`` and
        ``write(conn, run_id)``, called in the flush's transaction."""
        if self._conn is not None:
            try:
                self._conn.executescript(writer.SCHEMA)
            except sqlite3.Error as e:
                self._fail(e)
        self._writers.append(writer)

    def finish(self, report: dict[str, Any] | None) -> None:
        """Flush, then store the final report and the end time on the run row."""
        for w in self._writers:
            w.seal()
        self.flush()
        if self.run_id is not None:
            self._execute("UPDATE runs SET ended=?, report=? WHERE id=?",
                          (_now_iso(), None if report is None else _dumps(report), self.run_id))

    def close(self) -> None:
        """Flush what is buffered and close; safe to call twice."""
        self.flush()
        if self._stats is not None and self._on_event in self._stats.listeners:
            self._stats.listeners.remove(self._on_event)
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def __enter__(self) -> EventLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ buffering
    def _on_event(self, ev: Event) -> None:
        self._events.append((ev.t, ev.kind, ev.data))      # nothing else on the tick's time

    def _bind(self, stats: Stats) -> None:
        if stats is self._stats:
            return
        if self._stats is not None:
            self._take_samples()
            if self._on_event in self._stats.listeners:
                self._stats.listeners.remove(self._on_event)
        # events emitted on the new Stats before we heard of it (the STARTING switch)
        self._events.extend((ev.t, ev.kind, ev.data) for ev in stats.events)
        stats.listeners.append(self._on_event)
        self._stats, self._timeline_idx = stats, 0

    def _take_samples(self) -> None:
        tl = self._stats.timeline if self._stats is not None else []
        if len(tl) > self._timeline_idx:
            self._samples.extend(tl[self._timeline_idx:])
            self._timeline_idx = len(tl)

    def periodic_flush(self) -> None:
        """Call after each tick: flushes every ``flush_every`` events or ``flush_wall_s``."""
        if len(self._events) >= self.flush_every or time.monotonic() >= self._next_flush:
            self.flush()

    def flush(self) -> None:
        """Write the buffered events and samples in one transaction."""
        self._next_flush = time.monotonic() + self.flush_wall_s
        self._take_samples()
        if self._conn is None or self.run_id is None or not (
                self._events or self._samples or any(w.pending() for w in self._writers)):
            return
        rid = self.run_id
        events = [(rid, float(t), kind, _dumps(data)) for t, kind, data in self._events]
        samples = [(rid, *(s.get(c) for c in SAMPLE_COLUMNS),
                    _extra(s)) for s in self._samples]
        self._events, self._samples = [], []
        try:
            with self._conn:
                self._conn.executemany("INSERT INTO events VALUES (?,?,?,?)", events)
                self._conn.executemany("INSERT INTO samples VALUES (?,?,?,?,?,?,?,?)", samples)
                for w in self._writers:
                    w.write(self._conn, rid)
        except sqlite3.Error as e:
            self._fail(e)

    def _execute(self, sql: str, args: tuple) -> sqlite3.Cursor | None:
        if self._conn is None:
            return None
        try:
            with self._conn:
                return self._conn.execute(sql, args)
        except sqlite3.Error as e:
            self._fail(e)
            return None

    def _fail(self, error: sqlite3.Error) -> None:
        """A full disk must not stop the cell: warn once, stop logging, keep feeding."""
        print(f"feeder: event log {self.path} disabled: {error}", file=sys.stderr)
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        self._events, self._samples = [], []


# ---------------------------------------------------------------------------- reading


def open_readonly(path: str | Path) -> sqlite3.Connection:
    """Open an existing event log for reading; EventLogError (one line) if it is not one."""
    p = Path(path)
    if not p.is_file():
        raise EventLogError(f"{path}: no such event log{hint(path)}")
    try:
        conn = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error as e:
        raise EventLogError(f"{path}: cannot open: {e}") from None
    conn.row_factory = sqlite3.Row
    try:
        _check_feeder_db(conn, path)
        conn.execute("SELECT id FROM runs LIMIT 1").fetchall()
    except EventLogError:
        conn.close()
        raise
    except sqlite3.Error as e:
        conn.close()
        raise EventLogError(f"{path}: not a feeder event log ({e})") from None
    return conn
