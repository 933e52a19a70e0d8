"""Regenerate every command output and figure quoted in docs/ (docs that cannot
go stale). ``python docs/build.py`` rewrites them in place; ``--check`` only compares and
exits 1 naming each quote that no longer matches (tests/project/test_docs_outputs.py runs that).

A quoted output is the fenced block right under a marker comment::

    <!-- output: feeder render scenarios/x.yaml --out out/f ; feeder locate ... | grep ^x -->

The commands (separated by `` ; ``) run with bash in a scratch folder holding copies of
scenarios/, cells/, faults/, supply/, examples/ and tests/data/ (so a command may write a
variant beside them), ``feeder`` being this checkout's CLI; the block is the last command's standard output
(``| grep RE`` keeps the lines matching the Python regex RE). A quote is exact, except
that wall-clock figures (``… s wall``, ``… ms``) are not compared (they are the machine's,
not the program's) and a marker ``<!-- output (±2 %): ...`` lets each number differ from a
fresh run's by that much of itself (figures that vary with the platform's floating point).

A figure is a marker ``<!-- figure: COMMANDS -> FILE.png -->`` above the image: the
commands write ``out/FILE.png``, copied to ``docs/FILE.png`` by ``python docs/build.py``.
``--check`` compares the title the plot wrote into the PNG's text (``feeder report
--plot`` does: the run, its seed, parts/min and length) with a fresh one's, the same way.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
COPIED = ("scenarios", "cells", "faults", "supply", "examples", "tests/data")
REL_TOL = 0.0         # by default a quote is exact (the runs are deterministic)
MARK = re.compile(r"<!-- output(?: \(±(?P<tol>[\d.]+) %\))?: (?P<cmds>.*?) -->\n+"
                  r"```(?P<lang>\w*)\n(?P<body>.*?)```", re.S)
FIGURE = re.compile(r"<!-- figure: (?P<cmds>.*?) -> (?P<png>[\w.-]+\.png) -->")
WALL = [(re.compile(r"\(\d+(?:\.\d+)? s wall\)"), "(… s wall)"),
        (re.compile(r"\b\d+(?:\.\d+)? ms\b"), "… ms")]
NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


@dataclass
class Quote:
    """One quoted output: where it is, the commands that make it, what the doc says."""

    doc: Path
    cmds: str
    body: str
    start: int
    end: int
    rel_tol: float = REL_TOL

    @property
    def where(self) -> str:
        line = self.doc.read_text()[: self.start].count("\n") + 1
        name = self.doc.relative_to(ROOT) if self.doc.is_relative_to(ROOT) else self.doc
        return f"{name}:{line}"


def quotes(docs: list[Path] | None = None) -> list[Quote]:
    """Every quoted output in the docs, in order."""
    out = []
    for doc in docs or sorted(DOCS.glob("*.md")):
        text = doc.read_text()
        for m in MARK.finditer(text):
            tol = float(m.group("tol")) / 100 if m.group("tol") else REL_TOL
            out.append(Quote(doc, " ".join(m.group("cmds").split()), m.group("body"),
                             m.start("body"), m.end("body"), tol))
    return out


def scratch() -> Path:
    """A folder with copies of the inputs and a `feeder` that runs this checkout."""
    tmp = Path(tempfile.mkdtemp(prefix="feeder-docs-"))
    for name in COPIED:
        shutil.copytree(ROOT / name, tmp / name)
    bin_dir = tmp / ".bin"
    bin_dir.mkdir()
    shim = bin_dir / "feeder"
    shim.write_text(f"#!/bin/sh\nexec {sys.executable} -m feeder_bt.cli \"$@\"\n")
    shim.chmod(0o755)
    return tmp


def run(cmds: str, where: Path) -> str:
    """The last command's output (filtered by a trailing ``| grep RE``)."""
    pattern = None
    m = re.search(r"\s\|\s*grep (.+)$", cmds)
    if m:
        cmds, pattern = cmds[: m.start()], m.group(1).strip().strip("'\"")
    env = dict(os.environ, PATH=f"{where / '.bin'}:{os.environ['PATH']}",
               PYTHONPATH=str(ROOT), COLUMNS="80")
    *setup, last = [c.strip() for c in cmds.split(" ; ")]
    for c in setup:
        subprocess.run(["bash", "-c", c], cwd=where, env=env, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600)
    done = subprocess.run(["bash", "-c", last], cwd=where, env=env, capture_output=True,
                          text=True, timeout=600)
    text = done.stdout + done.stderr if not done.stdout else done.stdout
    lines = text.splitlines()
    if pattern is not None:
        lines = [s for s in lines if re.search(pattern, s)]
    return "\n".join(s.rstrip() for s in lines) + "\n"


