"""An interpreter for the subset of Galil's DMC language that ``galil_programs/`` uses.

The Galil emulator runs the programs the driver downloads with this interpreter, so the
programs shipped in ``galil_programs/`` are tested by running them, not by a stand-in.

Subset: labels (``#NAME``), ``JP``/``JS`` with optional conditions, ``EN`` (end a thread or
return from ``JS``), ``IF``/``ELSE``/``ENDIF`` (nestable), variables and assignments,
arithmetic and comparison expressions, operands with their axis named (``_TPB``,
``_BGB``, ``_TI0``, ``_ALB``, ``_RLB`` ... answered by the host),
functions (``@IN[n]``, ``@OUT[n]`` from the host; ``@ABS``, ``@INT``, ``@FRAC``, ``@RND``,
``@COM``, ``@SQR`` here), ``MG`` with strings, expressions and ``{Fm.n}``/``{Zm.n}``/
``{$m.n}``/``{N}``/``{^n}`` formatting, ``WT`` (milliseconds of wall time), automatic
subroutines (``#POSERR``, ``#LIMSWI``, ``#AMPERR`` entered on the host's event, ``#CMDERR``
on a program error, each ended by ``RE``/``EN``), ``NO`` and
``'`` comments. Anything else in a program is handed to the host as a command (``SB 1``,
``JG ,100``, ``BGB``...).

Not in the subset, refused at download as the strictest card would: the variable axis
designators ``~a``-``~h`` (``_TP~a``, ``ST ~b``). Galil's newer command references list
them (DMC-30010, DMC-40x0), but no source confirms them on the DMC-21x3 the programs are
written for (docs/real-cell.md, "Galil facts"), so the programs name each axis.

Galil evaluates arithmetic strictly left to right, with no operator precedence:
``1+2*3`` is 9. Parentheses group; a comparison splits a condition into two such
expressions (``A+1>B*2`` is ``(A+1)>(B*2)``), and conditions combine with ``&``/``|``
only in parentheses: ``(A>1)&(B<2)``.

Each program thread (``XQ #LABEL,n``) runs on its own Python thread. An error stops that
thread and is reported to the host with a Galil error code, as ``TC1`` would give it.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass, field

from feeder_bt.emulators.galil.dmc_expr import (
    _FMT_RE,
    _MATH,
    DmcError,
    DmcHost,
    Tok,
    _Parser,
    format_number,
    split_args,
    tokenize,
)
from feeder_bt.hal.galil.protocol import (
    MAX_LABELS,
    MAX_LINE_CHARS,
    MAX_PROGRAM_LINES,
    MAX_VARIABLE_CHARS,
    THREADS,
    label_problem,
)

AXES = "ABCDEFGH"
MAX_STACK = 16
SLICE = 200            # statements a thread runs before yielding for a moment

# Two-letter commands the interpreter hands to the host rather than reading ``XYB=...`` as
# an assignment to a variable ``XYB``.
HOST_COMMANDS = frozenset(
    "AB AC AL BG CB CF CN CW DC DL EO ER HX IH JG MO OB OE PR RL SB SH SP ST TC TH TI TP TV WH "
    "XQ".split())

#: Automatic subroutines (Galil command reference, "#POSERR", "#LIMSWI", "#AMPERR", "#CMDERR"):
#: the card jumps to them on the event if the downloaded program has the label.
AUTO_LABELS = ("#POSERR", "#LIMSWI", "#AMPERR", "#CMDERR")


# ---------------------------------------------------------------------------- program


@dataclass
class Stmt:
    kind: str               # label if else endif jp js en wt mg assign axis nop cmd
    text: str
    line: int               # 1-based program line
    target: str = ""        # label of jp/js; variable of assign; axis var letter
    expr: str = ""          # condition / wait / value / MG arguments
    toks: list[Tok] | None = None
    jump: int = -1          # if: index of else+1 or endif+1; else: endif+1


def split_statements(line: str) -> list[str]:
    """A program line's statements (``;``-separated, outside quotes)."""
    out, cur, quoted = [], [], False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        if ch == ";" and not quoted:
            out.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur).strip())
    return [s for s in out if s]


def is_axis_command(word: str) -> bool:
    """``SPB``, ``ACAB``, ``JG``: a host command in explicit-axis form, not a variable."""
    return word[:2] in HOST_COMMANDS and all(c in AXES for c in word[2:])


_ASSIGN_RE = re.compile(r"^([A-Za-z][A-Za-z0-9]*)\s*=\s*(.*)$")
_AXIS_DESIGNATOR_RE = re.compile(r'~[a-h]?(?=(?:[^"]*"[^"]*")*[^"]*$)')
_JUMP_RE = re.compile(r"^(JP|JS)\s*(#[A-Za-z0-9]+)\s*(?:,(.*))?$")


