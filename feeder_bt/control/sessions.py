"""Who is logged in, who holds control, and who must wait before trying a password again.

Web-thread state only: nothing here touches the cell, and everything runs on the server's
one asyncio loop, so there are no locks. Time comes from an injectable clock so the tests
can step it instead of sleeping.
"""

from __future__ import annotations

import math
import secrets
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

SESSION_IDLE_S = 8 * 3600.0     # a session without a request this long ends
SESSION_LIFETIME_S = 12 * 3600.0  # and every session ends this long after its login
CONTROL_GRACE_S = 60.0          # control outlives its holder's last open page this long


@dataclass(eq=False)
class Session:
    token: str
    user: str
    ip: str
    created: float
    seen: float                     # the last request (websocket pushes do not count)
    secret: str = ""                # the user's password hash at login (see UsersFile)
    conns: int = 0                  # open websockets (pages showing the dashboard)
    left: float = 0.0               # when the last of them closed


class Sessions:
    """Session tokens (random, 256 bits) handed out at login and kept only in memory:
    restarting the controller logs everybody out. A session ends ``idle_s`` after its last
    request and ``lifetime_s`` after its login, whichever comes first."""

    def __init__(self, idle_s: float = SESSION_IDLE_S,
                 clock: Callable[[], float] = time.monotonic,
                 lifetime_s: float = SESSION_LIFETIME_S) -> None:
        self.idle_s, self.clock, self.lifetime_s = idle_s, clock, lifetime_s
        self._by_token: dict[str, Session] = {}

    def create(self, user: str, ip: str = "", secret: str = "") -> Session:
        now = self.clock()
        s = Session(secrets.token_urlsafe(32), user, ip, now, now, secret, 0, now)
        self._by_token[s.token] = s
        return s

    def _expired(self, s: Session, now: float) -> bool:
        return now - s.seen > self.idle_s or now - s.created > self.lifetime_s

    def peek(self, token: str | None) -> Session | None:
        """The live session for ``token`` without marking it as used (a push, not a
        request), or None."""
        if not token:
            return None
        s = self._by_token.get(token)
        if s is None:
            return None
        if self._expired(s, self.clock()):
            del self._by_token[token]
            return None
        return s

    def get(self, token: str | None) -> Session | None:
        """The live session for ``token`` (marked as seen now: a request), or None."""
        s = self.peek(token)
        if s is not None:
            s.seen = self.clock()
        return s

    def all(self) -> list[Session]:
        return list(self._by_token.values())

    def end(self, token: str | None) -> Session | None:
        return self._by_token.pop(token, None) if token else None

    def end_user(self, user: str) -> list[Session]:
        gone = [s for s in self._by_token.values() if s.user == user]
        for s in gone:
            del self._by_token[s.token]
        return gone

    def prune(self) -> list[Session]:
        """Remove and return the sessions idle too long or past their lifetime."""
        now = self.clock()
        gone = [s for s in self._by_token.values() if self._expired(s, now)]
        for s in gone:
            del self._by_token[s.token]
        return gone

    def users(self) -> list[str]:
        """Distinct names of the users logged in now."""
        return sorted({s.user for s in self._by_token.values()})

    def __len__(self) -> int:
        return len(self._by_token)


