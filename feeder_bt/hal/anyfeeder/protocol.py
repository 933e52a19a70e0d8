"""The AnyFeeder's serial protocol, as the Adept AnyFeeder User's Guide (Rev. B, ch. 3.6
"Serial Command Codes", pp. 33-38; Rev. A pp. 30-34) and the public ROS 2 driver
SHOP4CF/anyfeeder_connector (used on SXM100/140 and SX240/340) give it: ASCII lines ended
by a carriage return (Table 3-2: ``<cr>``, ASCII 13), case sensitive; ``x=N`` executes
command N, ``ab[N]=V`` sets its parameter and ``ab[N]=V x=N`` (one explicit space) sets it
and executes. Each motor answers ``m<i><x>``: i the drive (1 the flip drive under the feed
surface, 2 the dispense drive under the bulk container), x its status (Table 3-5). Some
feeders echo each command line before the motor codes (anyfeeder_connector discards the
first line of every reply). Every source, and what could not be confirmed:
docs/plate-feeders.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

CR = b"\r"
LINE_CAP = 256          # bytes without a <cr>: not an AnyFeeder, drop the link

#: Table 3-2: [turns] 1...10 (purge 1...127), [speed] 1...10
TURNS = (1, 10)
PURGE_TURNS = (1, 127)
SPEED = (1, 10)
#: the repetition parameter of action N is ab[N] (Rev. A p. 31: 1-8, 8 heavy dispense);
#: its speed parameter ab[N+16] (Rev. A p. 32: 19-22; anyfeeder_connector's
#: buildABCommand: "+16", so 17, 18 and 23 for feed forward, feed backward and purge)
REPS_PARAMS = range(1, 9)
PURGE_PARAM = 7
SPEED_OFFSET = 16
SPEED_PARAMS = range(17, 24)
OUTPUT_PARAM = 27                   # Table 3-4: set digital output (modes 0...5)
OUTPUT_MODES = (0, 5)
BACKLIGHT_OFF, BACKLIGHT_ON = 2, 3  # ab[27] modes

#: Table 3-5 / 3-6: each status code's meaning, in the manual's words
MEANING = {
    0: "completed action successfully",
    1: "received command and is busy",
    2: "Invalid command: command or command syntax incorrect",
    3: "servo error: possibly overloaded; check for obstructions or hardware problems; "
       "error must be reset before operation can continue",
    6: "not initialized: the AnyFeeder must be initialized before commands can be sent",
    7: "error state: error must be reset before operation can continue",
    8: "timeout, no sync-signal received: the sync-signal was not received from Motor 1, "
       "so Motor 2 cannot start its action",
}
DONE, BUSY, INVALID, SERVO, NOT_INIT, ERROR_STATE, NO_SYNC = 0, 1, 2, 3, 6, 7, 8
MOTORS = frozenset({1, 2})

_REPLY = re.compile(r"^m([12])([0-9])$")
_LINE = re.compile(r"^(?:ab\[(\d{1,3})\]=(\d{1,3}))?(?:(?<=\d) )?(?:x=(\d{1,3}))?$")


class ProtocolError(ValueError):
    """A line that is not the AnyFeeder's syntax."""


def shown(text: str | bytes, limit: int = 48) -> str:
    """Device text for a one-line message: quoted, control bytes escaped, cut short."""
    if isinstance(text, bytes):
        text = text.decode("latin-1")
    cut = text[:limit]
    out = ascii(cut)
    return out + ("..." if len(text) > limit else "")


@dataclass(frozen=True)
class Reply:
    motor: int
    code: int

    @property
    def text(self) -> str:
        return f"m{self.motor}{self.code}"

    @property
    def error(self) -> bool:
        return self.code not in (DONE, BUSY)

    def describe(self) -> str:
        what = MEANING.get(self.code, "unknown status")
        return f"{self.text}: Motor {self.motor} {what}" if self.code != INVALID \
            else f"{self.text}: {what}"


def parse_reply(line: str) -> Reply:
    m = _REPLY.match(line.strip())
    if m is None:
        raise ProtocolError(f"not an AnyFeeder reply: {shown(line)}")
    return Reply(int(m.group(1)), int(m.group(2)))


def is_reply(line: str) -> bool:
    return _REPLY.match(line.strip()) is not None


@dataclass(frozen=True)
class Command:
    """One line: an optional parameter set (``ab[param]=value``), an optional execute."""

    param: int | None
    value: int | None
    execute: int | None


def parse_command(line: str) -> Command:
    """A line as the feeder reads it (without its ``<cr>``); ProtocolError if malformed."""
    m = _LINE.match(line)
    if m is None or (m.group(1) is None and m.group(3) is None) or line.endswith(" "):
        raise ProtocolError(f"bad syntax: {shown(line)}")
    param, value, execute = (int(g) if g is not None else None for g in m.groups())
    if param is not None and execute is not None and " " not in line:
        raise ProtocolError(f"bad syntax (one space between the set and x=): {shown(line)}")
    if param is not None and execute is not None and param != execute:
        raise ProtocolError(f"ab[{param}] set with x={execute}: {shown(line)}")
    return Command(param, value, execute)


def param_range(param: int) -> tuple[int, int] | None:
    """The values the manual allows for ``ab[param]``; None: not a parameter it lists."""
    if param == PURGE_PARAM:
        return PURGE_TURNS
    if param in REPS_PARAMS:
        return TURNS
    if param in SPEED_PARAMS:
        return SPEED
    if param == OUTPUT_PARAM:
        return OUTPUT_MODES
    return None


def command_line(number: int, value: int | None = None) -> bytes:
    """``x=N<cr>``, or ``ab[N]=V x=N<cr>`` to set the parameter and execute."""
    text = f"x={number}" if value is None else f"ab[{number}]={value} x={number}"
    return text.encode("ascii") + CR


def set_line(param: int, value: int) -> bytes:
    """``ab[N]=V<cr>``: sets a parameter; the feeder answers nothing (Rev. A p. 31)."""
    return f"ab[{param}]={value}".encode("ascii") + CR
