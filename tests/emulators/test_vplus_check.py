"""The V+ checker refuses what V+ LOAD refuses (one test per rule, each finding of the V+ audit
item 1 among them), accepts every shipped program, and the emulator will not serve a
program it refuses."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.emulators.vplus.check import (
    VPLUS_DIR,
    VplusRefused,
    check_dir,
    check_text,
    main,
    require_loadable,
)


def prog(*body: str, name: str = "demo", params: str = "") -> str:
    return "\n".join([f".PROGRAM {name}({params})", *body, ".END", ""])


def rules(text: str, **kw) -> list[tuple[int, str]]:
    return [(f.line, f.rule) for f in check_text(text, "t.v2", **kw)]


def test_every_shipped_program_is_accepted():
    assert check_dir(VPLUS_DIR) == []
    require_loadable(VPLUS_DIR)
    assert main([str(VPLUS_DIR)]) == 0


# ---------------------------------------------------------------------------- reserved words
@pytest.mark.parametrize("source,line", [
    # the audit's item 1: a_server.v2:155,170 (value), motion_server.v2:132 (latch, id),
    # io_notify.v2:12 (last[]), status
    (prog("    x = 1", params="$args, value, ok"), 1),
    (prog("    value = VAL($word)"), 2),
    (prog("    AUTO id, x, ok"), 2),
    (prog("    AUTO x, latch, ok"), 2),
    (prog("    AUTO lun, last[32]"), 2),
    (prog("    status = IOSTAT(lun)"), 2),
    (prog("    CALL motion.done(status)"), 2),
])
def test_keywords_as_variable_names_are_refused(source, line):
    assert (line, "reserved") in rules(source)


def test_a_program_named_after_an_instruction_is_refused():
    found = check_text(prog("    RETURN", name="reacte"), "reacte.v2")
    assert [(f.line, f.rule) for f in found] == [(1, "reserved")]
    assert str(found[0]) == ("reacte.v2:1: reserved: program name 'reacte' is the V+ "
                             "keyword REACTE")


def test_keywords_in_capitals_stay_keywords():
    assert rules(prog("    AUTO st", "    st = IOSTAT(lun)", "    REACTE err.trap",
                      "    WAIT")) == []


# ---------------------------------------------------------------------------- names
def test_names_over_15_characters_are_refused():
    # a_server.v2:66: err.out.of.range (16): V+ would truncate it to err.out.of.rang
    assert rules(prog("    err.out.of.range = -610")) == [(2, "long-name")]
    assert rules(prog("    err.range = -610")) == []
    assert rules(prog("    x = 1", name="a_very_long_prog")) == [(1, "long-name")]
    assert rules(prog("    $fifteen.chars.x = \"\"")) == []          # 15 without the $


def test_names_with_bad_characters_are_refused():
    assert rules(prog("    AUTO 3x")) == [(2, "bad-name")]


# ---------------------------------------------------------------------------- text
def test_non_ascii_is_refused():
    # reacte.v2:3-4: an em dash in a comment
    found = check_text(prog("; the arm \u2014 stalled"), "r.v2")
    assert [(f.line, f.rule) for f in found] == [(2, "non-ascii")]
    assert "U+2014" in found[0].message


def test_text_outside_programs_is_refused():
    # a_server.v2:115-118: a comment block between two programs
    text = prog("    x = 1") + "\n; ---- socket helpers\n" + prog("    y = 2", name="other")
    assert rules(text) == [(5, "outside")]
    assert rules("\n\n" + prog("    x = 1") + "\n\n") == []      # blank lines are fine


def test_long_lines_are_refused_and_the_limit_is_a_setting():
    # io_server.v2:97: 116 characters
    long = "    ok = (s == INT(s)) AND " + " AND ".join(["(s > 1)"] * 12)
    assert len(long) > 80
    assert rules(prog(long)) == [(2, "long-line")]
    assert rules(prog(long), max_line=len(long)) == []


# ---------------------------------------------------------------------------- structure
@pytest.mark.parametrize("body,line,what", [
    (["    IF x THEN", "        y = 1"], 2, "IF is never closed"),
    (["    IF x THEN", "    END", "    END"], 4, "END without"),
    (["    WHILE x DO", "        y = 1"], 2, "WHILE is never closed"),
    (["    WHILE x", "        y = 1", "    END"], 2, "WHILE without DO"),
    (["    DO", "        y = 1", "    END"], 4, "DO ends with UNTIL"),
    (["    y = 1", "    UNTIL y > 0"], 3, "UNTIL without DO"),
    (["    FOR n = 0 TO 3", "        y = n"], 2, "FOR is never closed"),
    (["    CASE x OF", "        VALUE 1:", "            y = 1"], 2, "CASE is never closed"),
    (["    VALUE 1:"], 2, "VALUE outside CASE"),
    (["    ELSE"], 2, "ELSE outside IF"),
    (["    IF x > 1", "        y = 1", "    END"], 2, "IF without THEN"),
])
def test_unbalanced_control_structures_are_refused(body, line, what):
    found = check_text(prog(*body), "s.v2")
    assert any(f.rule == "structure" and f.line == line and what in f.message for f in found), \
        [str(f) for f in found]


def test_balanced_structures_are_accepted():
    body = ["    AUTO n, y", "    n = 1", "    IF n THEN", "        y = 1", "    ELSE", "        y = 2",
            "    END", "    WHILE y DO", "        y = y-1", "    END", "    DO",
            "        y = y+1", "    UNTIL y > 3", "    FOR n = 0 TO 3", "        y = n",
            "    END", "    CASE y OF", "        VALUE 1, 2:", "            y = 0",
            "        ANY", "    END", "    IF y GOTO 10"]
    assert rules(prog(*body)) == []


def test_a_program_without_end_and_declarations_after_code_are_refused():
    assert (1, "structure") in rules(".PROGRAM demo()\n    x = 1\n")
    assert rules(prog("    x = 1", "    AUTO y")) == [(3, "declaration")]


def test_calls_to_undefined_programs_and_duplicates_are_refused(tmp_path):
    (tmp_path / "a.v2").write_text(prog("    CALL nowhere(1)", name="a"))
    (tmp_path / "b.v2").write_text(prog("    RETURN", name="a"))
    found = {(Path(f.file).name, f.line, f.rule) for f in check_dir(tmp_path)}
    assert found == {("a.v2", 2, "undefined"), ("b.v2", 1, "duplicate")}


# ---------------------------------------------------------------------------- the emulator
def test_the_emulator_refuses_to_serve_programs_v_plus_would_not_load(tmp_path):
    vplus = tmp_path / "vplus"
    shutil.copytree(VPLUS_DIR, vplus)
    path = vplus / "motion_server.v2"
    path.write_text(path.read_text().replace("AUTO pid, x, y", "AUTO id, x, y"))
    emu = AdeptEmulator(plant=None, programs=vplus)
    with pytest.raises(VplusRefused) as info:
        emu.start()
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}:") or "motion_server.v2:" in msg
    assert "reserved: variable 'id' is the V+ keyword ID" in msg
    assert emu.ports["motion"] == 0                   # nothing was opened
    assert main([str(vplus)]) == 1


def test_the_cli_exits_non_zero_with_one_line(tmp_path, capsys):
    (tmp_path / "x.v2").write_text("; stray\n" + prog("    RETURN", name="x"))
    assert main([str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("x.v2:1: outside: text outside .PROGRAM ... .END")
