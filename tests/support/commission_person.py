"""A person at the emulated cell, for the out-of-process commissioning tests.

``feeder emulate cell`` and ``feeder commission ...`` run as two subprocesses; ``Person``
reads each commissioning prompt (ending ``[KEY] ``), does what a person would do on the
cell by writing an action to the emulator's standard input (and waits for its one-line
answer), then answers the commissioning on its standard input. ``skip`` names prompts the
person ignores (answers without acting), for the failure cases. Every wait is for an event
(a line, a prompt) with a generous time-out; nothing sleeps and assumes.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
# a question ends "[KEY] " ("[yes/no]" is not a key); other output (a card event) may follow
PROMPT = re.compile(r"\[([A-Za-z0-9_.\-]+)\] ")
WAIT_S = 120.0                     # generous: the machine may be loaded


class Proc:
    """A subprocess whose standard output is collected by a thread."""

    def __init__(self, args: list[str], name: str) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.name = name
        self.p = subprocess.Popen([sys.executable, "-m", "feeder_bt.cli", *args], cwd=ROOT,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, env=env)
        self.text = ""
        self.pos = 0                          # how far the reader of prompts/lines got
        self.eof = False
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.p.stdout is not None
        fd = self.p.stdout.fileno()
        while True:
            data = os.read(fd, 4096)
            with self._cond:
                if not data:
                    self.eof = True
                    self._cond.notify_all()
                    return
                self.text += data.decode("utf-8", "replace")
                self._cond.notify_all()

    def wait(self, pred, timeout: float = WAIT_S):
        """Wait until ``pred(text_from_pos)`` returns something truthy; return it."""
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                got = pred(self.text[self.pos:])
                if got or self.eof:
                    return got
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{self.name}: nothing matching in {timeout:g} s; "
                                       f"output so far:\n{self.text[-3000:]}")
                self._cond.wait(left)

    def line(self, timeout: float = WAIT_S) -> str:
        def full(t: str) -> str | None:
            return t[: t.index("\n")] if "\n" in t else None
        got = self.wait(full, timeout)
        if got is None:
            raise EOFError(f"{self.name} ended:\n{self.text[-3000:]}")
        self.pos += len(got) + 1
        return got

    def write(self, text: str) -> None:
        assert self.p.stdin is not None
        self.p.stdin.write(text.encode())
        self.p.stdin.flush()

    def stop(self) -> None:
        if self.p.poll() is None:
            self.p.terminate()
            try:
                self.p.wait(20)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(10)


def free_block(n: int = 6) -> int:
    """A base port with ``n`` free consecutive ports (Galil, V+ x4, camera)."""
    for base in range(23000 + os.getpid() % 500 * 50, 60000, 97):
        socks = []
        try:
            for i in range(n):
                s = socket.socket()
                s.bind(("127.0.0.1", base + i))
                socks.append(s)
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free ports")


def write_cell(tmp_path: Path, port: int) -> Path:
    """cells/sim.yaml wired to the emulators on ``port``.., with a jam input on the Galil
    and the grip sensor named (Adept input 3, the V+ programs' grip.sense 1003)."""
    data = yaml.safe_load((ROOT / "cells" / "sim.yaml").read_text())
    data["io"]["jam"] = {"controller": "galil", "bit": 3, "dir": "in"}
    data["io"]["grip"] = {"controller": "adept", "bit": 3, "dir": "in"}
    # generous reply time-outs (cell settings): the emulator is another process on a
    # machine that may be loaded, and no step here is judged by how fast it answers
    data["galil"] = {"url": f"socket://127.0.0.1:{port}", "timeout_s": 10.0,
                     "watchdog_s": 10.0, "heartbeat_s": 10.0}
    data["adept"] = {"host": "127.0.0.1", "motion_port": port + 1, "position_port": port + 2,
                     "io_port": port + 3, "notify_port": port + 4, "timeout_s": 10.0,
                     "motion_timeout_s": 30.0}
    data["camera"]["source"] = f"emulated-camera://127.0.0.1:{port + 5}"
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def write_plate_cell(tmp_path: Path, port: int) -> Path:
    """cells/sim_plate.yaml wired to ``feeder emulate plate`` on ``port``, with speeds and
    a repetition to write after init (what ``plate.parameters`` reads back)."""
    data = yaml.safe_load((ROOT / "cells" / "sim_plate.yaml").read_text())
    data["plate"].update(url=f"socket://127.0.0.1:{port}", timeout_s=20.0,
                         speeds={"feed_forward": 5, "purge": 3},
                         repetitions={"heavy_dispense": 2})
    path = tmp_path / "plate.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


class PlateEmulator(Proc):
    """``feeder emulate plate`` in its own process; ``look`` on its standard input."""

    def __init__(self, cell: Path, port: int, *extra: str) -> None:
        super().__init__(["emulate", "plate", "scenarios/plate_lenses.yaml", "--cell",
                          str(cell), "--port", str(port), *extra], "plate emulator")
        while "Ctrl-C to stop" not in self.line():
            pass

    def act(self, action: str) -> str:
        self.write(action + "\n")
        return self.line()


class Emulator(Proc):
    def __init__(self, cell: Path, port: int, *extra: str) -> None:
        super().__init__(["emulate", "cell", "scenarios/lenses.yaml", "--cell", str(cell),
                          "--port", str(port), *extra], "emulator")
        while "Ctrl-C to stop" not in self.line():
            pass

    def act(self, action: str) -> str:
        self.write(action + "\n")
        return self.line()


NUM = r"(-?\d+(?:\.\d+)?)"


def _xy(prompt: str) -> tuple[str, str]:
    m = re.search(rf"x {NUM},? y {NUM}", prompt)
    assert m, prompt
    return m.group(1), m.group(2)


class Person:
    """Plays the person: ``skip`` holds prompt keys the person answers without acting."""

    def __init__(self, emulator: Emulator | PlateEmulator, skip: tuple[str, ...] = (),
                 miss: dict[str, tuple[float, float]] | None = None,
                 target_turn_deg: float = 0.0) -> None:
        self.emu, self.skip = emulator, skip
        self.miss = miss or {}                          # touch key -> (dx, dy) off the mark
        self.target_turn_deg = target_turn_deg          # the target laid turned this much
        self.actions: list[tuple[str, str]] = []        # (action, the emulator's answer)

    def _do(self, action: str) -> str:
        answer = self.emu.act(action)
        self.actions.append((action, answer))
        assert answer.startswith("ok"), (action, answer)
        return answer

    def respond(self, key: str, prompt: str) -> str:
        """Act on the cell for the prompt ``key``; the answer to type to the commissioning."""
        parts = key.split(".")
        if key in self.skip:
            return "no" if "[yes/no]" in prompt else ""
        if parts[0] == "action":                      # at the plate: did it do that?
            seen = self._do("look").split()           # "ok last NAME [xREPS]"
            return "yes" if seen[1:3] == ["last", parts[1]] else "no"
        if parts[0] == "input":
            self._do(f"toggle {parts[1]}")
        elif parts[0] in ("output", "vacuum"):
            name = parts[1] if parts[0] == "output" else "vacuum"
            state = parts[-1]
            return "yes" if self._do(f"look {name}").endswith(f" {state}") else "no"
        elif parts[0] == "limit":
            self._do(f"{parts[3]} {parts[1]}.{parts[2]}_limit")
        elif parts[0] == "estop":
            self._do(f"{parts[1]} estop")
        elif parts[0] == "push":
            self._do(f"push {parts[1]} 50")
        elif key == "latch":
            self._do("trigger")
        elif key == "power.on":
            self._do("power on")
        elif key == "grip.part":
            self._do("part on")
        elif key == "grip.away":
            self._do("part off")
        elif parts[0] in ("touch", "window"):
            x, y = (float(v) for v in _xy(prompt))
            dx, dy = self.miss.get(key, (0.0, 0.0))
            self._do(f"touch {x + dx} {y + dy}")
        elif key == "target.lay":
            x, y = _xy(prompt)
            deg = re.search(rf"{NUM} deg", prompt)
            turn = float(deg.group(1)) if deg else 0.0
            self._do(f"target {x} {y} {turn + self.target_turn_deg:g}")
        elif key == "target.remove":
            self._do("target off")
        elif parts[0] == "marker" and len(parts) == 2:
            self._do("marker {} {}".format(*_xy(prompt)))
        elif parts[0] == "marker":
            self._do("marker off")
        return "yes" if "[yes/no]" in prompt else "done"


def commission(what: str, cell: Path, report: Path, person: Person, *extra: str
               ) -> tuple[int, str]:
    """Run ``feeder commission WHAT`` with the person answering; (exit code, output)."""
    proc = Proc(["commission", what, str(cell), "--report", str(report), *extra],
                f"commission {what}")
    try:
        while True:
            m = proc.wait(lambda t: PROMPT.search(t))
            if m is None:
                break
            prompt = proc.text[proc.pos:proc.pos + m.end()]
            key = m.group(1)
            proc.pos += m.end()
            proc.write(person.respond(key, prompt.splitlines()[-1]) + "\n")
        code = proc.p.wait(WAIT_S)
        return code, proc.text
    finally:
        proc.stop()
