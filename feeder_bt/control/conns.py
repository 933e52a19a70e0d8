"""Connection limits for every listener: the dashboard, ``feeder replay --ui``, the part
server and the OPC UA server all admit TCP connections through a ``ConnGate``.

A peer on the network must not be able to starve the cell by opening connections and
sending nothing, nor keep the operator who holds control from her Stop. So each listener
has:

- a cap on connections **per address** and a cap **in all**. Over either, the newcomer
  takes the place of the oldest connection that is doing nothing (no request in flight,
  not an activated OPC UA session, not a robot that said who it is; an idle websocket is
  such a connection too) from that address (per-address cap) or from anywhere (cap in
  all). Eviction comes before refusal: held idle connections never keep a newcomer out,
  and behind a reverse proxy, where every user shares one address, one user's idle
  connections cannot keep out another's;
- a **reserve** outside the caps (``ConnLimits.reserve``) for whom the listener vouches
  (``vouch``): the session that holds control (its requests and its websocket), a robot
  that proved who it is. A vouched-for connection is never closed for a newcomer. When
  every capped connection is busy, a newcomer goes *on trial* in the reserve; the
  listener closes it unless its first request is vouched for (``on_trial``);
- optionally (``ConnLimits.lobby``, for listeners that call ``heard`` on every first byte:
  the part server and the OPC UA server; not the web listeners, whose h11 is not told)
  a **lobby** for connections that have not sent a byte yet, outside the caps: they do not
  compete with connections that have spoken. When the lobby is full, the oldest silent
  connection of the address holding the most lobby places is closed. A connection enters
  the caps on its first bytes (``heard``), where it may displace only the oldest idle
  connection that has spoken (from its address, or from anywhere). So a client is closed
  before it speaks only after ``lobby`` newer silent connections from an address holding
  at least as many places as its own: a flood of fewer silent connections than that, even
  from the client's own address and reopened as fast as they close, never closes it;
- a deadline for a connection's first request (``header_s``; the listeners apply it) and
  an idle time-out;
- a listen backlog as large as the system allows (``backlog()``), so a burst waits in the
  kernel instead of being reset;
- cheap refusals: the socket is aborted in the accept callback (no thread, no task, no
  traceback); refusals are counted and told in one summarised line per ``period_s``.

Everything here runs on the listener's own event loop (no locks); ``stats()`` may be read
from any thread (a dict copy).
"""

from __future__ import annotations

import asyncio
import resource
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

SOMAXCONN = "/proc/sys/net/core/somaxconn"


@dataclass(frozen=True)
class ConnLimits:
    """One listener's limits (the defaults suit a cell: a few operators or robots)."""

    total: int = 256            # connections at once, in all
    per_address: int = 32       # ... from one address (a browser opens ~6, plus a websocket)
    header_s: float = 10.0      # a connection's first request must arrive within this
    idle_s: float = 60.0        # a connection silent this long is closed (where it applies)
    period_s: float = 60.0      # at most one summary line of refusals per period
    reserve: int = 0            # connections outside the caps for whom the listener vouches
    lobby: int = 0              # silent connections held outside the caps (0: no lobby)


def backlog(want: int = 4096) -> int:
    """The listen backlog: ``want``, or the system's ceiling if that is lower (Linux
    silently truncates to ``net.core.somaxconn``)."""
    try:
        with open(SOMAXCONN) as f:
            return max(16, min(want, int(f.read().strip())))
    except (OSError, ValueError):
        return min(want, 1024)


def raise_fd_limit(want: int = 65536) -> int:
    """Raise this process's soft limit on open files towards ``want`` (never above the
    hard limit) so that a flood of connections meets our caps, not EMFILE; returns the
    soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = want if hard == resource.RLIM_INFINITY else min(want, hard)
    if soft != resource.RLIM_INFINITY and soft < target:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError):
            pass
    return int(soft)


def peer_ip(transport: Any) -> str:
    peer = transport.get_extra_info("peername")
    return str(peer[0]) if isinstance(peer, tuple) and peer else "?"


CAPPED, TRIAL, RESERVED, LOBBY = "capped", "trial", "reserved", "lobby"


class _Entry:
    """What the gate knows of one connection."""

    __slots__ = ("ip", "busy", "kept", "pool", "spoke")

    def __init__(self, ip: str, busy: Callable[[], bool], pool: str) -> None:
        self.ip, self.busy = ip, busy
        self.spoke = False                             # sent a byte (``heard``)
        self.pool = pool                               # CAPPED, TRIAL, RESERVED, LOBBY
        self.kept: Callable[[], bool] | None = None    # set by vouch(): the reserve's

    def protected(self) -> bool:
        """Never closed for a newcomer: work in progress, or the reserve owner's."""
        try:
            if self.kept is not None and self.kept():
                return True
            return bool(self.busy())
        except Exception:          # a half-made protocol: treat it as idle
            return False