def compile_statement(text: str, line: int) -> Stmt:
    """One statement -> ``Stmt`` (expressions tokenised now, evaluated when run)."""
    s = text.strip()
    head = s[:2]
    if not s.startswith("'") and _AXIS_DESIGNATOR_RE.search(s):
        raise DmcError(1, f"{s!r}: a variable axis designator (~a-~h) is not confirmed on "
                          "the DMC-21x3: name the axis")
    if s.startswith("'") or (head == "NO" and (len(s) == 2 or not s[2].isalnum())):
        return Stmt("nop", s, line)
    if s == "ELSE":
        return Stmt("else", s, line)
    if s == "ENDIF":
        return Stmt("endif", s, line)
    if head == "IF" and len(s) > 2 and (s[2] in " (" or not s[2].isalnum()):
        return Stmt("if", s, line, expr=s[2:].strip(), toks=tokenize(s[2:]))
    if head in ("JP", "JS"):
        m = _JUMP_RE.match(s)
        if not m:
            raise DmcError(11, f"bad jump {s!r}")
        cond = (m.group(3) or "").strip()
        return Stmt(head.lower(), s, line, target=m.group(2).upper(), expr=cond,
                    toks=tokenize(cond) if cond else None)
    if s == "EN" or (head == "EN" and s[2:3] in (" ", ",")):
        return Stmt("en", s, line)
    if head in ("RE", "RI") and (len(s) == 2 or s[2:3] in " 01"):
        return Stmt("re", s, line)             # return from an automatic subroutine
    if head == "WT" and not s[2:3].isalpha():
        return Stmt("wt", s, line, expr=s[2:].strip(), toks=tokenize(s[2:]))
    if head == "MG" and not s[2:3].isalnum():
        return Stmt("mg", s, line, expr=s[2:].strip())
    m = _ASSIGN_RE.match(s)
    if m and not is_axis_command(m.group(1)):
        name = m.group(1)
        if len(name) > MAX_VARIABLE_CHARS:
            raise DmcError(9, f"variable name {name!r} is longer than {MAX_VARIABLE_CHARS}")
        return Stmt("assign", s, line, target=name, expr=m.group(2).strip(),
                    toks=tokenize(m.group(2)))
    return Stmt("cmd", s, line)


@dataclass
class Program:
    """A downloaded program: its lines, compiled statements and labels."""

    lines: list[str]
    stmts: list[Stmt] = field(default_factory=list)
    labels: dict[str, int] = field(default_factory=dict)

    @classmethod
    def parse(cls, text: str | list[str]) -> Program:
        """Compile program text; raises ``DmcError`` (60 too long, 61 bad label, 63 IF
        without ENDIF, ...) with the program line in ``detail``."""
        lines = text.splitlines() if isinstance(text, str) else list(text)
        if len(lines) > MAX_PROGRAM_LINES:
            raise DmcError(60, f"{len(lines)} lines; at most {MAX_PROGRAM_LINES}")
        prog = cls(lines)
        open_ifs: list[int] = []
        for n, raw in enumerate(lines, start=1):
            if len(raw) > MAX_LINE_CHARS:
                raise DmcError(60, f"line {n} is {len(raw)} characters; at most {MAX_LINE_CHARS}")
            parts = split_statements(raw)
            for k, part in enumerate(parts):
                if part.startswith("#"):
                    if k:
                        raise DmcError(61, f"line {n}: a label must start its line")
                    problem = label_problem(part)
                    if problem:
                        raise DmcError(61, f"line {n}: {problem}")
                    name = part.upper()
                    if name in prog.labels:
                        raise DmcError(61, f"line {n}: duplicate label {name}")
                    if len(prog.labels) >= MAX_LABELS:
                        raise DmcError(60, f"line {n}: more than {MAX_LABELS} labels")
                    prog.labels[name] = len(prog.stmts)
                    prog.stmts.append(Stmt("label", part, n))
                    continue
                try:
                    st = compile_statement(part, n)
                except DmcError as e:
                    raise DmcError(e.code, f"line {n}: {e.detail or e.text}") from None
                idx = len(prog.stmts)
                prog.stmts.append(st)
                if st.kind == "if":
                    open_ifs.append(idx)
                elif st.kind == "else":
                    if not open_ifs or prog.stmts[open_ifs[-1]].jump != -1:
                        raise DmcError(63, f"line {n}: ELSE without IF")
                    prog.stmts[open_ifs[-1]].jump = idx + 1
                    open_ifs.append(idx)            # the ELSE waits for its ENDIF too
                elif st.kind == "endif":
                    if not open_ifs:
                        raise DmcError(63, f"line {n}: ENDIF without IF")
                    top = open_ifs.pop()
                    if prog.stmts[top].kind == "else":
                        prog.stmts[top].jump = idx + 1
                        top = open_ifs.pop()
                    if prog.stmts[top].jump == -1:
                        prog.stmts[top].jump = idx + 1
        if open_ifs:
            raise DmcError(63, f"line {prog.stmts[open_ifs[-1]].line}: IF without ENDIF")
        for st in prog.stmts:
            if st.kind in ("jp", "js") and st.target not in prog.labels:
                raise DmcError(10, f"line {st.line}: undefined label {st.target}")
        return prog


