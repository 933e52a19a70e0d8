"""The Galil DMC ASCII protocol, as pure functions: no sockets, no threads, no clock.

What is here, and why it is kept apart from the driver:

- ``ReplySplitter``: the controller interleaves two byte streams on one link. Replies to
  commands end with ``:`` (``data\\r\\n:`` or a bare ``:``) or are a lone ``?`` (rejected,
  no CR/LF). Output of a running program (``MG``) is unsolicited; under ``CW 1`` each of its
  bytes has the top bit set, and may arrive in the middle of a reply. The splitter is fed
  raw bytes in any chunking and hands back completed replies and completed unsolicited
  lines, so it can be tested byte by byte without a controller.
- Typed errors: ``GalilError`` carries the controller's ``TC1`` code and text.
- Command formatting for multi-axis commands (``PR ,500``, ``SPB=2000``).
- ``prepare_download``: what ``DL`` sends, with comments and blank lines stripped and the
  controller's limits checked *before* anything is sent, so an over-long line is reported
  as ``file:line`` rather than as a ``?`` half-way through a download.

Controller model assumed throughout: a DMC-21x3 (Ethernet/RS-232, 8 threads): program
memory of 1000 lines of at most 80 characters; labels are ``#`` and 1-7 characters, the
first a letter; variable names 1-8 characters, the first a letter.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from feeder_bt.core.errors import CommsLost, HalError, one_line

# ---------------------------------------------------------------------------- limits

MODEL = "DMC-21x3"
MAX_LINE_CHARS = 80          # characters per program line (without the CR)
MAX_PROGRAM_LINES = 1000     # program memory, lines
MAX_LABEL_CHARS = 7          # after the '#'
MAX_VARIABLE_CHARS = 8
MAX_LABELS = 254             # labels in program memory (DMC-2x00 specifications; unconfirmed)
THREADS = 8
HANDLES = 8                  # Ethernet handles A-H (confirmed for the DMC-3425; see real-cell.md)
INPUT_BANKS = 2              # _TI0 and _TI1: inputs 1-16 are what the monitor reports
MAX_REPLY_BYTES = 4096       # longer without a terminator: the stream is garbage

LABEL_RE = re.compile(r"^#([A-Za-z][A-Za-z0-9]*)$")
AXES = "ABCDEFGH"

# Error codes of ``TC1`` (Galil command reference, TC). The emulator answers with these; the
# driver only needs the ones it names.
ERROR_TEXT: dict[int, str] = {
    0: "No error",
    1: "Unrecognized command",
    2: "Command only valid from program",
    3: "Command not valid in program",
    4: "Operand error",
    6: "Number out of range",
    7: "Command not valid while running",
    8: "Command not valid while not running",
    9: "Variable error",
    10: "Empty program line or undefined label",
    11: "Invalid label or line number",
    12: "Subroutine more than 16 deep",
    13: "JG only valid when running in jog mode",
    17: "ED, BN and DL not valid while program running",
    19: "Application strand already executing",
    20: "Begin not valid with motor off",
    21: "Begin not valid while running",
    22: "Begin not possible due to Limit Switch",
    50: "Not enough fields",
    52: "Missing quote or string too long",
    55: "Missing [ or []",
    56: "Array index invalid or out of range",
    57: "Bad function or array",
    59: "Mismatched parentheses",
    60: "Download error - line too long or too many lines",
    61: "Duplicate or bad label",
    63: "IF statement without ENDIF",
    83: "Not a valid number",
}


# ---------------------------------------------------------------------------- errors


class GalilError(HalError):
    """The controller rejected a command (``?``); ``code`` and ``text`` come from ``TC1``."""

    kind = "galil"

    def __init__(self, code: int, text: str, command: str | None = None) -> None:
        self.code, self.text, self.command = code, text, command
        where = f"{command!r}: " if command else ""
        super().__init__(f"Galil {where}error {code}: {text}")


class ProtocolError(CommsLost):
    """The byte stream makes no sense (garbage, a runaway reply): treat the link as lost."""


class DownloadError(GalilError):
    """A program cannot be downloaded; the message names ``file:line``."""

    def __init__(self, file: str, line: int, what: str, code: int = 60) -> None:
        self.file, self.line, self.what = file, line, what
        super().__init__(code, f"{file}:{line}: {what}")


def parse_tell_code(reply: str) -> tuple[int, str]:
    """``'1 Unrecognized command'`` -> ``(1, 'Unrecognized command')``; never raises."""
    text = reply.strip()
    m = re.match(r"^([+-]?\d+)\s*(.*)$", text)
    if not m:
        return -1, text or "unknown error (empty TC1 reply)"
    code = int(m.group(1))
    return code, m.group(2).strip() or ERROR_TEXT.get(code, "unknown error")


# ---------------------------------------------------------------------------- splitter


@dataclass(frozen=True)
class Reply:
    """One command's answer: ``ok`` with its data (may be empty), or rejected (``?``)."""

    ok: bool
    data: str = ""


