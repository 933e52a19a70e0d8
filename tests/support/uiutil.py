"""The operator UI's test rigs, one of each, shared by the UI's test files (over HTTP, in
a browser, in-process): a fake wall clock, users made the administrator's way, a real
`feeder ... --ui` in a child process, one user's HTTP session, and the simulated lenses
cell in virtual time (bare, or served with its camera and belt views), and the UI's app
driven in-process with its own browser stand-in and a users file of cheap hashes.

Chromium and Playwright are in browser_helpers.py."""

from __future__ import annotations

import asyncio
import json
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from concurrent.futures import Future
from http.cookiejar import CookieJar
from pathlib import Path
from typing import Any

from feeder_bt.config import load_scenario
from feeder_bt.control.bridge import Command, Outcome
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.operate import CellOps
from feeder_bt.control.status import CellPanel
from feeder_bt.control.ticker import Ticker
from feeder_bt.control.users import FORMAT, UsersFile, hash_password
from feeder_bt.core.clock import SimClock
from feeder_bt.sim.devices import make_sim_hal
from feeder_bt.ui.app import OperatorUi
from feeder_bt.ui.server import UiApp

ROOT = Path(__file__).resolve().parents[2]
LENSES = ROOT / "scenarios" / "lenses.yaml"
PASSWORD = "alice-secret-1"          # alice's, where she is the only user


class FakeClock:
    """A wall clock that moves only when a test sets ``t``."""

    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def feeder_cli(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess:
    """`feeder ARGS...` in a child process, from the repository's root."""
    return subprocess.run([sys.executable, "-m", "feeder_bt.cli", *args], input=stdin,
                          capture_output=True, text=True, timeout=120, cwd=ROOT)


def make_users(path: Path, users: dict[str, str]) -> Path:
    """The users file, made the way an administrator would: `feeder users add`."""
    for name, password in users.items():
        res = feeder_cli("users", "add", name, "--password-stdin", "--users", str(path),
                         stdin=password + "\n")
        assert res.returncode == 0, res.stderr
    return path


class UiProcess:
    """`feeder ARGS...` serving a UI on 127.0.0.1:0 in a child process; the port the system
    chose is read from the line it prints (``<announce>: http://127.0.0.1:PORT/``)."""

    def __init__(self, tmp: Path, args: list[str], announce: str,
                 timeout_s: float = 60.0) -> None:
        self.out, self.err = tmp / "stdout.txt", tmp / "stderr.txt"
        with self.out.open("w") as out, self.err.open("w") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "feeder_bt.cli", *args],
                                         stdout=out, stderr=err, cwd=ROOT)
        pattern = re.compile(re.escape(announce) + r": (http://127\.0\.0\.1:\d+/)")
        end = time.monotonic() + timeout_s
        self.url = ""
        while not self.url:
            m = pattern.search(self.err.read_text())
            if m:
                self.url = m.group(1)
            elif self.proc.poll() is not None or time.monotonic() > end:
                self.kill()
                raise AssertionError(f"feeder {args[0]} did not serve: {self.err.read_text()}")
            else:
                time.sleep(0.05)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)


class FeederUi(UiProcess):
    """`feeder run scenarios/lenses.yaml --ui 127.0.0.1:0 ...`: the simulated cell in real
    time, with its report written when it is stopped."""

    def __init__(self, tmp: Path, users: Path, *extra: str) -> None:
        self.report = tmp / "report.json"
        super().__init__(tmp, ["run", str(LENSES), "--ui", "127.0.0.1:0", "--users",
                               str(users), "--duration", "600", "--no-db", "--view", "none",
                               "--report", str(self.report), *extra], "operator UI")

    def stop(self, timeout: float = 60.0) -> dict[str, Any]:
        """Ctrl-C: the cell stops in order and the report is written."""
        self.proc.send_signal(signal.SIGINT)
        rc = self.proc.wait(timeout)
        assert rc == 0, self.err.read_text()
        return json.loads(self.report.read_text())


class ReplayUi(UiProcess):
    """`feeder replay DB --ui 127.0.0.1:0 --users FILE`: a past run's trees, served to
    signed-in users (alice, ``PASSWORD``, unless ``users`` is given)."""

    def __init__(self, tmp: Path, db: Path, users: Path | None = None) -> None:
        if users is None:
            users = tmp / "replay-users.json"
            UsersFile(users).add("alice", PASSWORD)
        self.users = users
        super().__init__(tmp, ["replay", str(db), "--ui", "127.0.0.1:0", "--users",
                               str(users)], "replay UI", 30.0)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


