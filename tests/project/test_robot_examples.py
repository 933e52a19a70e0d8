"""The robot-side examples call only what their sources were looked up for: the URScript
client's every function is in the lists docs/part-server.md gives with their sources."""

from __future__ import annotations

import re
from pathlib import Path

SCRIPT = Path("examples/robots/part_client.script")
DOC = Path("docs/part-server.md")

#: URScript functions found in UR's own pages (docs/part-server.md gives each page)
CITED = {"encoder_enable_pulse_decode", "encoder_get_tick_count", "track_conveyor_linear",
         "stop_conveyor_tracking", "encoder_unwind_delta_tick_count", "pose_trans", "movel"}
#: called, but not found in a UR source here: named as such in docs/part-server.md
NOT_CONFIRMED = {"socket_open", "socket_send_line", "socket_read_string", "str_find",
                 "str_sub", "str_cat", "to_num", "d2r", "popup", "sleep",
                 "set_tool_digital_out", "get_tool_digital_in"}
#: the legacy or non-existent calls the example must not come back to
GONE = {"end_track_conveyor", "get_conveyor_tick_count", "conveyor_pulse_decode", "pose_add"}


def calls(text: str) -> tuple[set[str], set[str]]:
    """Functions called and functions defined, comments and strings left out."""
    code = "\n".join(re.sub(r'"[^"]*"', '""', ln.split("#", 1)[0])
                     for ln in text.splitlines())
    defined = set(re.findall(r"^\s*def\s+(\w+)\s*\(", code, flags=re.M))
    called = set(re.findall(r"(?<![\w.])([a-z_]\w*)\s*\(", code)) - {"def", "if", "while"}
    called -= {"p"}                      # p[...] is a pose literal, never p(
    return called - defined, defined


def test_the_urscript_client_calls_only_functions_with_a_source():
    called, _ = calls(SCRIPT.read_text())
    assert called <= CITED | NOT_CONFIRMED, sorted(called - CITED - NOT_CONFIRMED)
    assert not called & GONE
    assert {"track_conveyor_linear", "stop_conveyor_tracking", "pose_trans",
            "encoder_enable_pulse_decode"} <= called


def test_the_doc_names_every_function_the_client_calls():
    doc = DOC.read_text()
    called, _ = calls(SCRIPT.read_text())
    assert all(f"`{name}`" in doc for name in called), \
        sorted(n for n in called if f"`{n}`" not in doc)
    assert "universal-robots.com" in doc
