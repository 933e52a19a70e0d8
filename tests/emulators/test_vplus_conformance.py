"""The V+ programs, the Python driver and vplus/PROTOCOL.md implement one command set.

Reads the command dispatch of the V+ servers (each handler is an ``IF $verb == "VERB"``
block; io_notify's messages are ``$line = "VERB ..."``), the driver's declared table
(``COMMANDS`` and ``NOTIFY_MESSAGES`` in hal/adept/protocol.py, read as source, not
imported, so a modified copy can be checked) and the per-socket tables of PROTOCOL.md.
"""

from __future__ import annotations

import ast
import re
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VPLUS = ROOT / "vplus"
PROTOCOL_PY = ROOT / "feeder_bt" / "hal" / "adept" / "protocol.py"
PROTOCOL_MD = VPLUS / "PROTOCOL.md"

SERVER_FILES = {"motion": "motion_server.v2", "position": "position_server.v2",
                "io": "io_server.v2", "notify": "io_notify.v2"}
_DISPATCH = re.compile(r'^\s*IF\s+\$verb\s*==\s*"([A-Z]+)"\s+THEN\b')
_MESSAGE = re.compile(r'^\s*\$line\s*=\s*"([A-Z]+) ')


def _code_lines(path: Path) -> list[str]:
    """The V+ source without comments (``;`` to the end of the line)."""
    return [line.split(";", 1)[0] for line in path.read_text().splitlines()]


def vplus_commands(vplus_dir: Path) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for socket, name in SERVER_FILES.items():
        pattern = _MESSAGE if socket == "notify" else _DISPATCH
        out[socket] = {m.group(1) for line in _code_lines(vplus_dir / name)
                       if (m := pattern.match(line))}
    return out


def python_commands(protocol_py: Path) -> dict[str, set[str]]:
    tree = ast.parse(protocol_py.read_text())
    out: dict[str, set[str]] = {}
    for node in tree.body:
        target = node.target if isinstance(node, ast.AnnAssign) else (
            node.targets[0] if isinstance(node, ast.Assign) else None)
        if not isinstance(target, ast.Name) or node.value is None:
            continue
        if target.id == "COMMANDS":
            assert isinstance(node.value, ast.Dict)
            for key, value in zip(node.value.keys, node.value.values, strict=True):
                out[ast.literal_eval(key)] = _verbs(value, "Command")
        elif target.id == "NOTIFY_MESSAGES":
            out["notify"] = _verbs(node.value, "Message")
    return out


def _verbs(node: ast.AST, ctor: str) -> set[str]:
    return {ast.literal_eval(call.args[0]) for call in ast.walk(node)
            if isinstance(call, ast.Call) and isinstance(call.func, ast.Name)
            and call.func.id == ctor and call.args}


def doc_commands(protocol_md: Path) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    section: str | None = None
    for line in protocol_md.read_text().splitlines():
        if m := re.match(r"^##\s+(\w+) socket\s*$", line):
            section = m.group(1)
            out[section] = set()
        elif line.startswith("## "):
            section = None
        elif section and (m := re.match(r"^\|\s*`([A-Z]+)\b", line)):
            out[section].add(m.group(1))
    return out


def check_conformance(vplus_dir: Path = VPLUS, protocol_py: Path = PROTOCOL_PY,
                      protocol_md: Path = PROTOCOL_MD) -> list[str]:
    """Every difference between the three command sets, one line each (empty: they agree)."""
    sides = {"V+": vplus_commands(vplus_dir), "Python": python_commands(protocol_py),
             "PROTOCOL.md": doc_commands(protocol_md)}
    problems = []
    for socket in SERVER_FILES:
        sets = {side: cmds.get(socket, set()) for side, cmds in sides.items()}
        everything = set().union(*sets.values())
        if not sets["V+"]:
            problems.append(f"{socket}: no commands found in the V+ source")
        for verb in sorted(everything):
            missing = [side for side, verbs in sets.items() if verb not in verbs]
            if missing:
                problems.append(f"{socket} {verb}: missing in {', '.join(missing)}")
    return problems


# ---------------------------------------------------------------------------- the check
def test_vplus_python_and_docs_have_the_same_command_sets():
    assert check_conformance() == []


def test_the_sets_are_the_expected_ones():
    cmds = vplus_commands(VPLUS)
    assert cmds["motion"] == {"HELLO", "PICK", "PLACE", "MOVE", "SAFE", "SPEED", "RECOVER",
                              "HOLDING", "HELD", "FRAME", "DEFSAFE", "ESTOP", "WINDOW",
                              "BELTSCALE"}
    assert cmds["position"] == {"HELLO", "WHERE", "BELT", "POLL", "STOP", "HERE"}
    assert cmds["io"] == {"HELLO", "SIG", "SET"}
    assert cmds["notify"] == {"IN"}


def test_the_emulator_answers_exactly_the_declared_commands():
    from feeder_bt.emulators.adept import AdeptEmulator
    from feeder_bt.hal.adept import protocol

    emu = AdeptEmulator(plant=None)                  # handlers only; nothing is started
    declared = {name: {c.verb for c in table} for name, table in protocol.COMMANDS.items()}
    assert emu.handled() == declared