class ConnGate:
    """Admits connections to one listener; see the module docstring.

    ``name`` is how the summary line names the listener (``operator UI``, ``part server``)."""

    def __init__(self, name: str, limits: ConnLimits | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 say: Callable[[str], None] | None = None) -> None:
        self.name, self.limits, self.clock = name, limits or ConnLimits(), clock
        # never more connections than file descriptors to spare (each costs one): the
        # reserve, the caps and the lobby share this budget, the reserve first (the
        # owner's connections), then the caps, the lobby what is left (at least 8)
        budget = max(0, (raise_fd_limit() - 64) // 2)
        self.reserve = max(0, min(self.limits.reserve, self.limits.total, budget - 8))
        self.total = max(8, min(self.limits.total, budget - self.reserve))
        self.trials = (self.reserve + 1) // 2     # of the reserve, at most this on trial
        # silent connections, outside the caps
        spare = budget - self.reserve - self.total
        want = max(0, self.limits.lobby)
        self.lobby = max(min(8, want), min(want, spare))
        self.say = say or (lambda line: print(line, file=sys.stderr, flush=True))
        self._conns: dict[Any, _Entry] = {}       # oldest first
        self._per_ip: Counter[str] = Counter()    # capped connections (not the reserve's)
        self._capped = 0                          # ... in all
        self._vouched = 0                         # in the reserve, vouched for
        self._on_trial = 0                        # in the reserve, on trial
        self._lobby_ip: Counter[str] = Counter()  # in the lobby, per address
        self._in_lobby = 0                        # ... in all
        self.counts: Counter[str] = Counter()     # admitted, refused, evicted, errors, ...
        self._pending: Counter[str] = Counter()   # not yet told
        self._told_at = -1e18
        self._flush: asyncio.TimerHandle | None = None

    # ------------------------------------------------------------------ admitting
    def admit(self, transport: Any, busy: Callable[[], bool]) -> bool:
        """Take ``transport`` in, or abort it (False). ``busy()`` says whether the
        connection is doing something worth keeping when the listener is full.

        Over a cap, the oldest idle connection (from the same address, for the
        per-address cap) is closed to make room: a peer holding idle connections can
        never keep a newcomer out. Only if none is idle does the newcomer go on trial in
        the reserve (the listener must see it vouched for by its first request, else
        close it: ``on_trial``), and only if the reserve is full too is it refused.

        With a lobby, none of that happens here but at its first bytes (``heard``): it
        waits in the lobby, where only another silent connection can take its place."""
        ip = peer_ip(transport)
        if self.lobby:
            if self._in_lobby >= self.lobby and not self._evict_lobby(ip):
                self._refuse(transport, f"{self.lobby} silent connections, none to close")
                return False
            pool = LOBBY
        else:
            pool, why = self._place(ip)
            if pool is None:
                self._refuse(transport, why)
                return False
        self._conns[transport] = _Entry(ip, busy, pool)
        self._count(ip, pool, +1)
        self.counts["admitted"] += 1
        return True

    def _place(self, ip: str) -> tuple[str | None, str]:
        """Where a connection from ``ip`` goes in the caps: CAPPED (after closing an idle
        one if over a cap), TRIAL, or None (refused), with why it is not CAPPED."""
        why = ""
        if self._per_ip[ip] >= self.limits.per_address and not self._evict(CAPPED, ip):
            why = f"over {self.limits.per_address} from one address, all busy"
        elif self._capped >= self.total and not self._evict(CAPPED):
            why = f"{self.total} connections, all busy"
        if not why:
            return CAPPED, ""
        if not self._room(trial=True):
            return None, why
        self.counts["on_trial"] += 1
        return TRIAL, why

    def vouch(self, transport: Any, kept: Callable[[], bool]) -> bool:
        """The listener knows this connection is the reserve owner's (the session that
        holds control, a robot that proved who it is) while ``kept()`` is true: it is
        never closed for a newcomer, and it moves out of the caps into the reserve if
        there is room there. Returns whether it is in the reserve (one on trial is then
        no longer on trial)."""
        entry = self._conns.get(transport)
        if entry is None:
            return False
        entry.kept = kept
        if entry.pool == RESERVED:
            return True
        if entry.pool in (CAPPED, LOBBY) and not self._room(trial=False):
            return False                     # kept from eviction, but where it was
        self._count(entry.ip, entry.pool, -1)
        entry.pool = RESERVED
        self._count(entry.ip, RESERVED, +1)
        return True

    def heard(self, transport: Any) -> bool:
        """The connection sent something: among idle ones it is closed for a newcomer only
        after every one that never said a word. With a lobby, this is where it enters the
        caps (closing the oldest idle connection that has spoken, from its address or from
        anywhere, if over one): a flood of connections that never speak then cannot
        displace it, nor a client mid-handshake (an OPC UA Hello, a robot's first line).
        False: it was refused and aborted here (over the caps, all busy, no reserve), and
        the listener must drop the data."""
        entry = self._conns.get(transport)
        if entry is None:
            return True
        entry.spoke = True
        if entry.pool != LOBBY:
            return True
        self._count(entry.ip, LOBBY, -1)
        del self._conns[transport]           # its age in the caps starts now
        if entry.kept is not None and entry.kept():
            # vouched for while it waited (a robot known by its address, the reserve
            # full then): the reserve if it has room now, else the caps even over them;
            # never a trial, which the listener would close at a first line not a HELLO
            pool: str | None = RESERVED if self._room(trial=False) else CAPPED
        else:
            pool, why = self._place(entry.ip)
        if pool is None:
            self._refuse(transport, why)
            return False
        entry.pool = pool
        self._conns[transport] = entry
        self._count(entry.ip, pool, +1)
        return True

    def unkeep(self, transport: Any) -> None:
        """This connection's latest request was not the reserve owner's (a proxy's
        pooled connection carries everyone's): it may be closed for a newcomer again."""
        entry = self._conns.get(transport)
        if entry is not None:
            entry.kept = None

    def on_trial(self, transport: Any) -> bool:
        """Whether this connection came in on trial and has not been vouched for: the
        listener closes it at its first request that is not the reserve owner's."""
        entry = self._conns.get(transport)
        return entry is not None and entry.pool == TRIAL

    def release(self, transport: Any) -> None:
        """The connection ended (idempotent)."""
        entry = self._conns.pop(transport, None)
        if entry is not None:
            self._count(entry.ip, entry.pool, -1)

    def replace(self, transport: Any, busy: Callable[[], bool]) -> None:
        """The same connection now judged by another ``busy`` (an upgrade to a websocket,
        a robot that said who it is)."""
        entry = self._conns.get(transport)
        if entry is not None:
            entry.busy = busy

    def _count(self, ip: str, pool: str, n: int) -> None:
        if pool == CAPPED:
            self._capped += n
            self._per_ip[ip] += n
            if self._per_ip[ip] <= 0:
                del self._per_ip[ip]
        elif pool == TRIAL:
            self._on_trial += n
        elif pool == LOBBY:
            self._in_lobby += n
            self._lobby_ip[ip] += n
            if self._lobby_ip[ip] <= 0:
                del self._lobby_ip[ip]
        else:
            self._vouched += n

    def _room(self, trial: bool) -> bool:
        """Whether the reserve takes one more (on trial, or vouched for), making room by
        closing the oldest idle one there that is no longer kept, or on trial."""
        if trial and self._on_trial >= self.trials and not self._evict(TRIAL):
            return False
        if self._vouched + self._on_trial < self.reserve:
            return True
        return self._evict(RESERVED) or (not trial and self._evict(TRIAL))

    def _evict(self, pool: str, ip: str | None = None) -> bool:
        """Close the oldest idle connection in ``pool`` (from ``ip``, or from anywhere)
        that is not kept; False if there is none."""
        for silent_only in (True, False):                # the ones that never spoke first
            for transport, entry in self._conns.items():     # oldest first
                if entry.pool != pool or (ip is not None and entry.ip != ip) \
                        or (silent_only and entry.spoke) or entry.protected():
                    continue
                self._close(transport)
                return True
        return False

    def _evict_lobby(self, ip: str) -> bool:
        """The lobby is full and a newcomer from ``ip`` comes: close the oldest silent
        connection of the address that would hold the most lobby places (ties: the one
        whose oldest is oldest), so that one address's flood makes room from itself and
        never from a lighter address. False (refuse the newcomer) if that address is the
        newcomer's own with nothing to close, or nothing can be closed."""
        oldest: dict[str, Any] = {}                      # address -> its oldest closable
        for transport, entry in self._conns.items():     # oldest first
            if entry.pool == LOBBY and entry.ip not in oldest and not entry.protected():
                oldest[entry.ip] = transport
        if not oldest:
            return False
        load = self._lobby_ip.copy()
        load[ip] += 1                                    # the newcomer counts
        victim = max(oldest, key=lambda a: load[a])      # first of the heaviest
        if load[ip] > load[victim]:
            return False
        self._close(oldest[victim])
        return True

    def _close(self, transport: Any) -> None:
        self.release(transport)
        transport.abort()
        self.counts["evicted"] += 1
        self.note("an idle connection closed for a newcomer")

    def _refuse(self, transport: Any, why: str) -> None:
        transport.abort()
        self.counts["refused"] += 1
        self.note(f"refused: {why}")

    # ------------------------------------------------------------------ telling
    def note(self, what: str) -> None:
        """Count ``what``; one summary line per period says how many of each."""
        self._pending[what] += 1
        now = self.clock()
        if now - self._told_at >= self.limits.period_s:
            self.tell()
        elif self._flush is None:
            try:
                loop = asyncio.get_running_loop()
            except RuntimeError:
                return
            self._flush = loop.call_later(self._told_at + self.limits.period_s - now,
                                          self.tell)

    def tell(self) -> None:
        """Print the summary line now (if anything happened since the last one)."""
        self._flush = None
        if not self._pending:
            return
        self._told_at = self.clock()
        parts = ", ".join(f"{n} {what}" for what, n in sorted(self._pending.items()))
        self._pending.clear()
        lobby = f", {self._in_lobby} of {self.lobby} silent" if self.lobby else ""
        self.say(f"feeder: {self.name}: {parts} (in {len(self._conns)} open{lobby}; at most "
                 f"{self.total}, {self.limits.per_address} per address)")

    def open_count(self) -> int:
        return len(self._conns)

    def stats(self) -> dict[str, int]:
        return {"open": len(self._conns), "addresses": len(self._per_ip),
                "reserve_open": self._vouched + self._on_trial, "lobby_open": self._in_lobby,
                **dict(self.counts)}

    def loop_errors(self, loop: asyncio.AbstractEventLoop) -> None:
        """Make ``loop``'s unhandled errors (``socket.accept() out of system resource``
        when the process runs out of descriptors, a connection reset mid-callback) one
        counted word in the summary, never a traceback per connection."""
        def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
            exc = context.get("exception")
            what = context.get("message", "error")
            if exc is not None:
                what = f"{what} ({type(exc).__name__})"
            self.counts["errors"] += 1
            self.note(what[:80])

        loop.set_exception_handler(handler)


class _ToGate:
    """A logging filter: a library's per-connection warnings (uvicorn's "Invalid HTTP
    request received.", asyncua's "Refusing connection ...") become counted words in the
    summary line of the gate serving the loop that logged them, instead of one line each."""

    def __init__(self) -> None:
        self.gates: dict[int, ConnGate] = {}

    def filter(self, record: Any) -> bool:
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return True
        gate = self.gates.get(id(loop))
        if gate is None:
            return True
        gate.note(str(record.getMessage()).splitlines()[0][:60])
        return False


_FILTERS: dict[str, _ToGate] = {}


def quiet_logger(name: str, gate: ConnGate) -> Callable[[], None]:
    """Route logger ``name``'s records made on the running loop into ``gate``'s summary;
    returns the function that undoes it (call it on the same loop)."""
    import logging
    f = _FILTERS.get(name)
    if f is None:
        f = _FILTERS[name] = _ToGate()
        logging.getLogger(name).addFilter(f)
    key = id(asyncio.get_running_loop())
    f.gates[key] = gate
    return lambda: f.gates.pop(key, None) and None
