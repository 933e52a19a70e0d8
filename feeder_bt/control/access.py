"""Who may reach an operator surface at all, and what is recorded when they are refused
. The web UI uses all of it; any other operator surface the project adds (an
OPC UA server, the part server) must use the same pieces: ``Settings`` from the users file,
``parse_body`` for whatever a client sends, ``Gate`` (or ``host_allowed``) before anything
else, ``guard.LoginGuard`` for passwords, and ``AccessRecorder`` for the event log.

Nothing here touches the cell; the recorder hands its events to a callable (the bridge).
"""

from __future__ import annotations

import ipaddress
import json
import math
import re
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from feeder_bt.control.users import UsersError

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
WILDCARDS = ("", "0.0.0.0", "::")
MAX_DEPTH = 4                 # the page's bodies are flat objects
MAX_NUMBER_CHARS = 32         # digits, sign, point and exponent of one JSON number
MAX_HOST_CHARS = 255


# ---------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class Settings:
    """The UI's access settings, kept in the users file's ``settings`` object and set with
    ``feeder users set KEY VALUE...``."""

    hosts: tuple[str, ...] = ()            # Host names answered besides the bound address
    proxies: tuple[str, ...] = ()          # addresses whose X-Forwarded-* headers are believed
    session_lifetime_s: float = 12 * 3600.0   # a session ends this long after its login
    session_idle_s: float = 8 * 3600.0     # ... or after this long without a request
    control_grace_s: float = 60.0          # control is free this long after its holder left
    readable_users_file: str = "warn"      # or "refuse": a users file others may read
    camera_fps: float = 2.0                # the camera view's most frames a second

    @classmethod
    def of(cls, raw: Mapping[str, Any], where: str = "settings") -> Settings:
        """From the users file's ``settings``; UsersError (one line) naming a bad key."""
        out: dict[str, Any] = {}
        for key, value in raw.items():
            if key not in SETTINGS:
                raise UsersError(f"{where}.{key}: unknown setting (one of: "
                                 f"{', '.join(SETTINGS)})")
            out[key] = parse_setting(key, value, where)
        return cls(**out)

    def as_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


SETTINGS = {
    "hosts": "Host names (or addresses) the UI answers to besides the bound address",
    "proxies": "addresses of reverse proxies whose X-Forwarded-For/-Proto are believed",
    "session_lifetime_s": "seconds after a login that its session ends, however busy",
    "session_idle_s": "seconds without a request that end a session",
    "control_grace_s": "seconds control stays with a holder whose every page is closed",
    "readable_users_file": "warn or refuse when others may read the users file",
    "camera_fps": "the most frames a second the dashboard's camera view shows (0.2-10)",
}
_HOST_RE = re.compile(r"[a-z0-9]([a-z0-9.-]{0,252})?|\[?[0-9a-f:.]+\]?")


def parse_setting(key: str, value: Any, where: str = "settings") -> Any:
    """One setting's value, checked (a list from the command line or the file)."""
    here = f"{where}.{key}"
    if key in ("hosts", "proxies"):
        items = [value] if isinstance(value, str) else value
        if not isinstance(items, list | tuple) or not all(isinstance(v, str) for v in items):
            raise UsersError(f"{here}: a list of names or addresses")
        out = []
        for item in items:
            v = item.strip().lower().strip("[]")
            if key == "proxies":
                try:
                    v = str(ipaddress.ip_address(v))
                except ValueError:
                    raise UsersError(f"{here}: {item!r} is not an IP address") from None
            elif not _HOST_RE.fullmatch(v) or v in WILDCARDS:
                raise UsersError(f"{here}: {item!r} is not a host name or address")
            out.append(v)
        return tuple(dict.fromkeys(out))
    if key == "readable_users_file":
        if value not in ("warn", "refuse"):
            raise UsersError(f"{here}: warn or refuse, got {value!r}")
        return value
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    if key == "camera_fps":
        try:
            fps = float(value)
        except (TypeError, ValueError, OverflowError):
            fps = math.nan
        if isinstance(value, bool) or not 0.2 <= fps <= 10.0:
            raise UsersError(f"{here}: frames a second between 0.2 and 10, got {value!r}")
        return fps
    if isinstance(value, bool) or not isinstance(value, int | float | str) \
            or (isinstance(value, str) and len(value) > MAX_NUMBER_CHARS):
        raise UsersError(f"{here}: seconds, a number, got {value!r}")
    try:
        seconds = float(value)
    except ValueError:
        raise UsersError(f"{here}: seconds, a number, got {value!r}") from None
    if not 1.0 <= seconds <= 366 * 86400.0:
        raise UsersError(f"{here}: seconds between 1 and one year, got {value!r}")
    return seconds


# ---------------------------------------------------------------------------- bodies


class BadBody(ValueError):
    """A request body that is not what the page sends: a 400 with this one line."""


def _too_deep(doc: Any, limit: int) -> bool:
    """True if ``doc`` nests arrays and objects more than ``limit`` deep (no recursion)."""
    stack = [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, dict | list):
            if depth > limit:
                return True
            items = value.values() if isinstance(value, dict) else value
            stack.extend((v, depth + 1) for v in items if isinstance(v, dict | list))
    return False


def _number(text: str, convert: Callable[[str], Any]) -> Any:
    if len(text) > MAX_NUMBER_CHARS:         # bounded before conversion, not after
        raise BadBody(f"a number in the body is too long (at most {MAX_NUMBER_CHARS} "
                      "characters)")
    value = convert(text)
    if isinstance(value, float) and not math.isfinite(value):      # 1e999 is infinity
        raise BadBody("a number in the body is out of range")
    return value


def _constant(text: str) -> Any:
    raise BadBody(f"{text} is not a JSON number")