# ---------------------------------------------------------------------------- it bites
@pytest.fixture
def copies(tmp_path):
    vplus = tmp_path / "vplus"
    shutil.copytree(VPLUS, vplus)
    py = tmp_path / "protocol.py"
    shutil.copy(PROTOCOL_PY, py)
    return vplus, py, vplus / "PROTOCOL.md"


def _remove_vplus_handler(path: Path, verb: str) -> None:
    """Delete the ``IF $verb == "VERB" THEN ... END`` block (and its marker comment)."""
    lines = path.read_text().splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if f'$verb == "{verb}"' in line)
    indent = len(lines[start]) - len(lines[start].lstrip())
    end = next(i for i in range(start + 1, len(lines))
               if lines[i].strip() == "END" and len(lines[i]) - len(lines[i].lstrip()) == indent)
    if lines[start - 1].strip().startswith(";@command"):
        start -= 1
    path.write_text("".join(lines[:start] + lines[end + 1:]))


@pytest.mark.parametrize("socket,verb", [("motion", "PLACE"), ("motion", "RECOVER"),
                                         ("position", "BELT"), ("io", "SET")])
def test_fails_when_a_command_is_removed_from_the_vplus_side(copies, socket, verb):
    vplus, py, md = copies
    _remove_vplus_handler(vplus / SERVER_FILES[socket], verb)
    assert verb not in vplus_commands(vplus)[socket]
    assert check_conformance(vplus, py, md) == [f"{socket} {verb}: missing in V+"]


@pytest.mark.parametrize("socket,verb", [("motion", "PICK"), ("motion", "HOLDING"),
                                         ("position", "WHERE"), ("io", "SIG")])
def test_fails_when_a_command_is_removed_from_the_python_side(copies, socket, verb):
    vplus, py, md = copies
    lines = py.read_text().splitlines(keepends=True)
    # the first matching line inside this socket's tuple of the COMMANDS literal
    start = next(i for i, line in enumerate(lines) if line.strip() == f'"{socket}": (')
    drop = next(i for i in range(start, len(lines)) if f'Command("{verb}"' in lines[i])
    py.write_text("".join(lines[:drop] + lines[drop + 1:]))
    assert check_conformance(vplus, py, md) == [f"{socket} {verb}: missing in Python"]


def test_fails_when_a_notify_message_or_a_doc_row_is_removed(copies):
    vplus, py, md = copies
    text = (vplus / "io_notify.v2").read_text()
    (vplus / "io_notify.v2").write_text(text.replace('$line = "IN ', '$line = "XX '))
    problems = check_conformance(vplus, py, md)
    assert "notify IN: missing in V+" in problems
    assert "notify XX: missing in Python, PROTOCOL.md" in problems

    shutil.copy(VPLUS / "io_notify.v2", vplus / "io_notify.v2")
    doc = md.read_text().splitlines(keepends=True)
    md.write_text("".join(line for line in doc if not line.startswith("| `SAFE`")))
    assert check_conformance(vplus, py, md) == ["motion SAFE: missing in PROTOCOL.md"]


# ---------------------------------------------------------------------------- V+ sources
_CALL = re.compile(r"\b(?:CALL|EXECUTE\s+\d+)\s+([a-z_][\w.]*)\s*\(", re.IGNORECASE)
_REACT = re.compile(r"\bREACTE\s+([a-z_][\w.]*)", re.IGNORECASE)
_WINDOW = re.compile(r"^\s*WINDOW\s+%[\w.]+\s*=.*,\s*([a-z_][\w.]*)\s*,\s*\d+\s*$", re.IGNORECASE)


def test_vplus_programs_are_well_formed_and_every_called_program_exists():
    defined: dict[str, str] = {}
    used: set[tuple[str, str]] = set()
    for path in sorted(VPLUS.glob("*.v2")):
        open_program = None
        for n, raw in enumerate(path.read_text().splitlines(), 1):
            code = raw.split(";", 1)[0].rstrip()
            if m := re.match(r"^\.PROGRAM\s+([\w.]+)\(.*\)\s*$", code):
                assert open_program is None, f"{path.name}:{n}: .PROGRAM inside {open_program}"
                open_program = m.group(1)
                assert open_program not in defined, f"{path.name}:{n}: {open_program} twice"
                defined[open_program] = path.name
            elif code.strip() == ".END":
                assert open_program is not None, f"{path.name}:{n}: .END without .PROGRAM"
                open_program = None
            elif code.strip():
                assert open_program is not None, f"{path.name}:{n}: code outside a program"
                for rx in (_CALL, _REACT, _WINDOW):
                    used.update((m.group(1), f"{path.name}:{n}") for m in rx.finditer(code))
        assert open_program is None, f"{path.name}: {open_program} has no .END"
    missing = sorted(f"{where}: {name}" for name, where in used if name not in defined)
    assert not missing, missing
    for server in ("a_server", "motion_server", "position_server", "io_server", "io_notify",
                   "err.trap", "arm.recover", "decode_and_do"):
        assert server in defined
