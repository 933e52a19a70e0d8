"""The part server's line protocol (docs/part-server.md): pure text, shared by the server
side (behaviours/serve.py) and the robot clients (plant/client.py).

One request per line, one reply per line, ASCII, fields separated by spaces, lines ended by
LF (a CR before it is ignored). Every reply starts with ``OK`` or ``ERR``, so a robot
program needs only to split a line on spaces: the second field says what the rest is.

    PART [TYPE] [WITHIN s] [WAIT s]  -> OK PART id type x y z rz latch left_s
                                        | OK NONE why
    PICKED id                        -> OK PICKED id
    PLACED id                        -> OK PLACED id total
    MISSED id [why]                  -> OK MISSED id
    RELEASE id                       -> OK RELEASE id queued|gone
    PREPARE [n] [TYPE]               -> OK PREPARE ready n
    STATUS                           -> OK STATUS key=value ...
    HELP [command]                   -> OK HELP ...
    QUIT                             -> OK BYE (the server closes the connection)

A robot named in the robots file with a secret proves who it is first, once per
connection, by challenge and response (the secret never crosses the network, and what
crosses it is worth nothing on another connection):

    HELLO NAME                       -> OK CHALLENGE nonce (32 hex digits, new each time)
    PROOF hex                        -> OK HELLO NAME
                                        hex = HMAC-SHA256(key, nonce), 64 hex digits,
                                        key = SHA-256(secret) (its 32 bytes)
    HELLO NAME SECRET                -> the old plain form: refused unless the robots file
                                        allows it for that robot (``plain_secret``)

Nothing here does any I/O, so both ends and the tests share one parser.
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass

MAX_LINE = 256                 # a longer request is refused (and the connection closed)

COMMANDS = ("PART", "PICKED", "PLACED", "MISSED", "RELEASE", "PREPARE", "STATUS", "HELP",
            "QUIT")

USAGE = {
    "PART": "PART [TYPE] [WITHIN s] [WAIT s]: hand me a part (of TYPE; one I can reach "
            "within s seconds; wait up to s seconds for one) -> OK PART id type x y z rz "
            "latch left_s | OK NONE why",
    "PICKED": "PICKED id: I gripped part id -> OK PICKED id",
    "PLACED": "PLACED id: part id is at its place pose -> OK PLACED id total",
    "MISSED": "MISSED id [why]: I did not get part id -> OK MISSED id",
    "RELEASE": "RELEASE id: I will not pick part id after all -> OK RELEASE id queued|gone",
    "PREPARE": "PREPARE [n] [TYPE]: I will want n parts (of TYPE) -> OK PREPARE ready n",
    "STATUS": "STATUS: the cell's state and counts -> OK STATUS key=value ...",
    "HELP": "HELP [command]: the commands, or one command's usage",
    "QUIT": "QUIT: close the connection -> OK BYE",
}


class ProtocolError(ValueError):
    """A request or reply that does not follow the protocol; the text goes after ``ERR``."""


@dataclass(frozen=True)
class Request:
    """One parsed request line."""

    command: str
    part_id: int | None = None       # PICKED, PLACED, MISSED, RELEASE
    part_type: str | None = None     # PART, PREPARE
    within_s: float | None = None    # PART
    wait_s: float = 0.0              # PART
    count: int = 1                   # PREPARE
    why: str = ""                    # MISSED
    topic: str | None = None         # HELP


def _number(text: str, what: str, command: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ProtocolError(f"{command}: {what} must be a number, got {text!r}") from None
    if not 0.0 <= v < 1e6:
        raise ProtocolError(f"{command}: {what} must be 0 or more seconds, got {text}")
    return v


def _part_id(tokens: list[str], command: str) -> int:
    if len(tokens) < 2:
        raise ProtocolError(f"{command} needs a part id: {USAGE[command]}")
    try:
        return int(tokens[1])
    except ValueError:
        raise ProtocolError(f"{command}: part id must be a whole number, got "
                            f"{tokens[1]!r}") from None


def parse_request(line: str) -> Request:
    """A request line to a ``Request``; ProtocolError with the reason otherwise."""
    if len(line) > MAX_LINE:
        raise ProtocolError(f"line longer than {MAX_LINE} characters")
    if not line.isascii() or not line.isprintable():
        raise ProtocolError("only printable ASCII is accepted")
    tokens = line.split()
    if not tokens:
        raise ProtocolError("empty request (HELP lists the commands)")
    cmd = tokens[0].upper()
    if cmd not in COMMANDS:
        raise ProtocolError(f"unknown command {tokens[0]!r} (HELP lists the commands)")
    if cmd == "PART":
        ptype, within, wait = None, None, 0.0
        rest = tokens[1:]
        if rest and rest[0].upper() not in ("WITHIN", "WAIT"):
            ptype, rest = rest[0], rest[1:]
        while rest:
            key = rest[0].upper()
            if key not in ("WITHIN", "WAIT") or len(rest) < 2:
                raise ProtocolError(f"PART: expected WITHIN s or WAIT s, got "
                                    f"{' '.join(rest)!r}: {USAGE['PART']}")
            v = _number(rest[1], key.lower(), "PART")
            if key == "WITHIN":
                within = v
            else:
                wait = v
            rest = rest[2:]
        return Request("PART", part_type=ptype, within_s=within, wait_s=wait)
    if cmd in ("PICKED", "PLACED", "RELEASE"):
        if len(tokens) > 2:
            raise ProtocolError(f"{cmd} takes one part id: {USAGE[cmd]}")
        return Request(cmd, part_id=_part_id(tokens, cmd))
    if cmd == "MISSED":
        return Request(cmd, part_id=_part_id(tokens, cmd), why=" ".join(tokens[2:])[:64])
    if cmd == "PREPARE":
        n, ptype = 1, None
        for tok in tokens[1:]:
            if tok.isdigit():
                n = int(tok)
            elif ptype is None:
                ptype = tok
            else:
                raise ProtocolError(f"PREPARE: unexpected {tok!r}: {USAGE['PREPARE']}")
        if not 1 <= n <= 1000:
            raise ProtocolError(f"PREPARE: n must be 1..1000, got {n}")
        return Request(cmd, part_type=ptype, count=n)
    if cmd == "HELP":
        return Request(cmd, topic=tokens[1].upper() if len(tokens) > 1 else None)
    if len(tokens) > 1:
        raise ProtocolError(f"{cmd} takes no arguments")
    return Request(cmd)


@dataclass(frozen=True)
class Offer:
    """A part handed to a robot: where to pick it, in the robot's frame.

    ``x, y`` (mm) is the grip point (the part's pose plus the type's tool offset) in the belt
    frame at the moment of the latch, ``rz`` its angle (degrees), and ``latch`` the robot
    controller's belt encoder count at that moment: a tracking robot picks at
    ``x + (encoder_now - latch) / counts_per_mm`` (what V+ does with a belt frame set at
    the latch). ``left_s`` is how long until the part passes ``too_far``."""

    id: int
    type: str
    x: float
    y: float
    z: float
    rz: float
    latch: int
    left_s: float

    def line(self) -> str:
        return (f"OK PART {self.id} {self.type} {self.x:.3f} {self.y:.3f} {self.z:.3f} "
                f"{self.rz:.3f} {self.latch} {self.left_s:.3f}")


def secret_key(secret: str) -> bytes:
    """The HMAC key of a robot's secret: its SHA-256, the same hash the robots file keeps
    (so the file needs no other record of the secret; see docs/part-server.md)."""
    return hashlib.sha256(secret.encode("utf-8")).digest()


def prove(key: bytes, nonce: str) -> str:
    """A robot's answer to ``OK CHALLENGE nonce``: HMAC-SHA256(key, nonce) in hex."""
    return hmac.new(key, nonce.encode("ascii", "replace"), hashlib.sha256).hexdigest()


