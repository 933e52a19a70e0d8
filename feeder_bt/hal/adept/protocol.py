"""The line protocol of the V+ servers (``vplus/PROTOCOL.md``), as pure functions.

Request: ``VERB arg ...`` and a newline. Reply: ``OK [values]`` or
``ERR <code> <$ERROR text>``, where the code is a negative V+ error number passed through
unchanged (or one of our server programs' own codes, -9001 and below). The notify socket
carries unsolicited ``IN <signal> <0|1>`` lines.

``COMMANDS`` is the client's declared command table; ``tests/emulators/test_vplus_conformance.py``
checks it against the dispatch in the V+ sources and against PROTOCOL.md, so the three
cannot drift apart. Nothing here does I/O: the socket side lives in ``client.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from feeder_bt.core.errors import (
    CommsLost,
    EnvelopeError,
    HalError,
    MissedGrab,
    PowerOff,
    ServoTimeout,
)
from feeder_bt.hal.interfaces import Held, Pose

PROTOCOL_VERSION = 2
MAX_LINE = 256                       # longest line either side sends (V+ READ buffer)
ROBOT_COUNT_MIN, ROBOT_COUNT_MAX = -(1 << 23), (1 << 23) - 1   # V+ belt encoders: 24-bit


class VplusError(HalError):
    """An error reply from a V+ server that is none of the typed HAL errors."""

    kind = "vplus"

    def __init__(self, code: int, text: str, message: str | None = None) -> None:
        self.code, self.text = code, text
        super().__init__(message or f"V+ {code} {text}")


class ProtocolError(HalError):
    """A reply that does not follow the protocol (garbled, truncated, wrong arity):
    the link can no longer be trusted, so the client drops and re-opens the socket."""

    kind = "protocol"


class GarbledReply(CommsLost, ProtocolError):
    """What came back on the link is no reply: bytes that are not ASCII, a line past
    ``MAX_LINE``, a line that does not parse. Noise on a cable or a flood look like this,
    so the link is dropped and the reply counted lost, as when the link dies (the cell
    then asks the controller what the gripper holds); a server that keeps answering so is
    a link that keeps dying, and the trees' retry limit ends it."""


@dataclass(frozen=True)
class Command:
    """One request verb: its arguments and the values of its ``OK`` reply."""

    verb: str
    args: tuple[str, ...] = ()
    reply: tuple[str, ...] = ()
    motion: bool = False             # takes robot time: the motion time-out applies


@dataclass(frozen=True)
class Message:
    """An unsolicited line on the notify socket."""

    verb: str
    fields: tuple[str, ...] = ()


# The declared command table, per socket. Keep one ``Command("VERB", ...)`` per line: the
# conformance test reads this literal.
COMMANDS: dict[str, tuple[Command, ...]] = {
    "motion": (
        Command("HELLO", (), ("version", "server")),
        Command("PICK", ("id", "x", "y", "angle", "latch", "tracking", "ox", "oy", "oz", "grip"), ("id", "x_mm"), motion=True),
        Command("PLACE", ("x", "y", "z", "rz"), (), motion=True),
        Command("MOVE", ("x", "y", "z", "rz"), (), motion=True),
        Command("SAFE", (), (), motion=True),
        Command("FRAME", ("x", "y", "rz"), ()),
        Command("DEFSAFE", ("x", "y", "z", "rz"), ()),
        Command("BELTSCALE", ("mm",), ()),
        Command("WINDOW", ("up", "down", "pick"), ()),
        Command("ESTOP", ("signal",), ()),
        Command("SPEED", ("pct",), ()),
        Command("RECOVER", ("power",), (), motion=True),
        Command("HOLDING", (), ("held",)),
        Command("HELD", (), ("held", "placed"), motion=True),
    ),
    "position": (
        Command("HELLO", (), ("version", "server")),
        Command("WHERE", (), ("x", "y", "z", "rz")),
        Command("BELT", (), ("count",)),
        Command("POLL", (), ("x", "y", "z", "rz", "count")),
        Command("HERE", (), ("x", "y", "z", "rz")),
        Command("STOP", (), ()),
    ),
    "io": (
        Command("HELLO", (), ("version", "server")),
        Command("SIG", ("signal",), ("value",)),
        Command("SET", ("signal", "value"), ()),
    ),
}