class Client:
    """One user's HTTP session (cookie jar), as the page would make its requests."""

    def __init__(self, base: str, headers: dict[str, str] | None = None) -> None:
        self.base = base
        self.headers = dict(headers or {})   # sent with every request (X-Forwarded-For)
        self.jar = CookieJar()
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(self.jar))

    def call(self, path: str, body: Any = None, headers: dict[str, str] | None = None,
             raw: bytes | None = None) -> tuple[int, dict[str, Any], Any]:
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        hdrs = {"Content-Type": "application/json"} if data is not None else {}
        req = urllib.request.Request(self.base + path, data=data,
                                     headers={**hdrs, **self.headers, **(headers or {})})
        try:
            with self.opener.open(req, timeout=20) as resp:
                return resp.status, json.loads(resp.read()), resp.headers
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read()), e.headers

    def login(self, user: str, password: str) -> tuple[int, dict[str, Any], Any]:
        return self.call("api/login", {"user": user, "password": password})

    def status(self) -> dict[str, Any]:
        code, body, _ = self.call("api/status")
        assert code == 200, body
        return body["status"]

    def command(self, name: str, **args: Any) -> tuple[int, dict[str, Any]]:
        code, body, _ = self.call("api/command", {"command": name, **args})
        return code, body

    @property
    def cookie(self) -> str:
        return "; ".join(f"{c.name}={c.value}" for c in self.jar)


class SimRig:
    """A real Cell on the simulated HAL in virtual time, with the UI's tick-thread parts."""

    def __init__(self) -> None:
        self.scenario, self.spec = load_scenario(LENSES)
        self.clock = SimClock()
        self.hal = make_sim_hal(self.scenario, self.spec, self.clock, 1)
        self.cell = Cell(self.spec, self.hal, self.clock)
        self.cell.load(self.scenario)
        self.ops = CellOps(self.cell, LENSES.parent, self.scenario.cell_path)
        self.panel = CellPanel(self.cell, self.ops.limits, lambda: sorted(self.ops.scenarios))
        self.ticker = Ticker(self.cell, fast=True)

    def do(self, name: str, **args: Any) -> Outcome:
        return self.ops.execute(Command(name, args, "alice", Future()))

    def run(self, seconds: float) -> None:
        self.ticker.run(until=self.clock.now() + seconds)

    def run_until(self, state: CellState, limit: float = 60.0) -> None:
        self.ticker.run(until=self.clock.now() + limit, stop=lambda: self.cell.state is state)
        assert self.cell.state is state

    def horizontal(self) -> float:
        return self.hal.conveyors["horizontal"].speed()


class ServedRig:
    """The lenses cell in virtual time with its operator UI, served on 127.0.0.1:0, run
    until the last frame located parts and at least three are queued (~23 s of clock,
    well under a second of wall time). alice (``PASSWORD``) is its one user."""

    def __init__(self, tmp: Path) -> None:
        users = UsersFile(tmp / "users.json")
        users.add("alice", PASSWORD)
        self.scenario, spec = load_scenario(LENSES)
        self.clock = SimClock()
        self.cell = Cell(spec, make_sim_hal(self.scenario, spec, self.clock, 1), self.clock)
        self.cell.load(self.scenario)
        self.ui = OperatorUi(self.cell, LENSES, self.scenario.cell_path, "127.0.0.1", 0,
                             users.path)
        self.ticker = Ticker(self.cell, fast=True)
        self.cell.start()
        self.run_until_parts()
        self.url = self.ui.start()

    def run_until_parts(self, after_seq: int = 0) -> None:
        """Tick until a look newer than ``after_seq`` located parts and three are queued."""
        def ready() -> bool:
            look = self.ui.camera.slot.get()
            return (look is not None and look.seq > after_seq
                    and bool(look.result.parts) and len(self.cell.ctx.queue) >= 3)

        self.ticker.run(until=self.clock.now() + 60.0, every=self.ui.pump, stop=ready)
        assert ready(), "no parts located in a minute of clock"
        self.ui.bridge.pump(force=True)            # the status the page gets: this moment

    def client(self) -> Client:
        c = Client(self.url)
        code, body, _ = c.login("alice", PASSWORD)
        assert code == 200, body
        return c

    def close(self) -> None:
        self.ui.close()
        self.cell.ctx.vision.close()