@dataclass(frozen=True)
class Unsolicited:
    """One line of program output (top bit already stripped, no CR/LF)."""

    text: str


class ReplySplitter:
    """Separates replies from unsolicited output in a byte stream, in any chunking.

    Solicited bytes accumulate until ``:`` ends a reply. A ``:`` counts as the end only when
    the reply so far is empty or ends a line (``...\\r\\n:``, or a bare ``\\r`` as a serial
    port's echo of the command leaves it), so a colon inside data does not cut a reply
    short and an echoed command never leaves a reply incomplete. A ``?`` with nothing before it is a rejection. Unsolicited bytes
    (top bit set) accumulate until ``\\n``.
    """

    def __init__(self, max_reply: int = MAX_REPLY_BYTES) -> None:
        self._reply = bytearray()
        self._unsolicited = bytearray()
        self._max = max_reply

    def feed(self, data: bytes | bytearray) -> list[Reply | Unsolicited]:
        """Consume bytes; return what completed, in arrival order.

        Raises ``ProtocolError`` when a reply or line grows past ``max_reply`` bytes with no
        terminator: the link is out of step and must be re-synchronised (reconnected).
        """
        out: list[Reply | Unsolicited] = []
        for byte in bytes(data):
            if byte & 0x80:
                ch = byte & 0x7F
                if ch == 0x0A:
                    out.append(Unsolicited(_decode(self._unsolicited).rstrip("\r")))
                    self._unsolicited.clear()
                else:
                    self._unsolicited.append(ch)
                    if len(self._unsolicited) > self._max:
                        self._unsolicited.clear()
                        raise ProtocolError("unsolicited line too long: garbage on the link")
                continue
            if byte == 0x3A and (not self._reply or self._reply[-1] in (0x0A, 0x0D)):  # ':'
                out.append(Reply(True, _decode(self._reply).strip("\r\n")))
                self._reply.clear()
            elif byte == 0x3F and (not self._reply or self._reply[-1] in (0x0A, 0x0D)):
                out.append(Reply(False))                    # '?', maybe after an echo
                self._reply.clear()
            else:
                self._reply.append(byte)
                if len(self._reply) > self._max:
                    self._reply.clear()
                    raise ProtocolError("reply too long without ':': garbage on the link")
        return out

    def reset(self) -> None:
        """Forget partial input (after a reconnect)."""
        self._reply.clear()
        self._unsolicited.clear()

    @property
    def pending(self) -> bytes:
        """Solicited bytes received but not yet part of a complete reply (for diagnostics)."""
        return bytes(self._reply)


def _decode(buf: bytes | bytearray) -> str:
    """Bytes -> text; anything unprintable is escaped rather than failing."""
    return bytes(buf).decode("ascii", errors="backslashreplace")


# ---------------------------------------------------------------------------- events


@dataclass(frozen=True)
class InputsEvent:
    """The input monitor's ``I nnnnn``: inputs 1..16 as a bit mask (bit 0 = input 1)."""

    mask: int


@dataclass(frozen=True)
class DistanceEvent:
    """The distance notifier's ``D nnnnnnnnnn``: the notify axis's count."""

    count: int


@dataclass(frozen=True)
class ProgramError:
    """A program thread stopped on an error. The controller echoes the failing program line
    with a ``?`` (at the start, or after the line number or the failing command, depending
    on firmware); the on-card ``#CMDERR`` handler of ``monitor.dmc`` sends ``E CMDERR``."""

    text: str


@dataclass(frozen=True)
class CardEvent:
    """An on-card automatic subroutine's report: ``E POSERR``, ``E LIMSWI``, ``E AMPERR``,
    ``E CMDERR <thread> <line>``, or the host watchdog's ``W`` (belts stopped)."""

    kind: str
    detail: str = ""


@dataclass(frozen=True)
class Message:
    """Any other program output."""

    text: str


Event = InputsEvent | DistanceEvent | ProgramError | CardEvent | Message

_ECHO_ERROR_RE = re.compile(r"^\d+\s*\S.*\?|^[A-Z#][^\"]*\?\s*$")
CARD_EVENTS = ("POSERR", "LIMSWI", "AMPERR", "CMDERR")


