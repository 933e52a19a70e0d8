"""Forward processing: the ``forward-processing`` rule of the V+ checker.

A V+ motion instruction only starts the motion; the program goes on while the arm moves
("forward processing": V+ Language User's Guide v12, chapter 8, "Motion Control
Instructions": ``MOVE part.1`` then ``SIGNAL 1`` turns the signal on "immediately after the
robot begins moving to part.1"; ``BREAK`` waits for the motion to end,
https://1library.net/article/motion-control-instructions-language-user-guide-version.ye06vg1q).
So a vacuum ``SIGNAL`` after a ``MOVES`` with no ``BREAK`` between fires while the arm is
still descending, and a ``BELT(...)`` or ``HERE`` read for the grip reads the belt or the arm
before it got there.

Definitions (``vplus_words.MOTION``): a *motion instruction* is ALIGN, AMOVE, APPRO,
APPROS, DELAY, DEPART, DEPARTS, DRIVE, MOVE, MOVEC, MOVEF, MOVES, MOVESF, MOVET, MOVEST or
READY. A statement that *must wait for the arm* is a ``SIGNAL`` (of an output: which
signal it is cannot be told statically, so every SIGNAL), a ``BELT(...)`` function read and
a ``HERE`` / ``#PHERE`` read. Such a statement is refused when, on some path through the
program, a motion instruction comes before it with no ``BREAK`` between.

A step whose comment says ``@nowait`` (with the reason) is meant to run while the arm
moves (reading the belt count now, not at the grip; letting go of a vacuum that gripped
nothing as the arm leaves) and is not refused: the marker makes the intent reviewable.

Paths follow the control structures: IF/ELSE and CASE branches start from the state before
the branch and are merged at END (a motion on either branch counts); a branch that ends in
RETURN, RETURNE, HALT, STOP or GOTO does not reach the END. A CALL takes the state its
program leaves (``motion.done``, which starts with BREAK, clears it), and a CALL made while
the arm moves is refused when the called program would itself signal or read before a
BREAK. A loop body that leaves the arm moving is walked a second time from its start (a
motion at the end of the body and a SIGNAL at its start). Not modelled: GOTO targets and
other tasks. Deliberately signalling at the start of a motion (V+'s own idiom) is not
possible with this rule: write BREAK, or move the SIGNAL before the motion.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from feeder_bt.emulators.vplus.words import MOTION

Pending = tuple[str, int, str] | None      # (file, line, instruction) of the motion in flight

_HEAD = re.compile(r"^[$#%]?[A-Za-z][\w.]*")
_CALL = re.compile(r"\bCALLS?\s+([A-Za-z][\w.]*)")
_BELT_READ = re.compile(r"\bBELT\s*\(")
_HERE_READ = re.compile(r"(?<![\w.$])(?:HERE|#PHERE)(?![\w.])")
_DEAD_ENDS = {"RETURN", "RETURNE", "HALT", "STOP", "GOTO"}
NOWAIT = "@nowait"      # in a step's comment: it is meant to run while the arm moves


@dataclass
class FlowProgram:
    """One program's steps as the checker saw them: (line, code without comment/label)."""
    name: str
    file: str
    steps: list[tuple[int, str]] = field(default_factory=list)
    params: list[str] = field(default_factory=list)
    nowait: set[int] = field(default_factory=set)   # lines marked ``@nowait``: meant to
                                                     # run while the arm moves


@dataclass
class _Frame:
    kind: str                    # IF, CASE, LOOP
    entry: Pending
    exits: list[Pending] = field(default_factory=list)
    dead: bool = False           # entered on a path that had already returned
    else_seen: bool = False      # IF: ELSE seen; CASE: a VALUE/ANY seen
    has_any: bool = False
    start: int = 0               # LOOP: index of its first step, for the way round
    again: bool = False          # LOOP: this is the walk round a second time


def waits_for_arm(code: str) -> str | None:
    """What in this step must wait for the arm (SIGNAL, BELT read, HERE read), or None."""
    head = _HEAD.match(code)
    if head and head.group() == "SIGNAL":
        return "SIGNAL"
    if _BELT_READ.search(code):
        return "the BELT read"
    if _HERE_READ.search(code):
        return "the HERE read"
    return None


