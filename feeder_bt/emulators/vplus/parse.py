"""V+ lines and expressions: tokens, a precedence parser, closures that evaluate.

An expression becomes a tree of tuples (``parse_expr``), then a closure ``f(ctx)``
(``compile_expr``) that asks the task context ``ctx`` for variables (``get``,
``get_elem``), references (``ref``, ``ref_elem``: V+ passes variables to CALL and to
``$DECODE`` by reference) and functions (``func``). Names are case-insensitive and kept
in lower case; ``$`` names are strings, ``%`` names belts (V+ Language User's Guide v17,
"Variable Name Requirements", p. 99).

Precedence, lowest first (V+ Language User's Guide, "Operator Precedence"; the programs
parenthesise every mixed logical expression, so only the usual order matters): OR XOR,
AND, NOT, relations (== <> < > <= >=), + -, * / MOD, ^, unary minus, ``:``
(transformation composition).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

Node = tuple
Expr = Callable[[Any], Any]

_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<str>"[^"]*")
  | (?P<num>\d+\.\d*|\.\d+|\d+)
  | (?P<name>[$%#]?[A-Za-z_][A-Za-z0-9_.]*)
  | (?P<op><=|>=|<>|==|[-+*/^<>=:,()\[\]])
""", re.VERBOSE)
_FMT = re.compile(r"/[A-Za-z]\d*(\.\d+)?")
_WORD_OPS = {"and", "or", "xor", "not", "mod"}
_NULLARY = {"here", "true", "false", "pi"}       # functions written without parentheses


class SyntaxErr(Exception):
    """A line the interpreter cannot parse (the checker should have refused it)."""


def tokenize(text: str) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    i = 0
    while i < len(text):
        if text[i] == "/" and (not out or out[-1][1] in ("(", ",")):
            m = _FMT.match(text, i)
            if m:
                out.append(("fmt", m.group(0)[1:].upper()))
                i = m.end()
                continue
        m = _TOKEN.match(text, i)
        if not m:
            raise SyntaxErr(f"unexpected {text[i:i + 10]!r}")
        i = m.end()
        kind = m.lastgroup
        if kind == "ws":
            continue
        value = m.group(0)
        if kind == "name":
            value = value.lower()
            if value in _WORD_OPS:
                kind = "op"
        elif kind == "str":
            value = value[1:-1]
        out.append((kind, value))
    return out


def strip_comment(line: str) -> str:
    """The code of a line: ``;`` outside a string starts a comment."""
    quoted = False
    for i, ch in enumerate(line):
        if ch == '"':
            quoted = not quoted
        elif ch == ";" and not quoted:
            return line[:i]
    return line


class Parser:
    """A token stream with the expression grammar."""

    _BIN = [({"or", "xor"}, 1), ({"and"}, 2), ({"==", "<>", "<", ">", "<=", ">="}, 4),
            ({"+", "-"}, 5), ({"*", "/", "mod"}, 6), ({"^"}, 7)]

    def __init__(self, tokens: list[tuple[str, str]]) -> None:
        self.toks, self.i = tokens, 0

    def peek(self, k: int = 0) -> tuple[str, str] | None:
        j = self.i + k
        return self.toks[j] if j < len(self.toks) else None

    def at(self, value: str) -> bool:
        t = self.peek()
        return t is not None and t[0] in ("op", "name") and t[1] == value

    def take(self, value: str | None = None) -> tuple[str, str]:
        t = self.peek()
        if t is None or (value is not None and t[1] != value):
            raise SyntaxErr(f"expected {value or 'more'}, got {t[1] if t else 'end of line'}")
        self.i += 1
        return t

    def done(self) -> bool:
        return self.i >= len(self.toks)

    def rest(self) -> list[tuple[str, str]]:
        return self.toks[self.i:]

    # ---------------------------------------------------------------- grammar
    def expr(self, level: int = 1) -> Node:
        if level == 3:                                   # NOT
            if self.at("not"):
                self.take()
                return ("un", "not", self.expr(3))
            return self.expr(4)
        if level > 7:
            return self.unary()
        ops = next((o for o, lv in self._BIN if lv == level), None)
        if ops is None:
            return self.expr(level + 1)
        left = self.expr(level + 1)
        while (t := self.peek()) is not None and t[0] == "op" and t[1] in ops:
            self.take()
            left = ("bin", t[1], left, self.expr(level + 1))
        return left

    def unary(self) -> Node:
        if self.at("-"):
            self.take()
            return ("un", "-", self.unary())
        if self.at("+"):
            self.take()
            return self.unary()
        left = self.primary()
        while self.at(":"):
            if self.peek(1) is None:                     # "VALUE 1:" ends a CASE label
                break
            self.take()
            left = ("bin", ":", left, self.primary())
        return left

    def primary(self) -> Node:
        kind, value = self.take()
        if kind == "num":
            return ("num", float(value))
        if kind == "str":
            return ("str", value)
        if kind == "fmt":
            return ("fmt", value)
        if kind == "op" and value == "(":
            e = self.expr()
            self.take(")")
            return e
        if kind != "name":
            raise SyntaxErr(f"unexpected {value!r}")
        if self.at("("):
            self.take("(")
            args = self.args(")")
            return ("call", value, args)
        if self.at("["):
            self.take("[")
            idx = self.args("]")
            return ("idx", value, idx)
        if value in _NULLARY:
            return ("call", value, [])
        return ("var", value)

    def args(self, close: str) -> list[Node]:
        out: list[Node] = []
        if self.at(close):
            self.take(close)
            return out
        while True:
            out.append(self.expr())
            if self.at(","):
                self.take(",")
                continue
            self.take(close)
            return out

    def expr_list(self) -> list[Node]:
        """``a, b, c`` to the end of the line."""
        out = [self.expr()]
        while self.at(","):
            self.take(",")
            out.append(self.expr())
        return out