# ---------------------------------------------------------------------------- interpreter


class _Env:
    """What an expression can read: variables, operands, functions."""

    def __init__(self, interp: DmcInterpreter) -> None:
        self.interp = interp

    def variable(self, name: str) -> float:
        with self.interp.lock:
            if name not in self.interp.variables:
                raise DmcError(1, f"undefined variable {name}")
            return self.interp.variables[name]

    def operand(self, text: str) -> float:
        name, suffix = text[1:3], text[3:]
        return float(self.interp.host.operand(name, suffix))

    def function(self, name: str, arg: float) -> float:
        fn = _MATH.get(name)
        if fn is not None:
            return float(fn(arg))
        return float(self.interp.host.function(name, arg))


@dataclass
class _Thread:
    number: int
    stop: threading.Event
    thread: threading.Thread | None = None
    line: int = 0
    pending: list[str] = field(default_factory=list)    # automatic subroutines to enter
    in_cmderr: bool = False


class DmcInterpreter:
    """Program memory, variables and up to ``THREADS`` running program threads."""

    def __init__(self, host: DmcHost, threads: int = THREADS) -> None:
        self.host = host
        self.max_threads = threads
        self.program: Program | None = None
        self.variables: dict[str, float] = {}
        self.lock = threading.RLock()
        self._threads: dict[int, _Thread] = {}
        self._env = _Env(self)
        self.error_line = 0            # _ED: program line of the last error a #CMDERR caught
        self.error_thread = 0          # _ED1: its thread

    # ------------------------------------------------------------------ program memory
    def load(self, program: Program) -> None:
        """``DL``: replace program memory (refused while a thread runs, as the card does)."""
        if self.running():
            raise DmcError(17, "DL while a program runs")
        self.program = program

    # ------------------------------------------------------------------ expressions
    def evaluate(self, expr: str | list[Tok]) -> float:
        """Value of an expression or condition (left to right, no precedence)."""
        toks = tokenize(expr) if isinstance(expr, str) else expr
        if not toks:
            raise DmcError(1, "empty expression")
        p = _Parser(toks, self._env)
        value = p.condition()
        if p.peek() is not None:
            raise DmcError(1, f"unexpected {p.peek().text!r}")   # type: ignore[union-attr]
        return value

    def assign(self, name: str, expr: str | list[Tok]) -> None:
        if len(name) > MAX_VARIABLE_CHARS or not name[:1].isalpha() or not name.isalnum():
            raise DmcError(9, f"bad variable name {name!r}")
        value = self.evaluate(expr)
        with self.lock:
            self.variables[name] = value

    def message(self, args: str) -> str:
        """The text ``MG args`` prints, with CR/LF unless ``{N}``."""
        out: list[str] = []
        newline = True
        if not args.strip():
            return "\r\n"
        for arg in split_args(args):
            kind, m, n = "", 10, 4
            for spec in _FMT_RE.findall(arg):
                spec = spec.strip()
                if spec.upper() == "N":
                    newline = False
                elif spec.startswith("^"):
                    try:
                        out.append(chr(int(spec[1:]) & 0xFF))
                    except ValueError:
                        raise DmcError(1, f"bad {{{spec}}}") from None
                elif spec[:1].upper() in ("F", "Z", "$"):
                    fm = re.match(r"^([FZ$])(\d+)(?:\.(\d+))?$", spec, re.I)
                    if not fm:
                        raise DmcError(1, f"bad format {{{spec}}}")
                    kind, m, n = fm.group(1).upper(), int(fm.group(2)), int(fm.group(3) or 0)
                else:
                    raise DmcError(1, f"bad format {{{spec}}}")
            body = _FMT_RE.sub("", arg).strip()
            if not body:
                continue
            if body.startswith('"'):
                if len(body) < 2 or not body.endswith('"') or body.count('"') != 2:
                    raise DmcError(52, "missing quote")
                out.append(body[1:-1])
            else:
                out.append(format_number(self.evaluate(body), kind, m, n))
        return "".join(out) + ("\r\n" if newline else "")

    # ------------------------------------------------------------------ threads
    def running(self) -> list[int]:
        with self.lock:
            return sorted(n for n, t in self._threads.items()
                          if t.thread is not None and t.thread.is_alive())

    def thread_line(self, thread: int) -> int:
        """``_XQn``: the program line thread ``n`` is at, or -1 when it does not run."""
        with self.lock:
            t = self._threads.get(thread)
            if t is None or t.thread is None or not t.thread.is_alive():
                return -1
            return t.line

    def interrupt(self, label: str, thread: int = 0) -> bool:
        """An automatic subroutine: enter ``label`` on ``thread`` (started if it does not
        run), as the card does on an event. False when the program has no such label."""
        prog = self.program
        if prog is None or label.upper() not in prog.labels:
            return False
        with self.lock:
            t = self._threads.get(thread)
            if t is not None and t.thread is not None and t.thread.is_alive():
                if label.upper() not in t.pending:
                    t.pending.append(label.upper())
                return True
        try:
            self.execute(label, thread)
        except DmcError:
            return False
        return True

    def execute(self, label: str, thread: int = 0) -> None:
        """``XQ #LABEL,n``: start program thread ``n`` at ``label``."""
        if not 0 <= thread < self.max_threads:
            raise DmcError(6, f"thread {thread}")
        prog = self.program
        if prog is None:
            raise DmcError(10, "no program downloaded")
        start = prog.labels.get(label.upper())
        if start is None:
            raise DmcError(10, f"undefined label {label}")
        with self.lock:
            if thread in self.running():
                raise DmcError(19, f"thread {thread} is running")
            t = _Thread(thread, threading.Event())
            t.thread = threading.Thread(target=self._run, args=(prog, start, t),
                                        name=f"dmc-thread-{thread}", daemon=True)
            self._threads[thread] = t
            t.thread.start()

    def halt(self, thread: int | None = None, wait: float = 2.0) -> None:
        """``HX`` (all threads) or ``HXn``; waits for them to stop."""
        with self.lock:
            targets = [t for n, t in self._threads.items() if thread is None or n == thread]
        for t in targets:
            t.stop.set()
        for t in targets:
            if t.thread is not None and t.thread is not threading.current_thread():
                t.thread.join(wait)

    def _run(self, prog: Program, pc: int, t: _Thread) -> None:
        stack: list[int] = []
        count = 0
        while not t.stop.is_set():
            try:
                if t.pending:
                    with self.lock:
                        label = t.pending.pop(0)
                    if len(stack) >= MAX_STACK:
                        raise DmcError(12)
                    stack.append(pc)
                    pc = prog.labels[label]
                if pc >= len(prog.stmts):
                    return                           # ran off the end: the thread ends
                st = prog.stmts[pc]
                t.line = st.line
                pc, wait = self._step(prog, st, pc + 1, stack, t)
                if pc < 0:
                    return
                if wait is not None:
                    t.stop.wait(wait)
                    count = 0
                    continue
                count += 1
                if count >= SLICE:                  # a loop without WT must not hog the CPU
                    count = 0
                    t.stop.wait(0.0005)
            except Exception as e:                  # noqa: BLE001 - a fault stops the thread
                err = e if isinstance(e, DmcError) else DmcError(1, f"{type(e).__name__}: {e}")
                text = prog.lines[t.line - 1] if 0 < t.line <= len(prog.lines) else ""
                handler = prog.labels.get("#CMDERR")
                if handler is not None and not t.in_cmderr:
                    with self.lock:
                        self.error_line, self.error_thread = t.line, t.number
                    self.host.thread_error(t.number, err, t.line, text, trapped=True)
                    t.in_cmderr = True
                    stack.clear()
                    pc = handler
                    continue
                self.host.thread_error(t.number, err, t.line, text)
                return

    def _step(self, prog: Program, st: Stmt, pc: int, stack: list[int], t: _Thread
              ) -> tuple[int, float | None]:
        """Run one statement; returns the next pc (-1: the thread ends) and a wait (s)."""
        kind = st.kind
        if kind in ("label", "nop", "endif"):
            pass
        elif kind == "if":
            if not self.evaluate(st.toks or []):
                pc = st.jump
        elif kind == "else":
            pc = st.jump
        elif kind in ("jp", "js"):
            if st.toks is None or self.evaluate(st.toks):
                if kind == "js":
                    if len(stack) >= MAX_STACK:
                        raise DmcError(12)
                    stack.append(pc)
                pc = prog.labels[st.target]
        elif kind in ("en", "re"):
            if not stack:
                return -1, None
            pc = stack.pop()
        elif kind == "wt":
            ms = self.evaluate(st.toks or [])
            if ms < 0:
                raise DmcError(6, "WT < 0")
            return pc, ms / 1000.0
        elif kind == "mg":
            self.host.output(self.message(st.expr))
        elif kind == "assign":
            self.assign(st.target, st.toks or [])
        else:
            self.host.command(st.text, t.number)
        return pc, None


__all__ = ["DmcError", "DmcHost", "DmcInterpreter", "Program", "format_number", "tokenize"]
