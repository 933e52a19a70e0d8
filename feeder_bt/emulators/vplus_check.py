"""A checker for the V+ programs of ``vplus/``: it refuses what a V+ controller's LOAD refuses.

The Adept emulator runs only programs this checker accepts (``AdeptEmulator.start``), and the
tests check every shipped program with it, so a program that would not load on the robot
controller cannot pass as working against the emulator.

Rules, each with its source (docs/real-cell.md, "The Adept controller (V+)"):

- ``reserved``: a V+ keyword or function name used as a variable, parameter or program name
  (User's Guide v17 p. 99, "Variable Name Requirements"; list in ``vplus_words.py``).
- ``long-name``: a name over 15 characters. V+ keeps only the first 15 and silently truncates
  the rest (User's Guide p. 99), so two long names can become one variable; refused.
- ``bad-name``: a name that does not start with a letter or holds other characters than
  letters, digits, ``.`` and ``_`` (User's Guide p. 99).
- ``non-ascii``: any character outside 7-bit ASCII (V+ text is ASCII).
- ``outside``: anything but blank lines outside ``.PROGRAM`` ... ``.END`` (a program starts with
  its ``.PROGRAM`` step and ends with ``.END``: User's Guide p. 36).
- ``long-line``: a line longer than ``max_line`` characters. NOT CONFIRMED: the V+ limit on a
  program step's length was not found; ``max_line`` is a setting, 80 by default.
- ``structure``: unbalanced control structures: IF ... THEN / ELSE / END, WHILE ... DO / END,
  DO / UNTIL, FOR / END, CASE ... OF / VALUE / ANY / END (the editor marks such a program
  not executable: User's Guide p. 36).
- ``declaration``: AUTO, LOCAL or GLOBAL after an executable step (User's Guide p. 36).
- ``undefined``: CALL / EXECUTE / REACTE of a program no file defines; ``duplicate``: a
  program defined twice.

``python -m feeder_bt.emulators.vplus_check [DIR] [--max-line N]`` prints one line per finding,
``FILE:LINE: rule: what``, and exits 1 if there is any.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError
from .vplus_words import reserved

VPLUS_DIR = Path(__file__).resolve().parents[2] / "vplus"
MAX_NAME = 15                 # V+ significant characters in a name (User's Guide p. 99)
MAX_LINE = 80                 # NOT CONFIRMED: a setting (module docstring)

_NAME = re.compile(r"(?<![\w./])[$#%]?[A-Za-z_][\w.]*")
_VALID = re.compile(r"^[$#%]?[A-Za-z][A-Za-z0-9._]*$")
_PROGRAM = re.compile(r"^\.PROGRAM\s+(\S+?)\s*\((.*)\)\s*$", re.IGNORECASE)
_ASSIGN = re.compile(r"^\s*(?:SET\s+)?([$#%]?[A-Za-z_][\w.]*)\s*(?:\[[^\]]*\])?\s*=(?!=)",
                     re.IGNORECASE)
_CALLED = re.compile(r"\b(?:CALL|EXECUTE(?:\s+\d+)?|REACTE)\s+([A-Za-z_][\w.]*)", re.IGNORECASE)
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
    executable: bool = False


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
        self.called: list[tuple[str, str, int]] = []

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
        for param in filter(None, (p.strip() for p in m.group(2).split(","))):
            self._name(file, n, param.split("[")[0].strip(), "parameter")
        return _Program(name, n)

    def _statement(self, file: str, n: int, code: str, program: _Program,
                   stack: list[tuple[str, int]]) -> None:
        words = code.split()
        head = words[0].upper()
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
        if target and head not in ("FOR", "IF", "WHILE", "UNTIL"):
            self._name(file, n, target.group(1), "variable")
        seen = {target.group(1)} if target else set()
        for tok in _NAME.findall(code):
            if tok not in seen and _is_user_name(tok):
                seen.add(tok)
                self._name(file, n, tok, "name")
        for rx in (_CALLED, _WINDOW_PROG):
            self.called.extend((m.group(1), file, n) for m in rx.finditer(code))
        if not (target and head not in ("FOR", "IF", "WHILE", "UNTIL")):
            self._structure(file, n, words, stack)     # an assignment opens nothing

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
    def finish(self) -> list[Finding]:
        """Cross-file rules (programs called but never defined); every finding, sorted."""
        for name, file, n in self.called:
            if name.lower() not in self.defined:
                self._add(file, n, "undefined", f"program {name} is not defined in any file")
        self.called.clear()
        return sorted(set(self.findings), key=lambda f: (f.file, f.line, f.rule, f.message))


def check_text(text: str, file: str = "<text>", max_line: int = MAX_LINE) -> list[Finding]:
    """Findings in one source (calls to programs it does not define are not judged)."""
    checker = Checker(max_line=max_line)
    checker.check_text(text, file)
    checker.called.clear()
    return checker.finish()


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
    p = argparse.ArgumentParser(prog="python -m feeder_bt.emulators.vplus_check",
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