NOTIFY_MESSAGES: tuple[Message, ...] = (
    Message("IN", ("signal", "value")),
)

SOCKETS = ("motion", "position", "io", "notify")


def command(socket: str, verb: str) -> Command:
    """The table entry of ``verb`` on ``socket`` (a programming error if there is none)."""
    for cmd in COMMANDS[socket]:
        if cmd.verb == verb:
            return cmd
    raise KeyError(f"no command {verb} on the {socket} socket")


# ---------------------------------------------------------------------------- error codes
# V+ system messages (numbers from the V+ Language Reference's numerical list), and the
# codes our own server programs send. The class decides what the retriever does next:
# ServoTimeout runs the recovery subtree (RECOVER), EnvelopeError gives the part up, and
# PowerOff (power lost to an e-stop or a guard) goes to a person: never RECOVER.
CODE_POWER_OFF = -604
CODE_OUT_OF_RANGE = -610
CODE_TIMEOUT_NULLING = -1003
CODE_SOFT_ENVELOPE = -1006
CODE_MOTOR_STALLED = -1007
CODE_AMPLIFIER_FAULT = -1018
CODE_UNKNOWN_REQUEST = -9001
CODE_BAD_ARGUMENT = -9002
CODE_NOTHING_GRIPPED = -9003
CODE_OUTSIDE_WINDOW = -9004
CODE_REJECTED = -9005
CODE_STOPPED = -9006
CODE_ESTOP = -9007
CODE_NO_FRAME = -9008

VPLUS_ERRORS: dict[int, tuple[str, type[HalError]]] = {
    CODE_POWER_OFF: ("*Robot power off*", PowerOff),
    CODE_OUT_OF_RANGE: ("*Location out of range*", EnvelopeError),
    CODE_TIMEOUT_NULLING: ("*Time-out nulling errors*", ServoTimeout),
    CODE_SOFT_ENVELOPE: ("*Soft envelope error*", ServoTimeout),
    CODE_MOTOR_STALLED: ("*Motor stalled*", ServoTimeout),
    CODE_AMPLIFIER_FAULT: ("*Motor amplifier fault*", ServoTimeout),
    CODE_UNKNOWN_REQUEST: ("*Unknown request*", VplusError),
    CODE_BAD_ARGUMENT: ("*Bad argument*", VplusError),
    CODE_NOTHING_GRIPPED: ("*Nothing gripped*", MissedGrab),
    CODE_OUTSIDE_WINDOW: ("*Outside belt window*", EnvelopeError),
    CODE_REJECTED: ("*Request rejected*", VplusError),
    CODE_STOPPED: ("*Stopped by request*", VplusError),
    CODE_ESTOP: ("*E-stop input active*", PowerOff),
    CODE_NO_FRAME: ("*No cell frame*", VplusError),
}

# A controller release that numbers its messages differently still says the same words:
# unknown codes are classified by their $ERROR text.
_TEXT_CLASSES: tuple[tuple[str, type[HalError]], ...] = (
    ("nothing gripped", MissedGrab),
    ("out of range", EnvelopeError),
    ("belt window", EnvelopeError),
    ("too close", EnvelopeError),
    ("stalled", ServoTimeout),
    ("time-out nulling", ServoTimeout),
    ("envelope error", ServoTimeout),      # V+'s envelope = servo following error
    ("amplifier", ServoTimeout),
    ("power off", PowerOff),
    ("servo", ServoTimeout),
)


def error_text(code: int) -> str:
    """The $ERROR text our servers send with ``code``."""
    return VPLUS_ERRORS.get(code, (f"*Error {code}*", VplusError))[0]


def error_class(code: int, text: str) -> type[HalError]:
    """The HAL error type of a V+ error: by code, else by the words of its text."""
    if code in VPLUS_ERRORS:
        return VPLUS_ERRORS[code][1]
    low = text.lower()
    for words, cls in _TEXT_CLASSES:
        if words in low:
            return cls
    return VplusError