class ForwardChecker:
    """Walk every program's paths; ``findings`` are (file, line, message)."""

    def __init__(self, programs: dict[str, FlowProgram]) -> None:
        self.programs = programs
        self._memo: dict[tuple[str, bool], tuple[Pending, list[tuple[str, int, str]]]] = {}
        self._busy: set[str] = set()

    def findings(self) -> list[tuple[str, int, str]]:
        out: list[tuple[str, int, str]] = []
        for key in self.programs:
            out.extend(self._walk(key, None)[1])
        return out

    # ------------------------------------------------------------------ one program
    def _summary(self, key: str, moving: bool) -> tuple[Pending, list[tuple[str, int, str]]]:
        """(state at exit, findings) of program ``key`` entered with the arm moving or not."""
        memo = (key, moving)
        if memo not in self._memo:
            if key in self._busy:                       # recursion: assume no effect
                return (None, [])
            entry: Pending = ("", 0, "a motion") if moving else None
            self._memo[memo] = self._walk(key, entry)
        return self._memo[memo]

    def _walk(self, key: str, entry: Pending) -> tuple[Pending, list[tuple[str, int, str]]]:
        prog = self.programs[key]
        self._busy.add(key)
        try:
            return self._steps(prog, entry)
        finally:
            self._busy.discard(key)

    def _steps(self, prog: FlowProgram, entry: Pending
               ) -> tuple[Pending, list[tuple[str, int, str]]]:
        state, dead = entry, False
        stack: list[_Frame] = []
        exits: list[Pending] = []
        found: list[tuple[str, int, str]] = []
        i = -1
        while i + 1 < len(prog.steps):
            i += 1
            line, code = prog.steps[i]
            words = code.split()
            head = words[0].upper() if words else ""
            last = words[-1].upper() if words else ""
            # ---- structure
            if head == "IF" and last == "THEN":
                stack.append(_Frame("IF", state, dead=dead))
                continue
            if head == "CASE" and last == "OF":
                stack.append(_Frame("CASE", state, dead=dead))
                continue
            if head in ("WHILE", "FOR") or (head == "DO" and len(words) == 1):
                stack.append(_Frame("LOOP", state, dead=dead, start=i + 1))
                continue
            if head == "ELSE" and stack and stack[-1].kind == "IF":
                frame = stack[-1]
                if not dead:
                    frame.exits.append(state)
                frame.else_seen, state, dead = True, frame.entry, frame.dead
                continue
            if head in ("VALUE", "ANY") and stack and stack[-1].kind == "CASE":
                frame = stack[-1]
                if frame.else_seen and not dead:
                    frame.exits.append(state)
                frame.else_seen, state, dead = True, frame.entry, frame.dead
                frame.has_any = frame.has_any or head == "ANY"
                continue
            if (head == "END" and len(words) == 1) or head == "UNTIL":
                if stack:
                    frame = stack.pop()
                    if frame.kind == "LOOP" and not (frame.again or frame.dead or dead) \
                            and state is not None and frame.entry is None:
                        # the way round: the body again, entered with the arm moving
                        stack.append(_Frame("LOOP", state, start=frame.start, again=True))
                        i = frame.start - 1
                        continue
                    state, dead = self._close(frame, state, dead)
                continue
            if dead:
                continue
            # ---- what this step needs and does
            need = None if line in prog.nowait else waits_for_arm(code)
            if need and state is not None:
                found.append((prog.file, line, self._message(need, state)))
            if head in MOTION:
                state = (prog.file, line, head)
            elif head == "BREAK":
                state = None
            elif head in _DEAD_ENDS:
                exits.append(state)
                dead = True
            call = _CALL.search(code)
            if call and call.group(1).lower() in self.programs:
                state = self._call(prog, line, call.group(1), state, found)
        if not dead:
            exits.append(state)
        return (next((s for s in exits if s is not None), None), found)

    @staticmethod
    def _close(frame: _Frame, state: Pending, dead: bool) -> tuple[Pending, bool]:
        if frame.dead:
            return state, True
        if frame.kind == "LOOP":
            return (frame.entry if dead else (state or frame.entry)), False
        branches = list(frame.exits)
        if not dead:
            branches.append(state)
        if (frame.kind == "IF" and not frame.else_seen) or \
                (frame.kind == "CASE" and not frame.has_any):
            branches.append(frame.entry)              # the path that took no branch
        if not branches:
            return None, True                          # every branch returned
        return next((s for s in branches if s is not None), None), False

    def _call(self, prog: FlowProgram, line: int, name: str, state: Pending,
              found: list[tuple[str, int, str]]) -> Pending:
        key = name.lower()
        if state is not None:
            exit_state, inner = self._summary(key, True)
            alone = {(f, n) for f, n, _ in self._summary(key, False)[1]}
            fresh = [(f, n, m) for f, n, m in inner if (f, n) not in alone]
            if fresh:
                f, n, _ = fresh[0]
                found.append((prog.file, line, f"CALL {name} while the arm may still move "
                              f"({self._where(state)}, no BREAK between): {name} must wait "
                              f"for the arm at {f}:{n}"))
            return exit_state if exit_state is None or exit_state[1] else state
        exit_state, _ = self._summary(key, False)
        return exit_state

    def _message(self, need: str, state: tuple[str, int, str]) -> str:
        return (f"{need} runs while the arm may still move ({self._where(state)}, no BREAK "
                f"between): V+ runs ahead of the arm (forward processing)")

    @staticmethod
    def _where(state: tuple[str, int, str]) -> str:
        file, line, word = state
        return f"{word} at line {line}" if line else "a motion before the CALL"
