"""Slowing password guessing without locking the rightful user out.

Counting failures per user name lets anyone keep that user out. Instead, a login attempt is
judged by where it comes from:

- **A browser that has logged in as this user before** (it holds a ``known`` cookie the
  server signed at that login, bound to the user's current password) is judged on its own:
  only wrong passwords *from that browser* lock it. Nobody else's guesses touch it, even from
  the same address (everyone on one machine, or behind one proxy, shares an address).
- **Any other attempt** counts against its address (many names tried from one address) and
  against the name-and-address pair (one name guessed from one address); each locks for
  ``base_s`` after its free mistakes and doubles with every further one, up to ``max_s``.
- **A name under attack** (``name_free`` failures from anywhere within ``forget_s``) is
  slowed for everyone without a known cookie to one attempt per ``name_gap_s``: a fixed,
  short wait, never a lock that grows; an address where the user logged in before is not
  slowed.

Web-thread state only (one asyncio loop, no locks); time from an injectable clock.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass

from feeder_bt.control.sessions import LoginLimiter

KNOWN_COOKIE = "feeder_known_"          # + the user name; one cookie per user per browser
KNOWN_MAX_AGE_S = 90 * 86400


@dataclass(frozen=True)
class Attempt:
    """One login attempt as the guard sees it."""

    name: str
    ip: str
    known: str | None = None            # the ``known`` cookie's value for ``name``, if any

    def keys(self, trusted: bool) -> tuple[str, ...]:
        if trusted:
            return (f"dev:{self.name}:{self.known}",)
        return (f"ip:{self.ip}", f"pair:{self.name}|{self.ip}")


@dataclass(frozen=True)
class Verdict:
    """Whether to check the password now; if not, how long to wait and why."""

    wait_s: float
    why: str = ""                       # "address", "name and address", "browser", "name"
    trusted: bool = False


class LoginGuard:
    """See the module docstring. ``secret_of(name)`` is the user's stored hash (None for an
    unknown name): a ``known`` cookie is void once the password changes."""

    def __init__(self, secret_of: Callable[[str], str | None], *, pair_free: int = 3,
                 ip_free: int = 10, device_free: int = 5, base_s: float = 1.0,
                 max_s: float = 300.0, forget_s: float = 3600.0, name_free: int = 10,
                 name_gap_s: float = 5.0, known_s: float = KNOWN_MAX_AGE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.secret_of, self.clock = secret_of, clock
        self.pairs = LoginLimiter(pair_free, base_s, max_s, forget_s, clock)
        self.addrs = LoginLimiter(ip_free, base_s, max_s, forget_s, clock)
        self.devices = LoginLimiter(device_free, base_s, max_s, forget_s, clock)
        self.name_free, self.name_gap_s, self.forget_s = name_free, name_gap_s, forget_s
        self.known_s = known_s
        self._key = secrets.token_bytes(32)    # in memory: a restart voids every cookie
        self._names: dict[str, tuple[int, float]] = {}     # failures, last failure
        self._good: dict[tuple[str, str], float] = {}      # (name, address): last login

    # ------------------------------------------------------------------ known browsers
    def _mac(self, name: str, issued: int) -> str:
        secret = self.secret_of(name) or ""
        msg = f"{name}\0{issued}\0{hashlib.sha256(secret.encode()).hexdigest()}".encode()
        return hmac.new(self._key, msg, hashlib.sha256).hexdigest()[:40]

    def issue(self, name: str) -> str:
        """The ``known`` cookie's value after a good login as ``name``."""
        issued = int(self.clock())
        return f"{issued}.{self._mac(name, issued)}"

    def trusted(self, a: Attempt) -> bool:
        """True if ``a`` carries a valid, unexpired ``known`` cookie for its name."""
        if not a.known or len(a.known) > 80 or self.secret_of(a.name) is None:
            return False
        issued_s, _, mac = a.known.partition(".")
        if not issued_s.isdigit() or len(issued_s) > 15:
            return False
        issued = int(issued_s)
        if not 0 <= self.clock() - issued <= self.known_s:
            return False
        return hmac.compare_digest(mac, self._mac(a.name, issued))

    # ------------------------------------------------------------------ judging
    def _name_wait(self, a: Attempt, now: float) -> float:
        rec = self._names.get(a.name)
        if rec is None or rec[0] < self.name_free or now - rec[1] > self.forget_s:
            return 0.0
        if now - self._good.get((a.name, a.ip), -1e18) <= self.known_s:
            return 0.0                      # where this user logged in before: not slowed
        return max(0.0, rec[1] + self.name_gap_s - now)

    def check(self, a: Attempt) -> Verdict:
        """May ``a``'s password be checked now?"""
        now = self.clock()
        if self.trusted(a):
            wait = self.devices.locked_for(a.keys(True))
            return Verdict(wait, "browser" if wait > 0 else "", True)
        ip_key, pair_key = a.keys(False)
        waits = [(self.pairs.locked_for([pair_key]), "name and address"),
                 (self._name_wait(a, now), "name")]
        if now - self._good.get((a.name, a.ip), -1e18) > self.known_s:
            waits.append((self.addrs.locked_for([ip_key]), "address"))
        wait, why = max(waits)
        return Verdict(wait, why if wait > 0 else "")

    def begin(self, a: Attempt, trusted: bool) -> bool:
        """At most one password check in flight per key (guesses fired at once gain
        nothing)."""
        return self.pairs.begin(a.keys(trusted))

    def end(self, a: Attempt, trusted: bool) -> None:
        self.pairs.end(a.keys(trusted))

    def failure(self, a: Attempt, trusted: bool) -> list[tuple[str, float]]:
        """Count a wrong password; returns the locks it caused: [(why, seconds)]."""
        now = self.clock()
        if trusted:
            lock = self.devices.failure(a.keys(True))
            return [("browser", lock)] if lock > 0 else []
        ip_key, pair_key = a.keys(False)
        locks = [("name and address", self.pairs.failure([pair_key])),
                 ("address", self.addrs.failure([ip_key]))]
        failures, last = self._names.pop(a.name, (0, now))
        failures = 1 if now - last > self.forget_s else failures + 1
        self._names[a.name] = (failures, now)   # re-inserted last: the oldest stay first
        if failures == self.name_free:
            locks.append(("name", self.name_gap_s))
        _bound(self._names)
        return [(why, s) for why, s in locks if s > 0]

    def success(self, a: Attempt, trusted: bool) -> None:
        """A good password: clear its counts and remember the address as known-good. A
        known browser clears only its own count: a guesser at the same address stays
        locked."""
        if trusted:
            self.devices.success(a.keys(True))
        else:
            self.pairs.success(a.keys(False)[1:])
            self.addrs.success(a.keys(False)[:1])
        self._names.pop(a.name, None)
        self._good.pop((a.name, a.ip), None)
        self._good[(a.name, a.ip)] = self.clock()
        _bound(self._good)

    def known(self, a: Attempt) -> bool:
        """A known browser, or the address this user logged in from before: served before
        strangers when password checks are scarce."""
        if self.trusted(a):
            return True
        return self.clock() - self._good.get((a.name, a.ip), -1e18) <= self.known_s


MAX_KEYS = 10000


def _bound(d: dict) -> None:
    """Keep at most ``MAX_KEYS`` entries, dropping the least recently written: entries are
    re-inserted when written, so the oldest is first (O(1) a drop; never a sort on the
    event loop under a flood of names)."""
    while len(d) > MAX_KEYS:
        del d[next(iter(d))]


def set_login_cookies(resp, request, session_cookie: str, token: str, name: str,
                      known: str) -> None:
    """A login's two cookies: the session (the whole site) and the known-browser token
    ``LoginGuard.issue`` made (only ``/api/login`` reads it); both strict same-site,
    invisible to scripts, and over HTTPS only when the page came that way."""
    secure = request.url.scheme == "https"
    resp.set_cookie(session_cookie, token, httponly=True, samesite="strict", path="/",
                    secure=secure)
    resp.set_cookie(KNOWN_COOKIE + name, known, max_age=KNOWN_MAX_AGE_S, httponly=True,
                    samesite="strict", path="/api/login", secure=secure)