def parse_body(raw: bytes) -> dict[str, Any]:
    """The JSON object in ``raw``; ``BadBody`` with one line for anything else."""
    try:
        text = raw.decode("utf-8")
        doc = json.loads(text or "{}", parse_int=lambda s: _number(s, int),
                         parse_float=lambda s: _number(s, float), parse_constant=_constant)
    except BadBody:
        raise
    except RecursionError:                    # the C parser stops itself, cleanly
        raise BadBody("the body is nested too deeply") from None
    except (ValueError, TypeError, OverflowError):   # JSONDecodeError, UnicodeDecodeError
        raise BadBody("the body is not valid JSON") from None
    if not isinstance(doc, dict):
        raise BadBody("the body must be a JSON object")
    if _too_deep(doc, MAX_DEPTH):
        raise BadBody("the body is nested too deeply")
    return doc


# ---------------------------------------------------------------------------- hosts


def host_name(header: str | None) -> str | None:
    """The name in a ``Host`` header (``name``, ``name:port``, ``[v6]:port``), lower case;
    None if it is missing or not a host."""
    if not header or len(header) > MAX_HOST_CHARS:
        return None
    h = header.strip().lower()
    if h.startswith("["):
        name, _, rest = h[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else rest
    else:
        name, _, port = h.partition(":") if h.count(":") == 1 else (h, "", "")
    if port and not port.isdigit():
        return None
    return name if name and _HOST_RE.fullmatch(name) else None


def allowed_hosts(bound: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """The bound address, the loopback names when it is loopback or a wildcard (a browser on
    this machine), and the names the operator added; never the wildcard itself."""
    bound = bound.strip("[]").lower()
    names = set(extra)
    if bound not in WILDCARDS:
        names.add(bound)
    if bound in WILDCARDS or bound == "localhost" or _is_loopback(bound):
        names.update(LOOPBACK_NAMES)
    return frozenset(names)


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def client_address(scope: Scope, proxies: Iterable[str]) -> tuple[str, str | None]:
    """(client address, forwarded scheme or None): ``X-Forwarded-For`` and
    ``X-Forwarded-Proto`` count only when the connection comes from a named proxy, and
    then the address is the right-most one that is not itself a proxy."""
    peer = scope["client"][0] if scope.get("client") else "?"
    trusted = set(proxies)
    if peer not in trusted:
        return peer, None
    headers = Headers(scope=scope)
    hops = [h.strip() for h in ",".join(headers.getlist("x-forwarded-for")).split(",")
            if h.strip()]
    addr = peer
    for hop in reversed(hops):
        addr = hop
        if hop not in trusted:
            break
    proto = headers.get("x-forwarded-proto", "").split(",")[0].strip().lower()
    return addr[:64], proto if proto in ("http", "https") else None


class Gate:
    """The outermost layer: forwarded headers from a named proxy only, then the Host
    allow-list, before routing, cookies or bodies are looked at (a DNS-rebinding page
    sends its own name as Host and is refused here)."""

    def __init__(self, app: ASGIApp, hosts: Callable[[], frozenset[str]],
                 proxies: Callable[[], tuple[str, ...]],
                 refused: Callable[[str, str], None]) -> None:
        self.app, self.hosts, self.proxies, self.refused = app, hosts, proxies, refused

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        addr, proto = client_address(scope, self.proxies())
        scope = {**scope, "client": (addr, 0)}
        if proto is not None:
            secure = proto == "https"
            scope["scheme"] = ("https" if secure else "http") if scope["type"] == "http" \
                else ("wss" if secure else "ws")
        raw_host = Headers(scope=scope).get("host")
        name = host_name(raw_host)
        if name is None or name not in self.hosts():
            self.refused(addr, f"unknown Host {(raw_host or '')[:64]!r}")
            if scope["type"] == "websocket":
                await send({"type": "websocket.close", "code": 1008})
                return
            body = b'{"ok":false,"error":"refused: this server does not answer to that Host"}'
            await send({"type": "http.response.start", "status": 400, "headers": [
                (b"content-type", b"application/json"), (b"cache-control", b"no-store"),
                (b"content-length", str(len(body)).encode())]})
            await send({"type": "http.response.body", "body": body})
            return
        await self.app(scope, receive, send)


# ---------------------------------------------------------------------------- the record


class AccessRecorder:
    """Hands access events (failed logins, lock-outs, refusals, control released) to the
    event log, and prints lock-outs and forced releases on standard error.

    A flood must not flood the log: at most ``budget`` events per ``window_s``; the rest are
    counted and reported as one ``access_suppressed`` event when the window ends.
    """

    PRINTED = frozenset({"login_locked", "control_released", "session_ended"})

    def __init__(self, submit: Callable[[str, str, dict[str, Any]], Any], budget: int = 120,
                 window_s: float = 60.0, clock: Callable[[], float] = time.monotonic,
                 echo: bool = True) -> None:
        self.submit, self.budget, self.window_s, self.clock = submit, budget, window_s, clock
        self.echo = echo
        self._start = clock()
        self._used = self._suppressed = 0

    def __call__(self, kind: str, user: str = "-", **data: Any) -> None:
        now = self.clock()
        if now - self._start >= self.window_s:
            if self._suppressed:
                self.submit("access_suppressed", "-", {"count": self._suppressed,
                                                       "window_s": self.window_s})
            self._start, self._used, self._suppressed = now, 0, 0
        if self._used >= self.budget:
            self._suppressed += 1
            return
        self._used += 1
        self.submit(kind, user, data)
        if self.echo and kind in self.PRINTED:
            words = " ".join(f"{k}={v}" for k, v in data.items())
            print(f"feeder: operator UI: {kind} {user} {words}".rstrip(), file=sys.stderr)
