"""Variables read before anything assigns them: the ``unassigned`` rule of the V+ checker.

V+ creates a variable on its first assignment and stops a program that reads one with no
value (*Undefined value*; User's Guide v17 p. 99, "Dynamic Data Typing and Allocation": "The
first use of a variable determines its data type and allocates space"). Two cheap cases are
judged:

- an AUTO variable read, in the order of the program's steps, before any step that could
  give it a value;
- a global (neither AUTO, LOCAL nor a parameter) read somewhere, while no step of any
  program could give it a value.

A *read* is a name in the right-hand side of an assignment (or its index) or in the
condition of IF, WHILE, UNTIL, CASE or VALUE. Every other step that names a variable (CALL,
READ, DECOMPOSE, FOR, DEFBELT, PROMPT, ...) is counted as possibly assigning it, since many
instructions and every CALL can return values through their arguments. So a variable
read only after a branch that never ran still passes (the order of steps, not of paths, is
judged): this finds typos and forgotten initialisations, not every *Undefined value*.
"""

from __future__ import annotations

import re

from feeder_bt.emulators.vplus.flow import FlowProgram
from feeder_bt.emulators.vplus.words import reserved

_NAME = re.compile(r"(?<![\w./$#%])[$#%]?[a-z][\w.]*")
_ASSIGN = re.compile(r"^\s*(?:SET\s+)?([$#%]?[A-Za-z][\w.]*)\s*(\[[^\]]*\])?\s*=(?!=)")
_CONDITIONS = ("IF", "WHILE", "UNTIL", "CASE", "VALUE")
_DECLARE = ("AUTO", "LOCAL", "GLOBAL")


def _names(text: str) -> list[str]:
    """The user names in ``text`` (lower case by the V+ editor's format; keywords are
    capitals), without array indexes."""
    return _NAME.findall(text)


def unassigned(programs: dict[str, FlowProgram], globals_too: bool = True
               ) -> list[tuple[str, int, str]]:
    """(file, line, message) for every read no step could have given a value;
    ``globals_too``: the programs are the whole set, so globals are judged too."""
    found: list[tuple[str, int, str]] = []
    global_reads: list[tuple[str, int, str, str]] = []
    given: set[str] = set()                      # globals some step could assign
    for prog in programs.values():
        locals_: set[str] = set(prog.params)
        autos: set[str] = set()
        assigned: set[str] = set(prog.params)
        for line, code in prog.steps:
            head = code.split()[0].upper()
            if head in _DECLARE:
                declared = {d.strip().split("[")[0].strip()
                            for d in code[len(head):].split(",") if d.strip()}
                locals_ |= declared
                if head == "AUTO":
                    autos |= declared
                else:
                    assigned |= declared         # LOCAL/GLOBAL persist: not judged
                continue
            target = _ASSIGN.match(code) if head not in _CONDITIONS + ("FOR",) else None
            if target:
                reads = _names((target.group(2) or "") + code[target.end():])
                writes = [target.group(1)]
            elif head in _CONDITIONS:
                reads, writes = _names(code[len(head):]), []
            else:
                reads, writes = [], _names(code)
            for name in reads:
                if reserved(name):
                    continue                     # refused as ``reserved`` already
                if name in autos and name not in assigned:
                    found.append((prog.file, line, f"AUTO variable {name} is read before "
                                                   "any step gives it a value"))
                    assigned.add(name)           # once per variable
                elif name not in locals_:
                    global_reads.append((prog.file, line, name, prog.name))
            for name in writes:
                (assigned if name in locals_ else given).add(name)
    reported: set[str] = set()
    for file, line, name, prog_name in global_reads:
        if globals_too and name not in given and name.lower() not in programs and name not in reported:
            reported.add(name)
            found.append((file, line, f"global {name} is read (in {prog_name}) but no step "
                                      "of any program gives it a value"))
    return found
