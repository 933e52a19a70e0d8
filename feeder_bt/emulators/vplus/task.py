"""V+ program tasks: memory, CALL, control flow and error traps.

V+ memory is flat: a variable not declared ``AUTO`` is global, seen by every program on
every task (thesis 7.3.2; V+ Language User's Guide, "Variable Classes"). ``AUTO``
variables and parameters belong to one call; a parameter is the caller's variable itself
when the caller passes a variable or an array element (V+ passes them by reference),
else a copy of the value (User's Guide, "Argument Passing").

Errors (User's Guide v17 p. 47, "Error Trapping"): an error in a step stops the task,
unless ``REACTE prog`` armed a trap; V+ then calls ``prog`` as a subroutine. ``RETURNE``
ends it and the task goes on after the failed step; a plain ``RETURN`` from the trap
runs the failed step again (V+ Language Reference Guide, RETURNE: NOT CONFIRMED through
the search tool). The trap is disarmed while it runs and after (the programs re-arm it:
NOT CONFIRMED whether V+ keeps it armed). An error the arm reports while the task waits
or runs on (a servo error, a tracked part out of reach) comes in at the next step
boundary and, trapped, the task goes on at that step.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

from feeder_bt.emulators.vplus.parse import truth
from feeder_bt.emulators.vplus.program import Instr, Program

if TYPE_CHECKING:
    from feeder_bt.emulators.vplus.runtime import Runtime


class VError(Exception):
    """A V+ error in a program step: ``code`` is the negative V+ error number."""

    def __init__(self, code: int, what: str = "") -> None:
        super().__init__(f"{code} {what}".strip())
        self.code = code


class Killed(Exception):
    """The controller is shutting down: every task ends."""


class Cell:
    __slots__ = ("v",)

    def __init__(self, v: Any = None) -> None:
        self.v = v


class Array:
    __slots__ = ("items", "default")

    def __init__(self, default: Any) -> None:
        self.items: dict[tuple[int, ...], Any] = {}
        self.default = default


class ElemCell:
    """A reference to one array element (passed to CALL)."""

    __slots__ = ("arr", "key")

    def __init__(self, arr: Array, key: tuple[int, ...]) -> None:
        self.arr, self.key = arr, key

    @property
    def v(self) -> Any:
        return self.arr.items.get(self.key, self.arr.default)

    @v.setter
    def v(self, value: Any) -> None:
        self.arr.items[self.key] = value


def default_of(name: str) -> Any:
    if name.startswith("$"):
        return ""
    return 0.0


class Frame:
    """One CALL: its program, its AUTO variables and parameters, FOR and CASE state."""

    def __init__(self, prog: Program) -> None:
        self.prog = prog
        self.vars: dict[str, Any] = {}
        self.state: dict[int, Any] = {}


class Task:
    """A V+ task: runs a program on its own Python thread (EXECUTE n prog)."""

    def __init__(self, rt: Runtime, number: int) -> None:
        self.rt, self.number = rt, number
        self.trap: str | None = None            # REACTE program
        self.last_error = 0
        self.pending: list[Any] = []            # errors/reactions posted by the arm
        self.frame: Frame | None = None
        self.thread: threading.Thread | None = None
        self.running = False
        self.stopped_by: str = ""               # why the task ended (a V+ error)

    # ------------------------------------------------------------ life
    def start(self, name: str, args: list[Any]) -> None:
        self.thread = threading.Thread(target=self._main, args=(name, args),
                                       name=f"vplus-task{self.number}", daemon=True)
        self.running = True
        self.thread.start()

    def _main(self, name: str, args: list[Any]) -> None:
        try:
            self.call(name, [Cell(a) for a in args])
        except Killed:
            pass
        except VError as e:
            self.stopped_by = f"task {self.number} stopped: {e}"
            self.rt.log(self.stopped_by)
        finally:
            self.running = False

    def post(self, item: Any) -> None:
        """An asynchronous error (VError) or reaction (program name) for this task."""
        self.pending.append(item)
        self.rt.wake()

    # ------------------------------------------------------------ calls
    def call(self, name: str, cells: list[Any]) -> str:
        """Run a program; returns how it ended ("return" or "returne")."""
        prog = self.rt.programs.get(name)
        if prog is None:
            raise VError(-411, f"program {name} not found")
        frame = Frame(prog)
        for pname, cell in zip(prog.params, cells, strict=False):
            frame.vars[pname] = cell
        for pname in prog.params[len(cells):]:
            frame.vars[pname] = Cell(default_of(pname))
        outer, self.frame = self.frame, frame
        try:
            return self._run(frame)
        finally:
            self.frame = outer

    def _run(self, frame: Frame) -> str:
        code = frame.prog.code
        pc = 0
        while True:
            if self.pending or self.rt.killed:
                self._service()
            ins = code[pc]
            try:
                nxt = self._step(ins, pc, frame)
            except VError as e:
                how = self._trapped(e, ins)
                nxt = pc + 1 if how == "returne" else pc
            if nxt is None or isinstance(nxt, str):
                return nxt or "return"
            pc = nxt

    def _service(self) -> None:
        if self.rt.killed:
            raise Killed()
        while self.pending:
            item = self.pending.pop(0)
            if isinstance(item, VError):
                self._trapped(item, None)
            else:
                self.call(item, [])

    def _trapped(self, e: VError, ins: Instr | None) -> str:
        self.last_error = e.code
        where = f"{self.frame.prog.file}:{ins.line}" if (self.frame and ins) else "async"
        if self.trap is None:
            raise VError(e.code, f"{e} at {where}")
        trap, self.trap = self.trap, None
        return self.call(trap, [])

    # ------------------------------------------------------------ steps
    def _step(self, ins: Instr, pc: int, frame: Frame) -> int | str | None:
        k = ins.kind
        if k == "stmt":
            self.rt.statement(self, ins.a, ins.b)
            return pc + 1
        if k == "assign":
            ins.a(self).v = ins.b(self)
            return pc + 1
        if k == "jf":
            return pc + 1 if truth(ins.a(self)) else ins.target
        if k == "jmp":
            return ins.target
        if k == "call":
            self.call(ins.a, [f(self) for f in ins.b])
            return pc + 1
        if k in ("return", "returne"):
            return k
        if k == "auto":
            for name, is_array in ins.a:
                frame.vars[name] = Array(default_of(name)) if is_array else Cell(default_of(name))
            return pc + 1
        if k == "case":
            frame.state[pc] = ins.a(self)
            return pc + 1
        if k == "value":
            v = frame.state[ins.a]
            if not ins.b or any(f(self) == v for f in ins.b):
                return pc + 1
            return ins.target
        if k == "for_init":
            stop, step = ins.c
            frame.state[pc] = (stop(self), step(self))
            self.ref(ins.a).v = ins.b(self)
            return pc + 1
        if k == "for_test":
            stop, step = frame.state[pc - 1]
            v = self.get(ins.a)
            done = v > stop if step >= 0 else v < stop
            return ins.target if done else pc + 1
        if k == "for_step":
            _, step = frame.state[ins.b]
            cell = self.ref(ins.a)
            cell.v = cell.v + step
            return ins.target
        if k == "decompose":
            arr = self._array(ins.a)
            first = int(ins.b(self))
            for i, value in enumerate(self.rt.decompose(ins.c(self))):
                arr.items[(first + i,)] = value
            return pc + 1
        raise VError(-401, f"cannot run {k}")

    # ------------------------------------------------------------ memory (parse.py's ctx)
    def _lookup(self, name: str) -> Any:
        if self.frame is not None and name in self.frame.vars:
            return self.frame.vars[name]
        return self.rt.globals.get(name)

    def get(self, name: str) -> Any:
        cell = self._lookup(name)
        if cell is None or isinstance(cell, Array) or cell.v is None:
            raise VError(-401, f"undefined value {name}")
        return cell.v

    def ref(self, name: str) -> Any:
        cell = self._lookup(name)
        if cell is None:
            cell = self.rt.globals[name] = Cell(None)
        return cell

    def _array(self, name: str) -> Array:
        arr = self._lookup(name)
        if not isinstance(arr, Array):
            arr = self.rt.globals[name] = Array(default_of(name))
        return arr

    def get_elem(self, name: str, key: tuple[int, ...]) -> Any:
        arr = self._lookup(name)
        if not isinstance(arr, Array) or key not in arr.items:
            raise VError(-401, f"undefined value {name}{list(key)}")
        return arr.items[key]

    def ref_elem(self, name: str, key: tuple[int, ...]) -> ElemCell:
        return ElemCell(self._array(name), key)

    @staticmethod
    def value_cell(v: Any) -> Cell:
        return Cell(v)

    def compose(self, a: Any, b: Any) -> Any:
        return self.rt.compose(a, b)

    def func(self, name: str, args: list[Any]) -> Any:
        return self.rt.func(self, name, args)
