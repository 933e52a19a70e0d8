"""``feeder run`` in a pseudo-terminal of 80 x 24, read through a terminal emulator
(pyte): the header and the status line stay on screen in every frame, the view follows a
resize, and after Ctrl-C the summary says so and agrees with the last status line.

These run the cell in real time (the live view is for real-time runs). The short one runs
by default; the whole minute of the README's first command is a soak test
(``python -m pytest -m soak``)."""

from __future__ import annotations

import fcntl
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

pyte = pytest.importorskip("pyte")

ROOT = Path(__file__).resolve().parents[2]
STATES = ("STOPPED", "STARTING", "RUNNING", "PAUSED", "STOPPING", "FAULTING", "FAULT")


def _winsize(fd: int, cols: int, rows: int) -> None:
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))


class Terminal:
    """A child process on a pty of ``cols`` x ``rows``, its output fed to pyte."""

    def __init__(self, argv: list[str], cols: int = 80, rows: int = 24) -> None:
        self.master, slave = os.openpty()
        _winsize(slave, cols, rows)
        env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
        env.update(TERM="xterm-256color", PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, cwd=ROOT,
                                     env=env, close_fds=True)
        os.close(slave)
        self.screen = pyte.Screen(cols, rows)
        self.stream = pyte.ByteStream(self.screen)

    def resize(self, cols: int, rows: int) -> None:
        _winsize(self.master, cols, rows)
        self.screen.resize(rows, cols)
        self.proc.send_signal(signal.SIGWINCH)

    def settle(self, quiet: float = 0.05, limit: float = 10.0) -> bool:
        """Read until the child has drawn and then been quiet for ``quiet`` s (a whole frame
        drawn); False when the child has closed the terminal."""
        end = time.monotonic() + limit
        got = False
        while time.monotonic() < end:
            ready, _, _ = select.select([self.master], [], [], quiet)
            if not ready:
                if got:
                    break
                continue
            try:
                data = os.read(self.master, 65536)
            except OSError:             # EIO: the child is gone
                return False
            if not data:
                return False
            self.stream.feed(data)
            got = True
        return True

    def lines(self) -> list[str]:
        return [s.rstrip() for s in self.screen.display]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)
        os.close(self.master)


def _check_frame(term: Terminal, times: list[float] | None = None) -> list[str]:
    """The header and the status line are where they belong; ``times`` collects the
    status line's clock time, to show the checks covered the whole run."""
    lines = term.lines()
    assert lines[0].startswith("feeder_bt · lenses on "), "\n".join(lines)
    i = 2 if lines[1].startswith("Ctrl-C") else 1     # narrower than 64: a second header line
    assert lines[i].split(" ")[0] in STATES and "parts/min" in lines[i], "\n".join(lines)
    if times is not None:
        times.append(float(re.search(r" t +([\d.]+) s", lines[i]).group(1)))
    return lines


def _covered(times: list[float], start: float, end: float, gap: float | None = 5.0) -> bool:
    """Checked from ``start`` to ``end`` s of the run, never more than ``gap`` s apart (the
    gap is the wall clock's business: only the soak judges it; None: in order is enough)."""
    pairs = list(zip(times, times[1:], strict=False))
    return (bool(times) and times[0] <= start and times[-1] >= end
            and all(a <= b for a, b in pairs)
            and (gap is None or all(b - a < gap for a, b in pairs)))


def _ppm(text: str) -> str:
    return re.search(r"([\d.]+) parts/min", text).group(1)


def _status_and_summary(lines: list[str]) -> tuple[str, str]:
    """The last frame's status line and the summary under it (its first two lines)."""
    status = next(s for s in lines if s.startswith("STOPPED "))
    i = next(i for i, s in enumerate(lines) if s.startswith("lenses: "))
    return status, lines[i] + lines[i + 1]


def _run(tmp_path: Path, *extra: str) -> Terminal:
    return Terminal([sys.executable, "-m", "feeder_bt.cli", "run", "scenarios/lenses.yaml",
                     "--db", str(tmp_path / "r.db"), *extra])


@pytest.mark.soak      # real time in a terminal
def test_status_line_stays_on_screen_resize_and_ctrl_c(tmp_path):
    term = _run(tmp_path, "--duration", "600")
    try:
        waiting = retrieved = False
        resized = False
        times: list[float] = []
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:       # only a net against a hung child
            assert term.settle()
            lines = _check_frame(term, times)
            assert len(lines[1]) <= term.screen.columns
            waiting |= any(s.startswith("waiting for the first parts") for s in lines)
            if re.search(r"retrieved [1-9]", lines[1]):
                retrieved = True
                if resized:
                    break
                term.resize(60, 18)           # smaller: the next frame fits it
                resized = True
                assert term.settle()
                lines = _check_frame(term)
                assert all(len(s) <= 60 for s in lines)
                term.resize(80, 24)           # back, for the summary's sake
        assert waiting and retrieved and resized and _covered(times, 5.0, times[-1], gap=None)
        term.proc.send_signal(signal.SIGINT)
        while term.settle():
            pass
        term.proc.wait(timeout=60)
        assert term.proc.returncode == 0
        screen = term.lines()
        status, summary = _status_and_summary(screen)
        assert "STOPPED (interrupted)" in summary, screen
        assert _ppm(status) == _ppm(summary), screen
    finally:
        term.close()


@pytest.mark.soak
def test_the_readme_minute_keeps_its_status_line_on_screen(tmp_path):
    """The README's first command as a newcomer types it: a minute of lenses, 80 x 24."""
    term = _run(tmp_path)
    try:
        times: list[float] = []
        while term.settle():
            if term.proc.poll() is None:
                _check_frame(term, times)
        term.proc.wait(timeout=60)
        assert term.proc.returncode == 0
        assert _covered(times, 5.0, 58.0), times          # the whole minute
        status, summary = _status_and_summary(term.lines())
        assert "after 60 s" in summary and _ppm(status) == _ppm(summary)
        assert float(_ppm(summary)) > 20
    finally:
        term.close()
