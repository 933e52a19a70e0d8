"""The DMC language's expressions for the emulator's interpreter (``dmc``): the error
type with Galil's codes, the lexer, left-to-right evaluation with no operator precedence,
and ``MG`` number formatting."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from feeder_bt.hal.galil.protocol import ERROR_TEXT


class DmcError(Exception):
    """A Galil error: ``code`` and ``text`` as ``TC1`` reports them."""

    def __init__(self, code: int, detail: str | None = None) -> None:
        self.code = code
        self.text = ERROR_TEXT.get(code, "Unrecognized command")
        self.detail = detail
        super().__init__(f"{code} {self.text}" + (f" ({detail})" if detail else ""))


class DmcHost(Protocol):
    """What the interpreter needs from the controller around it."""

    def operand(self, name: str, suffix: str) -> float:
        """``_TPB`` -> ``operand('TP', 'B')``; ``_TI0`` -> ``operand('TI', '0')``."""

    def function(self, name: str, arg: float) -> float:
        """``@IN[3]`` -> ``function('IN', 3)`` (I/O functions only)."""

    def command(self, text: str, thread: int) -> None:
        """Carry out a non-flow command from a program (``SB 1``, ``BGB``)."""

    def output(self, text: str) -> None:
        """Program output (``MG``), with its CR/LF, for the unsolicited channel."""

    def thread_error(self, thread: int, error: DmcError, line: int, text: str,
                     trapped: bool = False) -> None:
        """A thread stopped on an error at program line ``line`` (``trapped``: it went on
        in the program's ``#CMDERR`` instead)."""


# ---------------------------------------------------------------------------- lexer

_TOKEN_RE = re.compile(r"""
    (?P<ws>\s+)
  | (?P<str>"[^"]*")
  | (?P<hex>\$[0-9A-Fa-f]+)
  | (?P<num>\d+\.?\d*|\.\d+)
  | (?P<opnd>_[A-Z]{2}[A-H0-9]*)
  | (?P<func>@[A-Z]{2,4})
  | (?P<name>[A-Za-z][A-Za-z0-9]*)
  | (?P<cmp><>|<=|>=|=|<|>)
  | (?P<op>[-+*/&|])
  | (?P<punct>[()\[\],])
""", re.X)


@dataclass(frozen=True)
class Tok:
    kind: str
    text: str
    value: float = 0.0


def tokenize(text: str) -> list[Tok]:
    """Tokens of an expression; raises ``DmcError`` on a character it cannot read."""
    out: list[Tok] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN_RE.match(text, pos)
        if not m:
            raise DmcError(1, f"cannot read {text[pos:]!r}")
        kind = m.lastgroup or ""
        s = m.group()
        pos = m.end()
        if kind == "ws":
            continue
        if kind == "num":
            out.append(Tok("num", s, float(s)))
        elif kind == "hex":
            out.append(Tok("num", s, float(int(s[1:], 16))))
        else:
            out.append(Tok(kind, s))
    return out


# ---------------------------------------------------------------------------- expressions


class _Parser:
    """Recursive descent over tokens, evaluating as it goes (Galil's left-to-right rules)."""

    def __init__(self, toks: list[Tok], env: Any) -> None:
        self.toks, self.i, self.env = toks, 0, env

    def peek(self) -> Tok | None:
        return self.toks[self.i] if self.i < len(self.toks) else None

    def take(self) -> Tok:
        tok = self.peek()
        if tok is None:
            raise DmcError(1, "expression ends too early")
        self.i += 1
        return tok

    def expect(self, text: str, code: int) -> None:
        tok = self.peek()
        if tok is None or tok.text != text:
            raise DmcError(code, f"expected {text!r}")
        self.i += 1

    def condition(self) -> float:
        left = self.arith()
        tok = self.peek()
        if tok is not None and tok.kind == "cmp":
            self.i += 1
            right = self.arith()
            return 1.0 if _compare(tok.text, left, right) else 0.0
        return left

    def arith(self) -> float:
        value = self.unary()
        while (tok := self.peek()) is not None and tok.kind == "op":
            self.i += 1
            value = _apply(tok.text, value, self.unary())
        return value

    def unary(self) -> float:
        tok = self.peek()
        if tok is not None and tok.kind == "op" and tok.text in "+-":
            self.i += 1
            v = self.unary()
            return -v if tok.text == "-" else v
        return self.primary()

    def primary(self) -> float:
        tok = self.take()
        if tok.kind == "num":
            return tok.value
        if tok.text == "(":
            v = self.condition()
            self.expect(")", 59)
            return v
        if tok.kind == "name":
            return self.env.variable(tok.text)
        if tok.kind == "opnd":
            return self.env.operand(tok.text)
        if tok.kind == "func":
            self.expect("[", 55)
            arg = self.condition()
            self.expect("]", 55)
            return self.env.function(tok.text[1:], arg)
        if tok.kind == "str":
            return _string_value(tok.text[1:-1])
        raise DmcError(1, f"unexpected {tok.text!r}")


def _string_value(s: str) -> float:
    """Galil packs up to 6 characters of a string into one number (first char highest)."""
    if len(s) > 6:
        raise DmcError(52, "string longer than 6 characters")
    v = 0
    for ch in s:
        v = (v << 8) | (ord(ch) & 0xFF)
    return float(v)


def _compare(op: str, a: float, b: float) -> bool:
    if op == "=":
        return abs(a - b) < 1e-9
    if op == "<>":
        return abs(a - b) >= 1e-9
    return {"<": a < b, ">": a > b, "<=": a <= b + 1e-9, ">=": a >= b - 1e-9}[op]


def _apply(op: str, a: float, b: float) -> float:
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        if b == 0:
            raise DmcError(6, "division by zero")
        return a / b
    if op == "&":
        return float(int(a) & int(b))
    return float(int(a) | int(b))      # '|'


_MATH: dict[str, Callable[[float], float]] = {
    "ABS": abs,
    "INT": lambda x: float(math.trunc(x)),
    "FRAC": lambda x: x - math.trunc(x),
    "RND": lambda x: float(math.floor(x + 0.5)),
    "COM": lambda x: float(~int(x) & 0xFFFFFFFF),
    "SQR": lambda x: math.sqrt(x) if x >= 0 else _raise(DmcError(6, "square root of < 0")),
}


def _raise(e: Exception) -> float:
    raise e


# ---------------------------------------------------------------------------- MG formatting


def format_number(value: float, kind: str = "", m: int = 10, n: int = 4) -> str:
    """A number as ``MG`` prints it: a sign column (space or ``-``), digits, decimals.

    ``kind`` '' is the default variable format (10.4, leading zeros suppressed); ``F`` pads
    the integer part with zeros to ``m`` digits, ``Z`` does not, ``$`` prints hex. A value
    too large for ``m`` digits prints as all nines, as the controller does.
    """
    sign = "-" if value < 0 else " "
    a = abs(value)
    if kind == "$":
        digits = f"{int(a):X}"
        return f"{sign}${digits.rjust(m, '0')[-m:] if m else digits}"
    scale = 10 ** n
    units = math.floor(a * scale + 0.5)
    whole, frac = divmod(units, scale)
    if kind in ("F", "Z") and len(str(whole)) > m:
        whole, frac = 10 ** m - 1, scale - 1
    whole_s = str(whole).rjust(m, "0") if kind == "F" else str(whole)
    if n > 0:
        return f"{sign}{whole_s}.{str(frac).rjust(n, '0')}"
    return f"{sign}{whole_s}"


_FMT_RE = re.compile(r"\{([^}]*)\}")


def split_args(text: str) -> list[str]:
    """Split on commas outside quotes, brackets, braces and parentheses."""
    out, depth, quoted, cur = [], 0, False, []
    for ch in text:
        if ch == '"':
            quoted = not quoted
        elif not quoted and ch in "([{":
            depth += 1
        elif not quoted and ch in ")]}":
            depth -= 1
        if ch == "," and not quoted and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if quoted:
        raise DmcError(52, "missing quote")
    out.append("".join(cur))
    return out