def vplus_error(code: int, text: str, context: str = "") -> HalError:
    """The typed error for an ``ERR`` reply; it carries ``code`` and ``text``."""
    cls = error_class(code, text)
    message = f"V+ {code} {text}" + (f" ({context})" if context else "")
    if cls is VplusError:
        return VplusError(code, text, message)
    err = cls(message)
    err.code, err.text = code, text      # type: ignore[attr-defined]
    return err


# ---------------------------------------------------------------------------- requests
def _fmt(value: object) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ProtocolError(f"cannot send a non-finite number ({value})")
        text = f"{value:.3f}".rstrip("0").rstrip(".")
        return "0" if text in ("-0", "") else text
    raise ProtocolError(f"cannot send {type(value).__name__} {value!r}")


def encode_request(socket: str, verb: str, *args: object) -> str:
    """``VERB arg ...\\n`` for a command of the table, with its argument count checked."""
    cmd = command(socket, verb)
    if len(args) != len(cmd.args):
        raise ProtocolError(f"{verb} takes {len(cmd.args)} arguments "
                            f"({' '.join(cmd.args) or 'none'}), not {len(args)}")
    line = " ".join([verb, *(_fmt(a) for a in args)])
    if len(line) >= MAX_LINE:
        raise ProtocolError(f"{verb} request longer than {MAX_LINE} characters")
    return line + "\n"


# ---------------------------------------------------------------------------- replies
def _clean(line: str | bytes, what: str) -> str:
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError(f"{what}: not ASCII: {line[:60]!r}") from None
    text = line.rstrip("\r\n")
    if not text.strip():
        raise ProtocolError(f"{what}: empty line")
    if len(text) >= MAX_LINE:
        raise ProtocolError(f"{what}: line longer than {MAX_LINE} characters")
    if not text.isascii() or not text.isprintable():
        raise ProtocolError(f"{what}: garbled line {text[:60]!r}")
    return text


def parse_reply(line: str | bytes, cmd: Command) -> list[str]:
    """The values of an ``OK`` reply to ``cmd``; raise the typed error of an ``ERR``.

    Anything else — garbage, a truncated line, the wrong number of values, an ``ERR``
    without a negative code — raises ``ProtocolError``, never IndexError/ValueError.
    """
    what = f"reply to {cmd.verb}"
    text = _clean(line, what)
    words = text.split()
    head = words[0]
    if head == "OK":
        values = words[1:]
        if len(values) != len(cmd.reply):
            raise ProtocolError(f"{what}: expected {len(cmd.reply)} values "
                                f"({' '.join(cmd.reply) or 'none'}), got {text!r}")
        return values
    if head == "ERR":
        parts = text.split(None, 2)
        if len(parts) < 2:
            raise ProtocolError(f"{what}: ERR without a code: {text!r}")
        code = _int(parts[1], "error code", what)
        if code >= 0:
            raise ProtocolError(f"{what}: V+ error codes are negative, got {code}")
        raise vplus_error(code, parts[2].strip() if len(parts) > 2 else "", cmd.verb)
    raise ProtocolError(f"{what}: neither OK nor ERR: {text[:60]!r}")


def _int(word: str, name: str, what: str) -> int:
    try:
        return int(word, 10)
    except ValueError:
        raise ProtocolError(f"{what}: {name} is not an integer: {word[:30]!r}") from None