def parse_unsolicited(line: str) -> Event:
    """Classify one unsolicited line; never raises (unknown lines become ``Message``).

    Program errors are recognised in every form the controller may echo them: a leading
    ``?``, a numbered program line with a ``?`` in it (``004 JP #X?``), or a program line
    ending in ``?``. Output of our programs never contains ``?``. Control characters are
    escaped (``\x1b``): a card's text reaches logs and terminals, never their controls.
    """
    text = one_line(line.strip())
    if text.startswith("?"):
        return ProgramError(text[1:].strip())
    if "?" in text and _ECHO_ERROR_RE.match(text):
        return ProgramError(text.replace("?", " ").strip())
    if text == "W":
        return CardEvent("WATCHDOG")
    if text.startswith("E ") and text[2:].split(" ", 1)[0] in CARD_EVENTS:
        kind, _, detail = text[2:].partition(" ")
        return CardEvent(kind, detail.strip())
    if len(text) >= 2 and text[0] in "ID" and not text[1].isalpha():
        try:
            value = parse_number(text[1:])
        except HalError:
            return Message(text)
        if text[0] == "I" and 0 <= value < 1 << (8 * INPUT_BANKS) and value == int(value):
            return InputsEvent(int(value))
        if text[0] == "D" and value == int(value):
            return DistanceEvent(int(value))
    return Message(text)


# ---------------------------------------------------------------------------- numbers

_NUMBER_RE = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")


def parse_number(text: str) -> float:
    """A numeric reply (``' 1234'``, ``'-5.0000'``, ``'$FF'``) -> float.

    Raises ``ProtocolError`` (a ``CommsLost``) for anything else, never ``ValueError``: a
    reply that is not a number means the link is out of step.
    """
    if not isinstance(text, str):
        raise ProtocolError(f"expected a number, got {type(text).__name__}")
    t = text.strip()
    if t.startswith("$"):
        try:
            return float(int(t[1:].split(".")[0], 16))
        except ValueError:
            raise ProtocolError(f"not a hex number: {text!r}") from None
    if not _NUMBER_RE.match(t):
        raise ProtocolError(f"expected a number, got {text!r}")
    value = float(t)
    if not math.isfinite(value):
        raise ProtocolError(f"expected a number, got {text!r}")
    return value


def parse_int(text: str) -> int:
    """A numeric reply rounded to an integer (counts, flags)."""
    return int(round(parse_number(text)))


def parse_numbers(text: str) -> list[float]:
    """A multi-axis reply (``' 100, -200'``) -> ``[100.0, -200.0]``."""
    return [parse_number(part) for part in text.split(",")]


# ---------------------------------------------------------------------------- commands


def _axis_index(axis: str) -> int:
    if not isinstance(axis, str) or len(axis) != 1 or axis.upper() not in AXES:
        raise GalilError(4, f"no such axis {axis!r} (one of {AXES})")
    return AXES.index(axis.upper())


def format_value(value: float) -> str:
    """Numbers as the controller reads them: integers bare, fractions to 4 places."""
    if not math.isfinite(value):
        raise GalilError(6, f"number out of range: {value!r}")
    if float(value).is_integer():
        return str(int(value))
    return f"{value:.4f}".rstrip("0").rstrip(".")


def positional(cmd: str, values: dict[str, float]) -> str:
    """Multi-axis positional form: ``positional('PR', {'B': 500})`` -> ``'PR ,500'``."""
    if not values:
        raise GalilError(50, f"{cmd} needs at least one axis")
    fields = [""] * (max(_axis_index(a) for a in values) + 1)
    for axis, value in values.items():
        fields[_axis_index(axis)] = format_value(value)
    return f"{cmd} {','.join(fields)}"


def explicit(cmd: str, axis: str, value: float) -> str:
    """Explicit-axis form: ``explicit('SP', 'B', 2000)`` -> ``'SPB=2000'``."""
    return f"{cmd}{AXES[_axis_index(axis)]}={format_value(value)}"


def axes_command(cmd: str, axes: Iterable[str]) -> str:
    """``axes_command('BG', 'B')`` -> ``'BGB'``; ``('SH', 'AB')`` -> ``'SHAB'``."""
    letters = "".join(AXES[_axis_index(a)] for a in axes)
    return f"{cmd}{letters}"


# ---------------------------------------------------------------------------- download


@dataclass(frozen=True)
class ProgramLine:
    """One line as it will be downloaded, with where it came from."""

    text: str
    file: str
    line: int