class Control:
    """The control token (thesis Figures 4-2, 4-4): held by at most one session at a time.

    Bound to a session, not to a name: the same user in a second browser only observes.
    When the holder has no page open (every websocket closed) and makes no request for
    ``grace_s``, control is free again (``expire``); the others are shown the count-down.
    """

    def __init__(self, grace_s: float = CONTROL_GRACE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.holder: Session | None = None
        self.grace_s, self.clock = grace_s, clock

    def free_in(self) -> float | None:
        """Seconds until control is free because its holder left; None while they are
        here (a page open) or nobody holds it."""
        h = self.holder
        if h is None or h.conns > 0:
            return None
        return max(0.0, max(h.left, h.seen) + self.grace_s - self.clock())

    def expire(self) -> Session | None:
        """Free control if its holder has been gone ``grace_s``; returns that holder."""
        left = self.free_in()
        if left is not None and left <= 0:
            gone, self.holder = self.holder, None
            return gone
        return None

    def take(self, session: Session) -> tuple[bool, str]:
        if self.holder is None or self.holder.token == session.token:
            self.holder = session
            return True, "you have control"
        return False, f"refused: {self.holder.user} has control; they must release it first"

    def release(self, session: Session) -> tuple[bool, str]:
        if self.holder is not None and self.holder.token == session.token:
            self.holder = None
            return True, "control released"
        return False, "refused: you do not have control"

    def drop(self, token: str) -> bool:
        """The holder's session ended (logout, expiry, user removed): control is free."""
        if self.holder is not None and self.holder.token == token:
            self.holder = None
            return True
        return False

    def is_holder(self, session: Session) -> bool:
        return self.holder is not None and self.holder.token == session.token

    def refusal(self, session: Session) -> str:
        """Why ``session`` may not operate the cell, in words for the page."""
        if self.holder is None:
            return "refused: take control first (nobody has it)"
        if self.holder.user == session.user:
            return ("refused: you have control in another session; release it there or "
                    "log out of it first")
        return f"refused: {self.holder.user} has control"

    def state_for(self, session: Session) -> dict[str, str | int | None]:
        """The indicator: ``available``, ``you``, or ``other`` with the holder's name (and
        ``same_user: true`` when the holder is this user's other session), and ``free_in`` (whole
        seconds) when the holder has left."""
        if self.holder is None:
            return {"state": "available", "holder": None}
        left = self.free_in()
        extra = {} if left is None else {"free_in": math.ceil(left)}
        if self.holder.token == session.token:
            return {"state": "you", "holder": session.user, **extra}
        if self.holder.user == session.user:            # her other tab, browser or PC
            extra["same_user"] = True
        return {"state": "other", "holder": self.holder.user, **extra}


@dataclass
class _Record:
    failures: int = 0
    locked_until: float = 0.0
    last: float = 0.0


class LoginLimiter:
    """Failed logins, counted per key (``user:NAME`` and ``ip:ADDR``).

    The first ``free - 1`` failures in a row cost nothing; the ``free``-th locks the key for
    ``base_s``, and every further failure doubles the lock, up to ``max_s``. While a key is
    locked, attempts are refused before the password is even checked (HTTP 429), and they
    do not extend the lock. A success clears its keys; a key forgets its failures after
    ``forget_s`` without one. At most one check per key is in flight at a time, so firing
    many guesses at once gains nothing.
    """

    def __init__(self, free: int = 3, base_s: float = 1.0, max_s: float = 300.0,
                 forget_s: float = 3600.0, clock: Callable[[], float] = time.monotonic,
                 max_keys: int = 10000) -> None:
        self.free, self.base_s, self.max_s, self.forget_s = free, base_s, max_s, forget_s
        self.clock, self.max_keys = clock, max_keys
        self._records: dict[str, _Record] = {}
        self._busy: set[str] = set()

    def _record(self, key: str, now: float) -> _Record | None:
        r = self._records.get(key)
        if r is not None and now - r.last > self.forget_s and now >= r.locked_until:
            del self._records[key]
            return None
        return r

    def locked_for(self, keys: Iterable[str]) -> float:
        """Seconds until every key in ``keys`` may try again (0 if none is locked)."""
        now = self.clock()
        wait = 0.0
        for key in keys:
            r = self._record(key, now)
            if r is not None:
                wait = max(wait, r.locked_until - now)
        return wait

    def begin(self, keys: Iterable[str]) -> bool:
        """Mark a check in flight; False if one already is for any of ``keys``."""
        keys = tuple(keys)
        if any(k in self._busy for k in keys):
            return False
        self._busy.update(keys)
        return True

    def end(self, keys: Iterable[str]) -> None:
        self._busy.difference_update(keys)

    def failure(self, keys: Iterable[str]) -> float:
        """Count a failed login; returns the lock it caused (seconds, 0 for none)."""
        now = self.clock()
        lock = 0.0
        for key in keys:
            r = self._record(key, now) or _Record()
            self._records.pop(key, None)          # re-inserted last: oldest stay first
            self._records[key] = r
            r.failures += 1
            r.last = now
            if r.failures >= self.free:
                delay = min(self.max_s, self.base_s * 2.0 ** (r.failures - self.free))
                r.locked_until = max(r.locked_until, now + delay)
                lock = max(lock, r.locked_until - now)
        while len(self._records) > self.max_keys:       # bound memory under a flood:
            del self._records[next(iter(self._records))]     # the least recent, O(1)
        return lock

    def success(self, keys: Iterable[str]) -> None:
        for key in keys:
            self._records.pop(key, None)


def retry_after(seconds: float) -> int:
    """Whole seconds for a ``Retry-After`` header and the page's message (at least 1)."""
    return max(1, math.ceil(seconds))