def _float(word: str, name: str, what: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise ProtocolError(f"{what}: {name} is not a number: {word[:30]!r}") from None
    if not math.isfinite(value):
        raise ProtocolError(f"{what}: {name} is not finite: {word[:30]!r}")
    return value


def _flag(word: str, name: str, what: str) -> bool:
    if word not in ("0", "1"):
        raise ProtocolError(f"{what}: {name} must be 0 or 1, got {word[:30]!r}")
    return word == "1"


def decode_hello(values: list[str]) -> tuple[int, str]:
    """HELLO → (protocol version, server name)."""
    return _int(values[0], "version", "reply to HELLO"), values[1]


def decode_pick(values: list[str]) -> tuple[int, float]:
    """PICK → (part id, belt-frame x of the grip in mm)."""
    return _int(values[0], "id", "reply to PICK"), _float(values[1], "x_mm", "reply to PICK")


def decode_where(values: list[str]) -> Pose:
    """WHERE → the robot's pose (mm, degrees)."""
    x, y, z, rz = (_float(v, n, "reply to WHERE") for v, n in zip(values, "x y z rz".split(),
                                                                     strict=True))
    return Pose(x, y, z, rz)


def frame_args(base_mm: tuple[float, float], base_deg: float) -> tuple[float, float, float]:
    """FRAME's arguments: the robot base's pose in the cell frame (mm, mm, deg)."""
    return float(base_mm[0]), float(base_mm[1]), float(base_deg)


def estop_signal(bit: int, active_low: bool) -> int:
    """ESTOP's argument: the V+ input number of the e-stop, negative when the input is
    off while the e-stop is active (V+ ``SIG(-s)`` is the complement of ``SIG(s)``)."""
    signal = signal_of(bit, True)
    return -signal if active_low else signal


def wrap_robot(count: int) -> int:
    """Fold a count into the robot controller's 24-bit signed belt counter."""
    half = ROBOT_COUNT_MAX + 1
    return ((count + half) % (2 * half)) - half


def decode_belt(values: list[str]) -> int:
    """BELT → the robot controller's 24-bit signed count of the belt encoder."""
    count = _int(values[0], "count", "reply to BELT")
    if not ROBOT_COUNT_MIN <= count <= ROBOT_COUNT_MAX:
        raise ProtocolError(f"reply to BELT: count {count} outside the 24-bit range")
    return count


def decode_poll(values: list[str]) -> tuple[Pose, int]:
    """POLL → (the robot's pose, the belt count): WHERE and BELT in one round trip."""
    return decode_where(values[:4]), decode_belt(values[4:])


def decode_held(values: list[str]) -> Held:
    """HELD → ``Held``: the commanded id in the gripper (0 none, -1 something no pick of
    ours gripped) and the id of the last part released at a place pose (0 none)."""
    what = "reply to HELD"
    held, placed = _int(values[0], "held", what), _int(values[1], "placed", what)
    if held < -1 or placed < 0:
        raise ProtocolError(f"{what}: held must be >= -1 and placed >= 0, got {held} {placed}")
    return Held(part_id=held if held > 0 else None, unknown=held == -1,
                last_placed=placed or None)


def decode_flag(values: list[str], verb: str) -> bool:
    """SIG, HOLDING → a 0/1 flag."""
    return _flag(values[0], "value", f"reply to {verb}")


def parse_notify(line: str | bytes) -> tuple[int, bool]:
    """``IN <signal> <0|1>`` → (V+ signal number, state)."""
    what = "notification"
    words = _clean(line, what).split()
    if len(words) != 3 or words[0] != "IN":
        raise ProtocolError(f"{what}: expected 'IN <signal> <0|1>', got {' '.join(words)[:60]!r}")
    return _int(words[1], "signal", what), _flag(words[2], "value", what)


# ---------------------------------------------------------------------------- I/O numbering
# V+ signal numbers: digital outputs 1-999 (0001-0008 on the controller), inputs 1001-1999,
# soft signals 2001-2999. The cell description gives a bit per signal and its direction.
INPUT_BASE = 1000
SOFT_BASE = 2000


def signal_of(bit: int, is_input: bool) -> int:
    """The V+ signal number of the cell description's ``bit`` on the Adept controller."""
    if bit >= INPUT_BASE:
        return bit                     # already a V+ signal number
    return INPUT_BASE + bit if is_input else bit


def bit_of(signal: int) -> tuple[int, bool]:
    """(cell bit, is input) of a V+ signal number; soft signals keep their number."""
    if INPUT_BASE < signal < SOFT_BASE:
        return signal - INPUT_BASE, True
    return signal, False
