"""A checker for the V+ programs of ``vplus/``: it refuses what a V+ controller's LOAD refuses,
and what the programs would do wrong at run time where a static check can see it.

The Adept emulator runs only programs this checker accepts (``AdeptEmulator.start``), and the
tests check every shipped program with it, so a program that would not load on the robot
controller cannot pass as working against the emulator.

Rules, each with its source (docs/real-cell.md, "The Adept controller (V+)"):

- ``reserved``: a V+ keyword (instruction, function, operator, system switch or parameter,
  monitor command) used as a variable, parameter or program name (User's Guide v17 p. 99,
  "Variable Name Requirements"). The index, its sources and where it may be incomplete are
  in ``vplus_words.py``; RX, RY, RZ (transformation functions) are among them, so ``rz`` is
  refused. The whole name is compared: ``rz.max`` is one word, not RZ (``vplus_words``).
- ``long-name``: a name over 15 characters. V+ keeps only the first 15 and silently truncates
  the rest (User's Guide p. 99), so two long names can become one variable; refused.
- ``bad-name``: a name that does not start with a letter or holds other characters than
  letters, digits, ``.`` and ``_`` (User's Guide p. 99).
- ``non-ascii``: any character outside 7-bit ASCII (V+ text is ASCII).
- ``outside``: anything but blank lines outside ``.PROGRAM`` ... ``.END`` (a program starts with
  its ``.PROGRAM`` step and ends with ``.END``: User's Guide p. 36).
- ``long-line``: a line longer than ``max_line`` characters. NOT CONFIRMED: the V+ limit on a
  program step's length was not found; ``max_line`` is a setting, 80 by default.
- ``structure``: unbalanced or mismatched control structures: IF ... THEN / ELSE / END,
  WHILE ... DO / END, DO / UNTIL, FOR / END, CASE ... OF / VALUE / ANY / END (the editor marks
  such a program not executable: User's Guide p. 36).
- ``declaration``: AUTO, LOCAL or GLOBAL after an executable step (User's Guide p. 36).
- ``unknown-instruction``: a step whose first word is not a V+ program instruction
  (``vplus_words.INSTRUCTIONS``), and not an assignment (a CALL is an instruction): "the
  operation portion of each step must be a valid V+ language keyword" (User's Guide p. 35).
- ``type``: a string (a literal, a ``$`` name or ``$`` function, joined by ``+``) assigned
  to a name without ``$``, or a number to a ``$`` name: string variables are the ``$``
  names (User's Guide p. 99: the first use fixes a variable's type). Locations (SET, ``#``,
  ``%``) are not judged.
- ``undefined``: CALL / EXECUTE / REACTE / REACTI / REACT / WINDOW naming a program no file
  defines (User's Guide p. 45: *Undefined program or variable name*); ``duplicate``: a
  program defined twice.
- ``arguments``: a CALL or EXECUTE with another number of arguments than the program has
  parameters. More is an error; fewer is legal V+ (the rest are passed undefined, User's
  Guide p. 45) but none of our programs relies on it, so it is refused as a slip.
- ``trap``: RETURNE in a program no REACTE names (RETURNE returns from an error trap).
- ``forward-processing``: a SIGNAL, BELT read or HERE read after a motion instruction with
  no BREAK between, on some path through the program (``vplus_flow.py`` defines which
  statements are which, and its limits).

- ``unassigned``: an AUTO variable read before any step could give it a value, or a global
  read while no step of any program could give it one (V+ stops with *Undefined value* at
  run time; ``vplus_vars.py`` says what counts as a read).

Not checked: which signal numbers are outputs, run-time values, the way round a loop
(``vplus_flow.py``), anything a V+ release or an option adds.

``python -m feeder_bt.emulators.vplus.check [DIR] [--max-line N]`` prints one line per finding,
``FILE:LINE: rule: what``, and exits 1 if there is any.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from feeder_bt.core.errors import ConfigError
from feeder_bt.emulators.vplus.flow import NOWAIT, FlowProgram, ForwardChecker
from feeder_bt.emulators.vplus.vars import unassigned
from feeder_bt.emulators.vplus.words import INSTRUCTIONS, reserved

VPLUS_DIR = Path(__file__).resolve().parents[3] / "vplus"
MAX_NAME = 15                 # V+ significant characters in a name (User's Guide p. 99)
MAX_LINE = 80                 # NOT CONFIRMED: a setting (module docstring)

_NAME = re.compile(r"(?<![\w./])[$#%]?[A-Za-z_][\w.]*")
_VALID = re.compile(r"^[$#%]?[A-Za-z][A-Za-z0-9._]*$")
_PROGRAM = re.compile(r"^\.PROGRAM\s+(\S+?)\s*\((.*)\)\s*$", re.IGNORECASE)
_ASSIGN = re.compile(r"^\s*(?:SET\s+)?([$#%]?[A-Za-z_][\w.]*)\s*(?:\[[^\]]*\])?\s*=(?!=)",
                     re.IGNORECASE)
_CALLED = re.compile(r"\b(CALLS?|EXECUTE(?:\s+[\w.]+)?|REACTE)\s+([A-Za-z_][\w.]*)\s*(\()?")
_REACT = re.compile(r"\b(REACTI?)\s+[^,]+,\s*([A-Za-z_][\w.]*)")
_LABEL = re.compile(r"^\d+\s+")
_HEAD = re.compile(r"^[$#%]?[A-Za-z][\w.]*")
_LOGIC = re.compile(r"==|<>|<=|>=|<|>|\b(?:AND|OR|NOT|XOR)\b")
_WINDOW_PROG = re.compile(r"^\s*WINDOW\s+%[\w.]+\s*=.*,\s*([a-z_][\w.]*)\s*,\s*\d+\s*$",
                          re.IGNORECASE)
_STRING = re.compile(r'"[^"]*"')
_OPENERS = {"IF": "END", "WHILE": "END", "FOR": "END", "CASE": "END", "DO": "UNTIL"}


@dataclass(frozen=True)
class Finding:
    file: str
    line: int
    rule: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.rule}: {self.message}"


@dataclass
class _Program:
    name: str
    line: int
    params: int = 0
    executable: bool = False
    flow: FlowProgram | None = None


@dataclass(frozen=True)
class _Call:
    kind: str                    # CALL, EXECUTE, REACTE, REACTI, WINDOW
    name: str
    file: str
    line: int
    args: int | None = None      # argument count of a CALL/EXECUTE, None when not given


def _code(raw: str) -> str:
    """The line without its comment and with its string literals blanked."""
    blanked = _STRING.sub(lambda m: '"' + " " * (len(m.group()) - 2) + '"', raw)
    cut = blanked.find(";")
    return blanked if cut < 0 else blanked[:cut]


def _is_user_name(token: str) -> bool:
    """Keywords are written in capitals, names in lower case (the V+ editor's own format:
    User's Guide p. 36); a token with a lower-case letter is a name."""
    return any(c.islower() for c in token)


class Checker:
    """Check V+ sources; ``findings`` collects what V+ would refuse."""

    def __init__(self, max_line: int = MAX_LINE, max_name: int = MAX_NAME) -> None:
        self.max_line, self.max_name = max_line, max_name
        self.findings: list[Finding] = []
        self.defined: dict[str, tuple[str, int]] = {}
        self.params: dict[str, int] = {}
        self.called: list[_Call] = []
        self.flow: dict[str, FlowProgram] = {}
        self.returne: list[tuple[str, str, int]] = []      # (program, file, line)

    def _add(self, file: str, line: int, rule: str, message: str) -> None:
        self.findings.append(Finding(file, line, rule, message))

    def _name(self, file: str, n: int, name: str, what: str) -> None:
        bare = name.lstrip("$#%")
        if not _VALID.match(name):
            self._add(file, n, "bad-name", f"{what} {name!r} is not a V+ name")
        elif reserved(name):
            self._add(file, n, "reserved", f"{what} {name!r} is the V+ keyword {bare.upper()}")
        elif len(bare) > self.max_name:
            self._add(file, n, "long-name", f"{what} {name!r} has {len(bare)} characters; "
                                            f"V+ keeps only the first {self.max_name}")

    # ------------------------------------------------------------------ one file
    def check_text(self, text: str, file: str) -> None:
        program: _Program | None = None
        stack: list[tuple[str, int]] = []
        for n, raw in enumerate(text.splitlines(), 1):
            bad = [c for c in raw if ord(c) > 127]
            if bad:
                self._add(file, n, "non-ascii", f"character {bad[0]!r} (U+{ord(bad[0]):04X}) "
                                                f"at column {raw.index(bad[0]) + 1}")
            if len(raw) > self.max_line:
                self._add(file, n, "long-line", f"{len(raw)} characters (limit {self.max_line})")
            stripped = raw.strip()
            code = _code(raw).strip()
            if program is None:
                m = _PROGRAM.match(code)
                if m:
                    program = self._start(file, n, m)
                    stack = []
                elif stripped:
                    self._add(file, n, "outside", "text outside .PROGRAM ... .END")
                continue
            if code.upper() == ".END":
                for kind, at in stack:
                    self._add(file, at, "structure", f"{kind} is never closed "
                                                     f"(by .END of {program.name})")
                program = None
                continue
            if _PROGRAM.match(code):
                self._add(file, n, "structure", f".PROGRAM inside {program.name} (no .END)")
                continue
            if code:
                self._statement(file, n, code, program, stack)
                if NOWAIT in raw[len(_code(raw)):] and program.flow is not None:
                    program.flow.nowait.add(n)
        if program is not None:
            self._add(file, program.line, "structure", f"{program.name} has no .END")

    def _start(self, file: str, n: int, m: re.Match) -> _Program:
        name = m.group(1)
        self._name(file, n, name, "program name")
        if name.lower() in self.defined:
            other = self.defined[name.lower()]
            self._add(file, n, "duplicate", f"program {name} also in {other[0]}:{other[1]}")
        else:
            self.defined[name.lower()] = (file, n)
        params = [p.strip() for p in m.group(2).split(",")] if m.group(2).strip() else []
        for param in params:
            self._name(file, n, param.split("[")[0].strip(), "parameter")
        flow = FlowProgram(name, file, params=[q.split("[")[0].strip() for q in params])
        if name.lower() not in self.flow:
            self.flow[name.lower()] = flow
            self.params[name.lower()] = len(params)
        return _Program(name, n, len(params), flow=flow)

    def _statement(self, file: str, n: int, code: str, program: _Program,
                   stack: list[tuple[str, int]]) -> None:
        code = _LABEL.sub("", code)                # a step label (GOTO target)
        if not code:
            return
        words = code.split()
        head_m = _HEAD.match(code)
        head = (head_m.group() if head_m else words[0]).upper()
        if program.flow is not None:
            program.flow.steps.append((n, code))
        # names: declared, assigned, or written as names anywhere
        if head in ("AUTO", "LOCAL", "GLOBAL"):
            if program.executable:
                self._add(file, n, "declaration", f"{head} after an executable step")
            for decl in code[len(words[0]):].split(","):
                decl = decl.strip().split("[")[0].strip()
                if decl:
                    self._name(file, n, decl, "variable")
            return
        program.executable = True
        target = _ASSIGN.match(code)
        if target and head in ("FOR", "IF", "WHILE", "UNTIL"):
            target = None
        if target:
            self._name(file, n, target.group(1), "variable")
            self._types(file, n, target.group(1), code[target.end():],
                        code.upper().startswith("SET"))
        elif head not in INSTRUCTIONS:
            self._add(file, n, "unknown-instruction",
                      f"{words[0]!r} is not a V+ program instruction, a CALL or an "
                      "assignment")
        seen = {target.group(1)} if target else set()
        for tok in _NAME.findall(code):
            if tok not in seen and _is_user_name(tok):
                seen.add(tok)
                self._name(file, n, tok, "name")
        self._calls(file, n, code)
        if head == "RETURNE":
            self.returne.append((program.name, file, n))
        if not target:
            self._structure(file, n, words, stack)     # an assignment opens nothing

    def _calls(self, file: str, n: int, code: str) -> None:
        """Record the programs this step names (checked in ``finish``)."""
        for m in _CALLED.finditer(code):
            kind = m.group(1).split()[0].upper().rstrip("S")
            args = _count_args(code, m.end() - 1) if m.group(3) else None
            self.called.append(_Call(kind, m.group(2), file, n, args))
        for m in _REACT.finditer(code):
            self.called.append(_Call(m.group(1).upper(), m.group(2), file, n))
        for m in _WINDOW_PROG.finditer(code):
            self.called.append(_Call("WINDOW", m.group(1), file, n))

    def _types(self, file: str, n: int, target: str, rhs: str, located: bool) -> None:
        """``type``: a ``$`` name holds a string, a plain name a number (User's Guide p. 99:
        the first use of a variable fixes its type; string names start with ``$``)."""
        if located or target[0] in "#%":
            return                                     # locations: SET, precision, belt
        rhs = rhs.strip()
        is_string = rhs[:1] in ('"', "$") and not _LOGIC.search(rhs)
        if target[0] == "$" and not is_string:
            self._add(file, n, "type", f"string variable {target} is assigned a number "
                                       f"({rhs[:30]})")
        elif target[0] != "$" and is_string:
            self._add(file, n, "type", f"real variable {target} is assigned a string "
                                       f"({rhs[:30]}); a string variable's name starts "
                                       "with $")

    def _structure(self, file: str, n: int, words: list[str], stack: list[tuple[str, int]]
                   ) -> None:
        head, last = words[0].upper(), words[-1].upper()
        top = stack[-1][0] if stack else None
        if head == "IF":
            if last == "THEN":
                stack.append(("IF", n))
            elif "GOTO" not in (w.upper() for w in words):
                self._add(file, n, "structure", "IF without THEN")
        elif head == "ELSE":
            if top != "IF":
                self._add(file, n, "structure", "ELSE outside IF ... END")
            else:
                stack[-1] = ("ELSE", stack[-1][1])
        elif head == "WHILE":
            if last != "DO":
                self._add(file, n, "structure", "WHILE without DO")
            stack.append(("WHILE", n))
        elif head == "DO" and len(words) == 1:
            stack.append(("DO", n))
        elif head == "UNTIL":
            if top != "DO":
                self._add(file, n, "structure", "UNTIL without DO")
            else:
                stack.pop()
        elif head == "FOR":
            stack.append(("FOR", n))
        elif head == "CASE":
            if last != "OF":
                self._add(file, n, "structure", "CASE without OF")
            stack.append(("CASE", n))
        elif head in ("VALUE", "ANY"):
            if top != "CASE":
                self._add(file, n, "structure", f"{head} outside CASE ... END")
        elif head == "END" and len(words) == 1:
            if top is None:
                self._add(file, n, "structure", "END without IF, WHILE, FOR or CASE")
            elif top == "DO":
                self._add(file, n, "structure", f"END closes the DO of line {stack[-1][1]} "
                                                "(DO ends with UNTIL)")
                stack.pop()
            else:
                stack.pop()

    # ------------------------------------------------------------------ many files
    def finish(self, whole: bool = True) -> list[Finding]:
        """Cross-program rules; every finding, sorted. ``whole``: the files are the whole
        program set (calls to programs no file defines are judged)."""
        traps = {c.name.lower() for c in self.called if c.kind == "REACTE"}
        for call in self.called:
            key = call.name.lower()
            if key not in self.defined:
                if whole:
                    self._add(call.file, call.line, "undefined",
                              f"{call.kind} names program {call.name}, which no file defines")
            elif call.args is not None and call.args != self.params[key]:
                self._add(call.file, call.line, "arguments",
                          f"{call.kind} {call.name} with {call.args} argument(s); "
                          f"{call.name} takes {self.params[key]}")
        for name, file, n in self.returne:
            if name.lower() not in traps:
                self._add(file, n, "trap", f"RETURNE in {name}, which no REACTE names: "
                                           "RETURNE returns from an error trap only")
        for file, n, message in ForwardChecker(self.flow).findings():
            self._add(file, n, "forward-processing", message)
        for file, n, message in unassigned(self.flow, globals_too=whole):
            self._add(file, n, "unassigned", message)
        self.called.clear()
        self.returne.clear()
        return sorted(set(self.findings), key=lambda f: (f.file, f.line, f.rule, f.message))


def check_text(text: str, file: str = "<text>", max_line: int = MAX_LINE) -> list[Finding]:
    """Findings in one source (calls to programs it does not define are not judged)."""
    checker = Checker(max_line=max_line)
    checker.check_text(text, file)
    return checker.finish(whole=False)


def check_dir(directory: Path | str = VPLUS_DIR, max_line: int = MAX_LINE) -> list[Finding]:
    """Findings in every ``*.v2`` of ``directory`` (one program set, as LOAD sees it)."""
    directory = Path(directory)
    files = sorted(directory.glob("*.v2"))
    if not files:
        return [Finding(str(directory), 0, "missing", "no *.v2 programs")]
    checker = Checker(max_line=max_line)
    for path in files:
        try:
            text = path.read_bytes().decode("utf-8", errors="replace")
        except OSError as e:
            checker._add(str(path), 0, "missing", f"cannot read: {e.strerror}")
            continue
        checker.check_text(text, _display(path))
    return checker.finish()


def _count_args(code: str, open_at: int) -> int:
    """Arguments between the parenthesis at ``open_at`` and its match (blank ones count:
    ``a, , b`` is three, as V+ reads it, User's Guide p. 45)."""
    depth, count, empty = 0, 1, True
    for c in code[open_at:]:
        if c in "([":
            depth += 1
            if depth == 1:
                continue
        elif c in ")]":
            depth -= 1
            if depth == 0:
                break
        elif c == "," and depth == 1:
            count += 1
            empty = False
            continue
        if depth >= 1 and not c.isspace():
            empty = False
    return 0 if empty else count


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


class VplusRefused(ConfigError):
    """V+ would refuse to load a program: ``FILE:LINE: rule: what`` (the first finding)."""


def require_loadable(directory: Path | str = VPLUS_DIR, max_line: int = MAX_LINE) -> None:
    """Raise ``VplusRefused`` naming the first finding (and how many there are)."""
    findings = check_dir(directory, max_line)
    if findings:
        first = findings[0]
        more = f" (and {len(findings) - 1} more)" if len(findings) > 1 else ""
        raise VplusRefused(f"{first.rule}: {first.message}: V+ would not load this{more}",
                           file=first.file, line=first.line or None)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m feeder_bt.emulators.vplus.check",
                                description="check V+ programs the way V+ LOAD would")
    p.add_argument("directory", nargs="?", default=str(VPLUS_DIR))
    p.add_argument("--max-line", type=int, default=MAX_LINE, metavar="N",
                   help=f"longest program line accepted (default {MAX_LINE}; not confirmed)")
    args = p.parse_args(argv)
    findings = check_dir(args.directory, args.max_line)
    for f in findings:
        print(f, file=sys.stderr)
    if not findings:
        print(f"ok: {args.directory}")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