def strip_comment(line: str) -> str:
    """The line without comments: ``REM``/``NO`` lines, ``'`` to end of line outside quotes.

    ``REM`` is removed by the host (as Galil's own tools do); ``NO`` and ``'`` are the
    controller's comments, removed too so that they cost no program memory.
    """
    s = line.strip()
    upper = s.upper()
    if upper.startswith("REM") and (len(s) == 3 or not s[3].isalnum()):
        return ""
    if upper.startswith("NO") and (len(s) == 2 or not s[2].isalnum()):
        return ""
    quoted = False
    for i, ch in enumerate(s):
        if ch == '"':
            quoted = not quoted
        elif ch == "'" and not quoted:
            s = s[:i]
            break
    s = s.rstrip()
    while s.endswith(";"):
        s = s[:-1].rstrip()
    return s


def prepare_lines(text: str, file: str = "<program>") -> list[ProgramLine]:
    """Strip comments and blank lines, and check each line against the controller's limits.

    Raises ``DownloadError`` naming ``file:line`` for an over-long line, a bad label or a
    character the controller cannot take.
    """
    out: list[ProgramLine] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        s = strip_comment(raw)
        if not s:
            continue
        if "\\" in s:
            raise DownloadError(file, n, "'\\' ends a download; it cannot appear in a program")
        bad = next((c for c in s if not (32 <= ord(c) < 127) and c != "\t"), None)
        if bad is not None:
            raise DownloadError(file, n, f"character {bad!r} cannot be sent to the controller")
        s = s.replace("\t", " ")
        if len(s) > MAX_LINE_CHARS:
            raise DownloadError(file, n, f"line is {len(s)} characters after stripping "
                                         f"comments; the {MODEL} takes at most {MAX_LINE_CHARS}")
        if s.startswith("#"):
            label = s.split(";", 1)[0].strip()
            err = label_problem(label)
            if err:
                raise DownloadError(file, n, err, code=61)
        out.append(ProgramLine(s, file, n))
    return out


def label_problem(label: str) -> str | None:
    """Why ``label`` is not a valid DMC label, or None."""
    m = LABEL_RE.match(label)
    if not m:
        return (f"bad label {label!r}: '#' then a letter, then letters or digits "
                f"(at most {MAX_LABEL_CHARS} characters)")
    if len(m.group(1)) > MAX_LABEL_CHARS:
        return f"label {label!r} is longer than {MAX_LABEL_CHARS} characters"
    return None


def prepare_download(files: Sequence[tuple[str, str]]) -> list[ProgramLine]:
    """Lines of one download made of several program files (``(name, text)`` pairs).

    The controller has one program buffer, so every file goes in one ``DL``. Checks the
    limits per line (``prepare_lines``), duplicate labels across files and the total line
    count; every problem raises ``DownloadError`` naming ``file:line``.
    """
    lines: list[ProgramLine] = []
    seen: dict[str, ProgramLine] = {}
    for name, text in files:
        for pl in prepare_lines(text, name):
            if pl.text.startswith("#"):
                label = pl.text.split(";", 1)[0].strip().upper()
                if label in seen:
                    first = seen[label]
                    raise DownloadError(pl.file, pl.line, f"label {label} is already defined "
                                                          f"at {first.file}:{first.line}", code=61)
                seen[label] = pl
                if len(seen) > MAX_LABELS:
                    raise DownloadError(pl.file, pl.line, f"more than the {MODEL}'s "
                                                          f"{MAX_LABELS} labels", code=61)
            lines.append(pl)
            if len(lines) > MAX_PROGRAM_LINES:
                raise DownloadError(pl.file, pl.line, f"program is longer than the {MODEL}'s "
                                                      f"{MAX_PROGRAM_LINES} lines")
    return lines


def read_programs(directory: Path, names: Sequence[str]) -> list[ProgramLine]:
    """Read and prepare the named files of ``directory`` (``GalilSpec.programs``)."""
    files = []
    for name in names:
        path = Path(directory) / name
        try:
            files.append((str(path), path.read_text(encoding="ascii")))
        except OSError as e:
            raise DownloadError(str(path), 0, f"cannot read program: {e.strerror or e}") from None
        except UnicodeDecodeError as e:
            line = path.read_bytes()[:e.start].count(b"\n") + 1
            raise DownloadError(str(path), line, "not plain ASCII") from None
    return prepare_download(files)


def download_payload(lines: Sequence[ProgramLine]) -> bytes:
    """The bytes after ``DL<CR>``: every line with CR, then the ``\\`` terminator."""
    return "".join(pl.text + "\r" for pl in lines).encode("ascii") + b"\\"


# _SC, the axis's stop code (Galil command reference, SC)
STOP_CODES = {0: "running", 1: "stopped at the commanded position", 2: "forward limit switch",
              3: "reverse limit switch", 4: "ST command", 6: "abort input (e-stop chain)",
              7: "abort command", 8: "off-on-error (position error over ER)"}


def stop_text(code: int) -> str:
    return STOP_CODES.get(code, f"stop code {code}")
