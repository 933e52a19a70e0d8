"""Examples in the README and docs/ must run: every `feeder ...` line in a sh block is run.

Runs are shortened (at most 60 virtual seconds, --fast, no live view; with --hal emulated
3 real seconds of feeding, 10 on a plate cell) so the suite stays quick; everything else on
the line is used as written."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario

DOCS = [Path("README.md"), *sorted(Path("docs").glob("*.md"))]
ROOT = Path(__file__).resolve().parents[2]


def commands() -> list[tuple[str, str]]:
    out = []
    for doc in DOCS:
        for block in re.findall(r"```sh\n(.*?)```", doc.read_text(), flags=re.S):
            for line in block.splitlines():
                line = line.split("&&")[-1].strip()
                if line.startswith("feeder "):
                    out.append((doc.name, line))
    return out


def shortened(argv: list[str]) -> list[str]:
    if argv[0] != "run":
        return argv
    argv = list(argv)
    emulated = "--hal" in argv and argv[argv.index("--hal") + 1] == "emulated"
    # The emulators run in real time. A plate cell picks its first parts within 10 s of
    # feeding; on a belt cell no part reaches the robot before ~20 s, so there a few
    # seconds start the cell through the real drivers, run the belts, take frames and stop
    # it in order, all that 10 s did (the emulated belt cell's feeding is the soak tests':
    # test_emulated_run.py).
    cap = 60.0
    if emulated:
        cap = 10.0 if load_scenario(argv[1])[1].presentation == "plate" else 3.0
    if "--duration" in argv:
        i = argv.index("--duration")
        argv[i + 1] = str(min(float(argv[i + 1]), cap))
    else:
        argv += ["--duration", str(cap)]
    if "--fast" not in argv and not emulated:
        argv.append("--fast")
    if "--db" not in argv:
        argv.append("--no-db")
    return argv


def test_docs_have_examples():
    assert len(commands()) >= 8


@pytest.mark.parametrize("doc,line", commands())
def test_documented_command_runs(doc, line, tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))         # leaf classes: examples.leaves:...
    args = shlex.split(line)[1:]
    taught = args[0] in ("check", "locate") and any(a.startswith("out/") for a in args)
    if args[0] in ("locate", "recipe", "report", "replay", "twin") or "--images" in args \
            or "--image" in args or taught:
        # they read what `render` / `teach` / `run --db` / `calibrate --save-image` wrote
        cmds = commands()
        db = next(iter(args[2:3] if args[0] == "twin" else args[1:2]), "")  # twin fit RUN.db
        for d, earlier in cmds[:cmds.index((doc, line))]:
            prev = shlex.split(earlier)[1:]
            if d == doc and ((prev[0] in ("render", "teach") or "--save-image" in prev)
                             if args[0] not in ("report", "replay", "twin") else db in prev):
                _run(doc, earlier, tmp_path, monkeypatch)
    _run(doc, line, tmp_path, monkeypatch)


def _run(doc, line, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    argv = shortened(shlex.split(line)[1:])
    for flag in ("-o", "--report"):           # write outputs into a scratch folder
        if flag in argv:
            i = argv.index(flag)
            argv[i + 1] = str(tmp_path / Path(argv[i + 1]).name)
    argv = [str(Path.cwd() / a) if a.startswith(("scenarios/", "cells/", "examples/", "faults/",
                                                 "supply/", "tests/data/"))
            else a
            for a in argv]
    # globs over the repository's files (photos in tests/data/) as the shell would
    argv = [str(p) for a in argv
            for p in (sorted(Path(a).parent.glob(Path(a).name))
                      if "*" in a and Path(a).is_absolute() and argv[0] != "check" else [a])]
    if argv[0] == "check":                    # expand globs the shell would expand
        root = str(Path.cwd())
        argv = [argv[0]] + [str(p) for a in argv[1:] for p in (sorted(Path.cwd().glob(
            a[len(root) + 1:])) if a.startswith(root + "/") else []) or [Path(a)]]
    if argv[0] == "tree" and argv[argv.index("--format") + 1] in ("svg", "png"):
        pytest.importorskip("shutil").which("dot") or pytest.skip("Graphviz not installed")
    monkeypatch.chdir(tmp_path)
    argv = [str(p) for a in argv                # globs over files earlier commands wrote
            for p in (sorted(Path().glob(a)) if "*" in a and not Path(a).is_absolute() else [a])]
    assert main(argv) == 0, f"{doc}: {line}"
