"""A shipped scenario copied beside a test with a few edits (the cell found from anywhere)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def edited_scenario(tmp_path: Path, name: str, *edits: tuple[str, str], text: str = "") -> Path:
    """``scenarios/NAME`` (or ``text``) with each ``(old, new)`` replaced (``old`` must be
    there: an edit that no longer applies fails the test, not silently passes it), written
    to ``tmp_path/NAME``."""
    text = text or (ROOT / "scenarios" / name).read_text()
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text)
    return p