def parse_expr(text: str) -> Node:
    p = Parser(tokenize(text))
    e = p.expr()
    if not p.done():
        raise SyntaxErr(f"unexpected {p.peek()[1]!r} after the expression")  # type: ignore[index]
    return e


# ---------------------------------------------------------------------------- closures
def _truth(v: Any) -> bool:
    return bool(v)


def _vbool(b: bool) -> float:
    return -1.0 if b else 0.0          # V+ TRUE is -1 (all bits set), FALSE 0


def _binop(op: str) -> Callable[[Any, Any, Any], Any]:
    import operator as o
    table: dict[str, Callable[[Any, Any], Any]] = {
        "+": o.add, "-": o.sub, "*": o.mul, "/": o.truediv, "^": o.pow,
        "mod": lambda a, b: a - b * int(a / b),
        "==": lambda a, b: _vbool(a == b), "<>": lambda a, b: _vbool(a != b),
        "<": lambda a, b: _vbool(a < b), ">": lambda a, b: _vbool(a > b),
        "<=": lambda a, b: _vbool(a <= b), ">=": lambda a, b: _vbool(a >= b),
        "and": lambda a, b: _vbool(_truth(a) and _truth(b)),
        "or": lambda a, b: _vbool(_truth(a) or _truth(b)),
        "xor": lambda a, b: _vbool(_truth(a) != _truth(b)),
    }
    return table[op]  # type: ignore[return-value]


def compile_expr(node: Node) -> Expr:
    kind = node[0]
    if kind in ("num", "str"):
        v = node[1]
        return lambda c: v
    if kind == "fmt":
        spec = node[1]
        return lambda c: ("fmt", spec)
    if kind == "var":
        name = node[1]
        return lambda c: c.get(name)
    if kind == "idx":
        name, idx = node[1], [compile_expr(n) for n in node[2]]
        return lambda c: c.get_elem(name, tuple(int(f(c)) for f in idx))
    if kind == "un":
        f = compile_expr(node[2])
        if node[1] == "not":
            return lambda c: _vbool(not _truth(f(c)))
        return lambda c: -f(c)
    if kind == "bin":
        a, b = compile_expr(node[2]), compile_expr(node[3])
        if node[1] == ":":
            return lambda c: c.compose(a(c), b(c))
        if node[1] in ("and", "or"):             # V+ evaluates both sides; no effects here
            op = _binop(node[1])
            return lambda c: op(a(c), b(c))
        op = _binop(node[1])
        if node[1] in ("==", "<>"):
            return lambda c: op(a(c), b(c))
        return lambda c: op(a(c), b(c))
    if kind == "call":
        name, args = node[1], node[2]
        if name == "$decode":                    # its first argument is changed in place
            ref = compile_ref(args[0])
            rest = [compile_expr(n) for n in args[1:]]
            return lambda c: c.func(name, [ref(c)] + [f(c) for f in rest])
        if name == "switch":                     # SWITCH(POWER): a switch's name
            switch = args[0][1] if args and args[0][0] == "var" else ""
            return lambda c: c.func("switch", [switch])
        fs = [compile_expr(n) for n in args]
        return lambda c: c.func(name, [f(c) for f in fs])
    raise SyntaxErr(f"cannot evaluate {node!r}")


def compile_ref(node: Node) -> Expr:
    """A reference to a variable or array element (CALL arguments, $DECODE); any other
    expression is passed by value (a fresh cell)."""
    if node[0] == "var":
        name = node[1]
        return lambda c: c.ref(name)
    if node[0] == "idx":
        name, idx = node[1], [compile_expr(n) for n in node[2]]
        return lambda c: c.ref_elem(name, tuple(int(f(c)) for f in idx))
    f = compile_expr(node)
    return lambda c: c.value_cell(f(c))


def truth(v: Any) -> bool:
    return _truth(v)