# ------------------------------------------------- the UI app in-process, no socket

PASSWORDS = {"alice": "alice-secret-1", "bob": "bob-secret-22", "carol": "carol-secret-3"}
HOST = "127.0.0.1:8080"


def write_users(path: Path, roles: dict[str, str] | None = None,
                extra: dict[str, Any] | None = None) -> UsersFile:
    """A users file with cheap scrypt hashes (the lowest cost the checker accepts), so that
    a test can afford dozens of password checks."""
    users = {n: {"hash": hash_password(p, n=2 ** 10), **({"role": roles[n]} if roles and
                                                          n in roles else {})}
             for n, p in PASSWORDS.items()}
    path.write_text(json.dumps({"format": FORMAT, "users": users, **(extra or {})}))
    path.chmod(0o600)
    return UsersFile(path)


class Recorder:
    """A bridge stand-in: commands are answered at once; access events are kept."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, dict[str, Any]]] = []
        self.notes: list[tuple[str, str]] = []

    def submit(self, name: str, args: dict[str, Any], user: str) -> Future:
        fut: Future = Future()
        if name == "access":
            args = dict(args)
            self.events.append((args.pop("kind"), user, args))
        elif name == "note":
            self.notes.append((user, args["action"]))
        fut.set_result(Outcome.done(f"{name} done"))
        return fut

    def latest(self) -> None:
        return None

    def kinds(self, kind: str) -> list[tuple[str, dict[str, Any]]]:
        return [(u, d) for k, u, d in self.events if k == kind]


class Browser:
    """One browser (its own cookies) at one address, talking to the app in-process."""

    def __init__(self, ui: UiApp, ip: str = "127.0.0.1", host: str = HOST) -> None:
        self.ui, self.ip, self.host = ui, ip, host
        self.cookies: dict[str, tuple[str, str]] = {}      # name: (value, path)
        self.last_headers: list[tuple[str, str]] = []

    def _cookie_header(self, path: str) -> str:
        return "; ".join(f"{k}={v}" for k, (v, p) in self.cookies.items()
                         if path.startswith(p))

    def call(self, method: str, path: str, body: Any = None, raw: bytes | None = None,
             headers: dict[str, str] | None = None) -> tuple[int, dict[str, Any]]:
        data = raw if raw is not None else (b"" if body is None else json.dumps(body).encode())
        hdrs = {"host": self.host, "cookie": self._cookie_header(path),
                **({"content-type": "application/json"} if method == "POST" else {}),
                **(headers or {})}
        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
                 "method": method, "scheme": "http", "path": path, "raw_path": path.encode(),
                 "query_string": b"", "root_path": "", "client": (self.ip, 50000),
                 "server": ("127.0.0.1", 8080),
                 "headers": [(k.encode(), v.encode()) for k, v in hdrs.items()]}
        sent: list[dict[str, Any]] = []

        async def receive() -> dict[str, Any]:
            return {"type": "http.request", "body": data, "more_body": False}

        async def send(message: dict[str, Any]) -> None:
            sent.append(message)

        asyncio.run(self.ui.app(scope, receive, send))
        start = next(m for m in sent if m["type"] == "http.response.start")
        self.last_headers = [(k.decode(), v.decode()) for k, v in start["headers"]]
        for k, v in self.last_headers:
            if k == "set-cookie":
                name, _, rest = v.partition("=")
                value = rest.split(";")[0]
                path = next((a.split("=", 1)[1] for a in rest.split("; ")
                             if a.lower().startswith("path=")), "/")
                if value in ('""', "") or "max-age=0" in v.lower():
                    self.cookies.pop(name, None)
                else:
                    self.cookies[name] = (value, path)
        text = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
        return start["status"], json.loads(text) if text else {}

    def login(self, user: str, password: str | None = None) -> tuple[int, dict[str, Any]]:
        return self.call("POST", "/api/login",
                         {"user": user, "password": PASSWORDS.get(user) if password is None
                          else password})

    def me(self) -> tuple[int, dict[str, Any]]:
        return self.call("GET", "/api/me")


def make_ui(tmp_path: Path, **kw: Any) -> tuple[UiApp, Recorder, FakeClock]:
    clock = FakeClock(1000.0)
    users = write_users(tmp_path / "users.json", kw.pop("roles", None))
    rec = Recorder()
    ui = UiApp(rec, users, clock=clock, **kw)
    ui.record.echo = False
    return ui, rec, clock
