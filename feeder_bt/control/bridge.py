"""The bridge between the web server's thread and the cell's tick thread.

The cell is not thread-safe and must never wait on a client, so the two threads share only:

- a queue of commands: the web side calls ``submit()`` and awaits the returned future;
  the tick thread runs ``pump()`` after each tick, executes the queued commands on the cell
  and resolves their futures (a future cancelled before its turn — the web side timed out —
  is skipped, so a command either runs or changes nothing);
- the latest ``Published`` snapshot: built on the tick thread at most ``hz`` times a second
  from immutable parts (a JSON string, tuples), swapped in by one reference assignment and
  announced to subscribers, which must not block (the server's only hops onto its loop).

Nothing here knows about asyncio or the cell, so it is tested with plain functions.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from feeder_bt.core.errors import FeederError


@dataclass(frozen=True)
class Outcome:
    """What a command did: ``ok`` and a message for the page; ``status`` is the HTTP
    status the server answers with (200 done, 400 bad value, 403 not the holder,
    409 not in this state, 503 not executed)."""

    ok: bool
    message: str
    status: int = 200

    @classmethod
    def done(cls, message: str) -> Outcome:
        return cls(True, message, 200)

    @classmethod
    def refused(cls, message: str, status: int = 409) -> Outcome:
        return cls(False, message, status)


@dataclass(frozen=True)
class Command:
    name: str
    args: Mapping[str, Any]
    user: str
    future: Future = field(compare=False, repr=False)


@dataclass(frozen=True)
class Message:
    """One line of the message window (thesis Figure 4-5)."""

    seq: int
    t: float
    kind: str
    text: str


@dataclass(frozen=True)
class Published:
    """An immutable view of the cell for the web side: safe to read from any thread."""

    seq: int
    status_json: str
    history: tuple[tuple[float, float, int], ...] = ()   # (up time s, parts/min, queue)
    messages: tuple[Message, ...] = ()

    @property
    def status(self) -> dict[str, Any]:
        """A fresh copy of the status (for tests and the JSON API)."""
        return json.loads(self.status_json)


Snapshot = tuple[dict[str, Any], tuple[tuple[float, float, int], ...], tuple[Message, ...]]
SHUTTING_DOWN = "refused: the controller is shutting down"


class Bridge:
    """Commands in, snapshots out; see the module docstring for who calls what."""

    def __init__(self, execute: Callable[[Command], Outcome], snapshot: Callable[[], Snapshot],
                 hz: float = 5.0, wall: Callable[[], float] = time.monotonic) -> None:
        self._execute, self._snapshot = execute, snapshot
        self.period = 1.0 / hz
        self._wall = wall
        self._queue: queue.SimpleQueue[Command] = queue.SimpleQueue()
        self._lock = threading.Lock()          # only around submit/close: microseconds
        self._closed = False
        self._latest: Published | None = None
        self._subscribers: tuple[Callable[[], None], ...] = ()
        self._next = 0.0
        self._seq = 0
        self._snapshot_failed = False

    # ------------------------------------------------------------------ any thread
    def submit(self, name: str, args: Mapping[str, Any], user: str) -> Future:
        """Queue a command for the tick thread; the future resolves to an ``Outcome``."""
        fut: Future = Future()
        with self._lock:
            if not self._closed:
                self._queue.put(Command(name, dict(args), user, fut))
                return fut
        fut.set_result(Outcome.refused(SHUTTING_DOWN, 503))
        return fut

    def latest(self) -> Published | None:
        return self._latest

    def subscribe(self, fn: Callable[[], None]) -> None:
        """``fn()`` is called on the tick thread after each publish: it must not block."""
        with self._lock:
            self._subscribers = (*self._subscribers, fn)

    def unsubscribe(self, fn: Callable[[], None]) -> None:
        with self._lock:
            self._subscribers = tuple(f for f in self._subscribers if f is not fn)

    @property
    def closed(self) -> bool:
        return self._closed

    # ------------------------------------------------------------------ tick thread
    def pump(self, force: bool = False) -> int:
        """Run the queued commands, then publish if due or if a command ran, and only then
        answer the commands: whoever gets an answer finds its effect in ``latest()``.
        Returns the number of commands executed."""
        done: list[tuple[Future, Outcome]] = []
        while True:
            try:
                cmd = self._queue.get_nowait()
            except queue.Empty:
                break
            if not cmd.future.set_running_or_notify_cancel():
                continue                      # the web side gave up on it: do nothing
            done.append((cmd.future, self._run(cmd)))
        now = self._wall()
        try:
            if force or done or now >= self._next:
                self._next = now + self.period
                self.publish()
        except Exception as e:          # the page goes stale; the cell keeps feeding
            if not self._snapshot_failed:
                print(f"feeder: operator UI: status snapshot failed: {type(e).__name__}: {e}",
                      file=sys.stderr)
                self._snapshot_failed = True
        finally:
            for fut, outcome in done:
                fut.set_result(outcome)
        return len(done)

    def _run(self, cmd: Command) -> Outcome:
        try:
            return self._execute(cmd)
        except FeederError as e:
            return Outcome.refused(f"refused: {e}", 409)
        except Exception as e:          # a bug must not take the cell down with it
            print(f"feeder: operator UI: command {cmd.name} failed: "
                  f"{type(e).__name__}: {e}", file=sys.stderr)
            return Outcome.refused(f"failed: internal error ({type(e).__name__}); see the "
                                   "controller's output", 500)

    def publish(self) -> Published:
        status, history, messages = self._snapshot()
        self._seq += 1
        pub = Published(self._seq, json.dumps({**status, "seq": self._seq},
                                              separators=(",", ":"), default=str),
                        tuple(history), tuple(messages))
        self._latest = pub
        for fn in self._subscribers:
            try:
                fn()
            except Exception:           # a closed loop: the server is going away
                pass
        return pub

    def close(self) -> None:
        """Refuse what is queued and everything submitted from now on (shutdown)."""
        with self._lock:
            self._closed = True
        while True:
            try:
                cmd = self._queue.get_nowait()
            except queue.Empty:
                return
            if cmd.future.set_running_or_notify_cancel():
                cmd.future.set_result(Outcome.refused(SHUTTING_DOWN, 503))
