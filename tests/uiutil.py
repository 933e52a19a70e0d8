"""The operator UI's test rigs, one of each, shared by the UI's test files (over HTTP, in
a browser, in-process): a fake wall clock, users made the administrator's way, a real
`feeder ... --ui` in a child process, one user's HTTP session, and the simulated lenses
cell in virtual time (bare, or served with its camera and belt views).

Chromium and Playwright are in browser_helpers.py."""

from __future__ import annotations

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

from feeder_bt.cell import Cell, CellState
from feeder_bt.clock import SimClock
from feeder_bt.hal.sim.devices import make_sim_hal
from feeder_bt.scenario import load_scenario
from feeder_bt.ticker import Ticker
from feeder_bt.ui.app import OperatorUi
from feeder_bt.ui.bridge import Command, Outcome
from feeder_bt.ui.operate import CellOps
from feeder_bt.ui.status import CellPanel
from feeder_bt.ui.users import UsersFile

ROOT = Path(__file__).resolve().parent.parent
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
    """`feeder replay DB --ui 127.0.0.1:0`: a past run's trees, served."""

    def __init__(self, tmp: Path, db: Path) -> None:
        super().__init__(tmp, ["replay", str(db), "--ui", "127.0.0.1:0"], "replay UI", 30.0)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


class Client:
    """One user's HTTP session (cookie jar), as the page would make its requests."""

    def __init__(self, base: str) -> None:
        self.base = base
        self.jar = CookieJar()
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(self.jar))

    def call(self, path: str, body: Any = None, headers: dict[str, str] | None = None,
             raw: bytes | None = None) -> tuple[int, dict[str, Any], Any]:
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        hdrs = {"Content-Type": "application/json"} if data is not None else {}
        req = urllib.request.Request(self.base + path, data=data, headers={**hdrs,
                                                                            **(headers or {})})
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
