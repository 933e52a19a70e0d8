"""`feeder run`'s exit codes are listed where the docs list them: the table in
docs/getting-started.md and the CI paragraph in docs/faults.md name every code the CLI
returns, each with the line on stderr that goes with it (exit 5 was in faults.md but not in
the table beside exit 4)."""

from __future__ import annotations

import re
from pathlib import Path

from feeder_bt.cli.main import EXIT_ACCOUNTING, EXIT_FED_TOO_LITTLE

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _table(text: str) -> dict[int, str]:
    section = text.split("## Exit codes", 1)[1].split("\n## ", 1)[0]
    return {int(m[1]): m[2] for m in re.finditer(r"^\| (\d+) \| (.*) \|$", section, re.M)}


def test_the_exit_code_table_has_every_code_of_feeder_run():
    rows = _table((DOCS / "getting-started.md").read_text())
    assert {0, 1, 2, 3, EXIT_ACCOUNTING, EXIT_FED_TOO_LITTLE} <= set(rows), sorted(rows)
    assert "lost or duplicated" in rows[EXIT_ACCOUNTING]
    assert "FED TOO LITTLE" in rows[EXIT_FED_TOO_LITTLE]
    assert "--min-ppm" in rows[EXIT_FED_TOO_LITTLE]


def test_the_ci_paragraph_names_them_too():
    text = " ".join((DOCS / "faults.md").read_text().split())
    para = text.split("`feeder run`'s exit codes, for a CI job:", 1)[1][:800]
    assert f"{EXIT_ACCOUNTING} a part lost" in para
    assert f"{EXIT_FED_TOO_LITTLE} the run fed too little" in para
