"""V+ programs: ``.PROGRAM name(params)`` ... ``.END`` compiled into flat instruction lists.

Control structures (V+ Language Reference Guide: IF...ELSE...END, WHILE...DO...END,
FOR...TO...STEP...END, CASE...OF...VALUE...ANY...END) become conditional jumps, so a
task runs a program with a program counter and a CALL is one Python call. Every other
statement is kept as ``("stmt", KEYWORD, parsed arguments)`` for the runtime.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from feeder_bt.emulators.vplus.parse import (
    Parser,
    SyntaxErr,
    compile_expr,
    compile_ref,
    strip_comment,
    tokenize,
)

_PROGRAM = re.compile(r"^\s*\.PROGRAM\s+([\w.]+)\s*\((.*)\)\s*$", re.IGNORECASE)
_IO = {"attach", "fopen", "fcmnd", "fclose", "detach", "read", "write"}
_PLAIN = {"type", "signal", "speed", "break", "delay", "wait", "brake", "appro", "appros",
          "move", "moves", "depart", "departs"}


@dataclass
class Instr:
    kind: str
    line: int
    a: Any = None
    b: Any = None
    c: Any = None
    target: int = -1


@dataclass
class Program:
    name: str
    params: list[str]
    file: str
    code: list[Instr] = field(default_factory=list)
    verbs: set[str] = field(default_factory=set)     # "$verb == ..." strings (handled())


class LoadError(Exception):
    """``FILE:LINE: what`` of a program line this interpreter cannot run."""


def load_dir(directory: Path) -> dict[str, Program]:
    programs: dict[str, Program] = {}
    for path in sorted(Path(directory).glob("*.v2")):
        for prog in load_text(path.read_text(), path.name):
            programs[prog.name] = prog
    return programs


def load_text(text: str, file: str = "<text>") -> list[Program]:
    out: list[Program] = []
    prog: Program | None = None
    body: list[tuple[int, str]] = []
    for n, raw in enumerate(text.splitlines(), 1):
        code = strip_comment(raw).strip()
        if not code:
            continue
        m = _PROGRAM.match(code)
        if m:
            params = [p.strip().lower() for p in m.group(2).split(",") if p.strip()]
            prog, body = Program(m.group(1).lower(), params, file), []
        elif code.upper() == ".END":
            if prog is None:
                raise LoadError(f"{file}:{n}: .END without .PROGRAM")
            _compile(prog, body)
            out.append(prog)
            prog = None
        elif prog is not None:
            body.append((n, code))
        else:
            raise LoadError(f"{file}:{n}: code outside a program")
    return out


def _compile(prog: Program, body: list[tuple[int, str]]) -> None:
    code = prog.code
    stack: list[tuple[str, Any]] = []          # open structures
    for n, line in body:
        try:
            _statement(prog, code, stack, n, line)
        except SyntaxErr as e:
            raise LoadError(f"{prog.file}:{n}: {e}") from None
    if stack:
        raise LoadError(f"{prog.file}: {prog.name}: {stack[-1][0].upper()} without END")
    code.append(Instr("return", 0))


def _statement(prog: Program, code: list[Instr], stack: list, n: int, line: str) -> None:
    toks = tokenize(line)
    p = Parser(toks)
    head = toks[0][1] if toks[0][0] in ("name", "op") else ""
    if head == "if":
        p.take()
        cond = p.expr()
        p.take("then")
        _verbs(prog, cond)
        code.append(Instr("jf", n, compile_expr(cond)))
        stack.append(("if", [len(code) - 1]))
    elif head == "else":
        kind, jumps = stack[-1]
        code.append(Instr("jmp", n))
        code[jumps[0]].target = len(code)
        stack[-1] = ("else", [len(code) - 1])
    elif head == "while":
        p.take()
        cond = p.expr()
        p.take("do")
        top = len(code)
        code.append(Instr("jf", n, compile_expr(cond)))
        stack.append(("while", [top]))
    elif head == "for":
        p.take()
        var = p.take()[1]
        p.take("=")
        start = p.expr()
        p.take("to")
        stop = p.expr()
        step = ("num", 1.0)
        if p.at("step"):
            p.take()
            step = p.expr()
        code.append(Instr("for_init", n, var, compile_expr(start),
                          (compile_expr(stop), compile_expr(step))))
        top = len(code)
        code.append(Instr("for_test", n, var))
        stack.append(("for", [top]))
    elif head == "case":
        p.take()
        e = p.expr()
        p.take("of")
        code.append(Instr("case", n, compile_expr(e)))
        stack.append(("case", {"slot": len(code) - 1, "ends": [], "last": None}))
    elif head in ("value", "any"):
        state = stack[-1][1]
        if state["last"] is not None:          # the previous branch jumps to the END
            code.append(Instr("jmp", n))
            state["ends"].append(len(code) - 1)
            code[state["last"]].target = len(code)
        p.take()
        values = [] if head == "any" else [compile_expr(e) for e in p.expr_list()]
        if p.at(":"):
            p.take()
        code.append(Instr("value", n, state["slot"], values))
        state["last"] = len(code) - 1
    elif head == "end":
        kind, data = stack.pop()
        if kind in ("if", "else"):
            code[data[0]].target = len(code)
        elif kind == "while":
            code.append(Instr("jmp", n, target=data[0]))
            code[data[0]].target = len(code)
        elif kind == "for":
            code.append(Instr("for_step", n, code[data[0]].a, data[0] - 1, target=data[0]))
            code[data[0]].target = len(code)
        elif kind == "case":
            if data["last"] is not None:
                code[data["last"]].target = len(code)
            for j in data["ends"]:
                code[j].target = len(code)
    else:
        code.append(_simple(prog, p, head, n))


def _verbs(prog: Program, node: tuple) -> None:
    if node[0] == "bin" and node[1] == "==" and node[2] == ("var", "$verb") \
            and node[3][0] == "str":
        prog.verbs.add(node[3][1])


def _simple(prog: Program, p: Parser, head: str, n: int) -> Instr:
    nxt = p.peek(1)
    if head == "set" or (nxt is not None and nxt[1] in ("=", "[") and head not in
                         ("defbelt", "setbelt", "window", "decompose")):
        if head == "set":
            p.take()
        target = p.primary()
        p.take("=")
        return Instr("assign", n, compile_ref(target), compile_expr(p.expr()))
    p.take()
    if head == "auto":
        decl = []
        for node in p.expr_list():
            if node[0] == "idx":
                decl.append((node[1], True))
            else:
                decl.append((node[1], False))
        return Instr("auto", n, decl)
    if head == "call":
        name = p.take()[1]
        p.take("(")
        args = [compile_ref(e) for e in p.args(")")]
        return Instr("call", n, name, args)
    if head in ("return", "returne"):
        return Instr(head, n)
    if head == "decompose":
        target = p.primary()
        p.take("=")
        return Instr("decompose", n, target[1], compile_expr(target[2][0]),
                     compile_expr(p.expr()))
    if head == "execute":
        task = compile_expr(p.expr())
        name = p.take()[1]
        p.take("(")
        args = [compile_expr(e) for e in p.args(")")]
        return Instr("stmt", n, "execute", (task, name, args))
    if head in ("reacte", "enable", "disable"):
        return Instr("stmt", n, head, p.take()[1])
    if head in ("defbelt", "setbelt", "window"):
        belt = p.take()[1]
        p.take("=")
        nodes = p.expr_list()
        if head == "window":
            args = [compile_expr(nodes[0]), compile_expr(nodes[1]), nodes[2][1],
                    compile_expr(nodes[3]) if len(nodes) > 3 else None]
        else:
            args = [compile_expr(e) for e in nodes]
        return Instr("stmt", n, head, (belt, args))
    if head in _IO:
        p.take("(")
        nodes = p.args(")")
        if head == "read":                   # READ (lun, handle, mode) $var: outputs
            args = [compile_expr(nodes[0]), compile_ref(nodes[1]),
                    compile_expr(nodes[2]) if len(nodes) > 2 else None]
            return Instr("stmt", n, head, (args, compile_ref(p.expr())))
        args = [compile_expr(e) for e in nodes]
        rest = compile_expr(p.expr()) if not p.done() else None
        return Instr("stmt", n, head, (args, rest))
    if head in _PLAIN:
        args = [compile_expr(e) for e in p.expr_list()] if not p.done() else []
        always = False
        if args and head == "speed" and p.at("always"):
            p.take()
            always = True
        if not p.done():
            raise SyntaxErr(f"{head.upper()}: unexpected {p.peek()[1]!r}")  # type: ignore[index]
        return Instr("stmt", n, head, (args, always))
    raise SyntaxErr(f"statement {head.upper()!r} is not in the interpreted V+ subset")