def parse_reply(line: str) -> tuple[str, list[str]]:
    """(``OK`` kind or ``ERR``, the fields after it); ProtocolError if not a reply."""
    tokens = line.split()
    if not tokens or tokens[0] not in ("OK", "ERR"):
        raise ProtocolError(f"not a reply: {line!r}")
    if tokens[0] == "ERR":
        return "ERR", [line[3:].strip()]
    if len(tokens) < 2:
        raise ProtocolError(f"reply without a kind: {line!r}")
    return tokens[1], tokens[2:]


def parse_offer(fields: list[str]) -> Offer:
    """The fields of an ``OK PART`` reply."""
    if len(fields) != 8:
        raise ProtocolError(f"OK PART needs 8 fields, got {len(fields)}")
    try:
        return Offer(int(fields[0]), fields[1], float(fields[2]), float(fields[3]),
                     float(fields[4]), float(fields[5]), int(fields[6]), float(fields[7]))
    except ValueError as e:
        raise ProtocolError(f"bad OK PART reply: {e}") from None


def parse_status(fields: list[str]) -> dict[str, str]:
    """The ``key=value`` fields of an ``OK STATUS`` reply."""
    out: dict[str, str] = {}
    for f in fields:
        key, sep, value = f.partition("=")
        if not sep:
            raise ProtocolError(f"STATUS field without '=': {f!r}")
        out[key] = value
    return out


def status_line(values: dict[str, object]) -> str:
    """``OK STATUS k=v ...``; spaces in values become ``_`` so a field stays one token."""
    parts = []
    for k, v in values.items():
        text = f"{v:g}" if isinstance(v, float) else str(v)
        parts.append(f"{k}={text.replace(' ', '_') or '-'}")
    return "OK STATUS " + " ".join(parts)


def help_line(topic: str | None) -> str:
    if topic is None:
        return "OK HELP " + " ".join(COMMANDS)
    if topic not in USAGE:
        return f"ERR HELP: unknown command {topic!r} (HELP lists the commands)"
    return "OK HELP " + USAGE[topic]