def _normal(text: str) -> str:
    for rx, to in WALL:
        text = rx.sub(to, text)
    return text


def same(quoted: str, fresh: str, rel_tol: float = REL_TOL) -> bool:
    """The words equal and each number within ``rel_tol`` of the fresh one."""
    a, b = _normal(quoted), _normal(fresh)
    if NUMBER.sub("#", a).split() != NUMBER.sub("#", b).split():
        return False
    for x, y in zip(NUMBER.findall(a), NUMBER.findall(b), strict=True):
        fx, fy = float(x), float(y)
        if abs(fx - fy) > rel_tol * max(abs(fy), 1e-9) and x != y:
            return False
    return True


def check(qs: list[Quote]) -> list[str]:
    """One line for each quote that no longer matches what its commands print."""
    bad = []
    where = scratch()
    try:
        for q in qs:
            fresh = run(q.cmds, where)
            if not same(q.body, fresh, q.rel_tol):
                bad.append(f"{q.where}: the quoted output of `{q.cmds}` is stale; now:\n"
                           + fresh)
        for doc, cmds, png in figures():
            run(cmds, where)
            old, new = png_title(DOCS / png), png_title(where / "out" / png)
            if not new or not same(old, new):
                bad.append(f"{doc.relative_to(ROOT)}: {png} is stale ({old or 'no title'!r}; "
                           f"now {new!r}): python docs/build.py")
    finally:
        shutil.rmtree(where, ignore_errors=True)
    return bad


def figures() -> list[tuple[Path, str, str]]:
    """(doc, commands, png) of every figure marker."""
    return [(doc, " ".join(m.group("cmds").split()), m.group("png"))
            for doc in sorted(DOCS.glob("*.md")) for m in FIGURE.finditer(doc.read_text())]


def png_title(path: Path) -> str:
    """The title a plot wrote into its PNG's text ("" if none)."""
    from PIL import Image
    try:
        with Image.open(path) as img:
            return str(img.info.get("Title", ""))
    except OSError:
        return ""


def build(qs: list[Quote]) -> int:
    """Rewrite every quote and redraw every figure from fresh runs."""
    where = scratch()
    try:
        by_doc: dict[Path, list[Quote]] = {}
        for q in qs:
            by_doc.setdefault(q.doc, []).append(q)
        for doc, items in by_doc.items():
            text = doc.read_text()
            for q in sorted(items, key=lambda q: -q.start):      # from the end: offsets hold
                text = text[: q.start] + run(q.cmds, where) + text[q.end:]
            doc.write_text(text)
            print(f"wrote {doc.relative_to(ROOT)} ({len(items)} output(s))")
        for _, cmds, png in figures():
            run(cmds, where)
            shutil.copy(where / "out" / png, DOCS / png)
            print(f"wrote docs/{png}")
    finally:
        shutil.rmtree(where, ignore_errors=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="compare only; exit 1 if stale")
    args = p.parse_args(argv)
    qs = quotes()
    if args.check:
        bad = check(qs)
        for line in bad:
            print(line, file=sys.stderr)
        print(f"{len(qs) - len(bad)} of {len(qs)} quoted outputs match")
        return 1 if bad else 0
    return build(qs)


if __name__ == "__main__":
    sys.exit(main())
