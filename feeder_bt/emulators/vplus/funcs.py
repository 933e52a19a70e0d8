"""The V+ real-valued and string functions the programs use that touch no device.

V+ Language Reference Guide (each keyword's page): ``$ENCODE`` formats its arguments
(``/In`` an integer in a field of n characters, ``/Fm.n`` fixed point with n decimals; a
field of 0 is as wide as the number needs); ``$DECODE(string, separators, mode)`` mode 0
returns the characters up to the first separator and removes them from the string
variable (mode 1 returns the separators); ``$MID(s, first, n)``; ``LEN``; ``ASC(s, i)``
the code of the i-th character (-1 past the end); ``POS(s, sub, start)`` the position
of ``sub`` in ``s`` from ``start``, 0 if absent; ``VAL`` the number at the start of a
string (0 if none); ``INT`` the integer part (truncated toward zero); ``ABS``. The
``$ERROR`` texts are the V+ messages of the codes the programs meet (numerical list of
V+ system messages); others read ``*Error n*``.
"""

from __future__ import annotations

import math
import re
from typing import Any

from feeder_bt.hal.adept import protocol as P

ERROR_TEXTS = {code: text for code, (text, _) in P.VPLUS_ERRORS.items()}
ERROR_TEXTS.update({
    -401: "*Undefined value*",                  # NOT CONFIRMED: number
    -526: "*No data received*",
    -527: "*Network connection lost*",          # NOT CONFIRMED: a broken TCP link's code
    -411: "*Program not found*",                # NOT CONFIRMED: number
})

_NUM = re.compile(r"\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def encode(args: list[Any]) -> str:
    out: list[str] = []
    spec = ("I", 0, 0)
    for a in args:
        if isinstance(a, tuple) and a and a[0] == "fmt":
            s = a[1]
            kind, _, rest = s[0], None, s[1:]
            if "." in rest:
                w, d = rest.split(".")
                spec = (kind, int(w or 0), int(d))
            else:
                spec = (kind, int(rest or 0), 0)
            continue
        if isinstance(a, str):
            out.append(a)
            continue
        kind, width, decimals = spec
        if kind == "I":
            text = str(int(round(a)))
        else:
            text = f"{a:.{decimals}f}"
            if text.startswith("-") and float(text) == 0.0:
                text = text[1:]
        out.append(text.rjust(width))
    return "".join(out)


def decode(cell: Any, seps: str, mode: float) -> str:
    s: str = cell.v or ""
    if int(mode) == 0:
        i = 0
        while i < len(s) and s[i] not in seps:
            i += 1
    else:
        i = 0
        while i < len(s) and s[i] in seps:
            i += 1
    cell.v = s[i:]
    return s[:i]


def mid(s: str, first: float, n: float = 1.0) -> str:
    i = max(int(first), 1) - 1
    return s[i:i + max(int(n), 0)]


def asc(s: str, i: float = 1.0) -> float:
    k = int(i) - 1
    return float(ord(s[k])) if 0 <= k < len(s) else -1.0


def pos(s: str, sub: str, start: float = 1.0) -> float:
    k = s.find(sub, max(int(start), 1) - 1)
    return float(k + 1)


def val(s: str) -> float:
    m = _NUM.match(s)
    return float(m.group(0)) if m else 0.0


def error_text(code: float) -> str:
    c = int(code)
    return ERROR_TEXTS.get(c, f"*Error {c}*")


PURE = {
    "$encode": lambda a: encode(a),
    "$mid": lambda a: mid(*a),
    "len": lambda a: float(len(a[0])),
    "asc": lambda a: asc(*a),
    "pos": lambda a: pos(*a),
    "val": lambda a: val(a[0]),
    "int": lambda a: float(math.trunc(a[0])),
    "abs": lambda a: abs(a[0]),
    "true": lambda a: -1.0,
    "false": lambda a: 0.0,
    "pi": lambda a: math.pi,
    "$error": lambda a: error_text(a[0]),
    "sqrt": lambda a: math.sqrt(a[0]),
    "max": lambda a: max(a),
    "min": lambda a: min(a),
    "$decode": lambda a: decode(*a),
}
