"""Each rule of the V+ checker, on a copy of the shipped programs with exactly one thing
broken: the checker refuses it with that rule and line, and accepts the
shipped programs as they are. Edits find their place by program and statement, not by
line number, so the shipped programs may change around them."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from feeder_bt.emulators.vplus.check import VPLUS_DIR, check_dir, check_text, main


# ---------------------------------------------------------------------------- helpers
def _code(line: str) -> str:
    return line.split(";", 1)[0].strip()


class Copy:
    """A copy of ``vplus/`` to break one thing in."""

    def __init__(self, tmp: Path) -> None:
        self.dir = tmp / "vplus"
        shutil.copytree(VPLUS_DIR, self.dir)

    def lines(self, file: str) -> list[str]:
        return (self.dir / file).read_text().split("\n")

    def write(self, file: str, lines: list[str]) -> None:
        (self.dir / file).write_text("\n".join(lines))

    def span(self, file: str, program: str) -> tuple[int, int]:
        """Indexes of ``.PROGRAM program(`` and its ``.END``."""
        lines = self.lines(file)
        start = next(i for i, s in enumerate(lines)
                     if _code(s).lower().startswith(f".program {program.lower()}("))
        end = next(i for i in range(start, len(lines)) if _code(lines[i]).upper() == ".END")
        return start, end

    def find(self, file: str, program: str, pred: Callable[[str], bool], after: int = -1
             ) -> int:
        """Index of the first step of ``program`` (after index ``after``) that ``pred``
        accepts."""
        start, end = self.span(file, program)
        lines = self.lines(file)
        return next(i for i in range(max(start + 1, after + 1), end) if pred(_code(lines[i])))

    def insert(self, file: str, program: str, step: str,
               before: Callable[[str], bool] = lambda c: c.startswith("CALL args.done")
               ) -> int:
        """Insert ``step`` before the first matching step; its 1-based line number."""
        at = self.find(file, program, before)
        lines = self.lines(file)
        lines.insert(at, "    " + step)
        self.write(file, lines)
        return at + 1

    def replace(self, file: str, program: str, pred: Callable[[str], bool], old: str,
                new: str) -> int:
        at = self.find(file, program, pred)
        lines = self.lines(file)
        assert old in lines[at], lines[at]
        lines[at] = lines[at].replace(old, new, 1)
        self.write(file, lines)
        return at + 1

    def delete(self, file: str, program: str, pred: Callable[[str], bool]) -> int:
        at = self.find(file, program, pred)
        lines = self.lines(file)
        del lines[at]
        self.write(file, lines)
        return at                      # the index the deleted line had

    def refused(self) -> set[tuple[str, int, str]]:
        return {(Path(f.file).name, f.line, f.rule) for f in check_dir(self.dir)}


@pytest.fixture
def cp(tmp_path: Path) -> Copy:
    return Copy(tmp_path)


def assert_only(cp: Copy, file: str, line: int, rule: str) -> None:
    found = cp.refused()
    assert (file, line, rule) in found, sorted(found)
    assert {r for _, _, r in found} == {rule}, sorted(found)


MS = "motion_server.v2"


# ---------------------------------------------------------------------------- as shipped
def test_the_shipped_programs_pass(cp):
    assert check_dir(cp.dir) == []
    assert main([str(VPLUS_DIR)]) == 0


# ---------------------------------------------------------------------------- names
@pytest.mark.parametrize("name", ["rz", "rx", "ry", "$rz", "frame", "inverse", "pi"])
def test_a_keyword_as_variable_is_refused(cp, name):
    # the audit's item 2: `rz` declared and used as a variable (motion_server.v2:291,335)
    line = cp.replace(MS, "do.place", lambda c: c.startswith("AUTO"), "AUTO ",
                      f"AUTO {name}, ")
    assert_only(cp, MS, line, "reserved")


def test_rz_in_a_pose_is_refused_where_it_is_used(cp):
    line = cp.insert(MS, "do.place", "SET place.loc = TRANS(0, 0, 0, 0, 180, rz)")
    assert_only(cp, MS, line, "reserved")


def test_dotted_names_that_start_with_a_keyword_are_one_word(cp):
    # V+ names are one run of letters, digits, '.' and '_' (User's Guide p. 99): rz.max is
    # not RZ (vplus_words docstring); the shipped stop.req and move.loc rely on it too
    cp.insert(MS, "do.place", "rz.max = 180")
    assert cp.refused() == set()


def test_a_name_over_15_characters_is_refused(cp):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("AUTO"), "AUTO ",
                      "AUTO place.tolerance.x, ")
    assert_only(cp, MS, line, "long-name")


# ---------------------------------------------------------------------------- forward processing
def _is_motion(code: str) -> bool:
    return code.split()[:1] in (["MOVES"], ["MOVE"], ["APPROS"], ["APPRO"])


def remove_the_wait(cp: Copy, program: str, signal: int) -> None:
    """Delete the BREAK the SIGNAL at index ``signal`` of ``program`` relies on: the last
    BREAK before it in ``program``, or the BREAK in the program the last CALL before it
    makes (``motion.done``, ``motion.halted``: wherever the shipped programs keep it)."""
    start, _ = cp.span(MS, program)
    lines = cp.lines(MS)
    depth = 0                                  # inside an IF/WHILE/CASE block before it
    for i in range(signal - 1, start, -1):
        code = _code(lines[i])
        words = code.split()
        if words in (["END"], ["UNTIL"]):
            depth += 1
        elif words[:1] in (["IF"], ["WHILE"], ["FOR"], ["CASE"], ["DO"]) and \
                (words[-1] in ("THEN", "DO", "OF") or words[0] in ("FOR", "DO")):
            depth -= 1
        if depth:
            continue
        if code == "BREAK":
            del lines[i]
            cp.write(MS, lines)
            return
        if code.startswith("CALL "):
            callee = code.split()[1].split("(")[0]
            try:
                cp.delete(MS, callee, lambda c: c == "BREAK")
                return
            except (StopIteration, ValueError):
                continue
    raise AssertionError(f"no BREAK before the SIGNAL of {program}")


@pytest.mark.parametrize("program", ["do.place", "do.pick"])
def test_a_removed_break_before_the_vacuum_is_refused(cp, program):
    # the audit's item 2: a BREAK deleted from do.place
    signal = cp.find(MS, program, lambda c: c.startswith("SIGNAL"))
    remove_the_wait(cp, program, signal)
    line = cp.find(MS, program, lambda c: c.startswith("SIGNAL")) + 1
    assert_only(cp, MS, line, "forward-processing")
    msg = [f.message for f in check_dir(cp.dir) if f.line == line][0]
    assert "forward processing" in msg and "no BREAK" in msg


def test_a_belt_read_for_the_grip_must_wait_for_the_arm(cp):
    # a new BELT read right after the descent, before the wait the SIGNAL has
    at = cp.find(MS, "do.pick", _is_motion) + 1
    lines = cp.lines(MS)
    lines.insert(at, "    enc = BELT(%pick.belt, 0)")
    cp.write(MS, lines)
    assert_only(cp, MS, at + 1, "forward-processing")


def test_a_signal_in_a_called_program_while_the_arm_moves_is_refused(cp):
    cp.write("grip.v2", [".PROGRAM vac.off()", "    SIGNAL -vacuum.out", ".END", ""])
    at = cp.find(MS, "do.place", _is_motion) + 1
    lines = cp.lines(MS)
    lines.insert(at, "    CALL vac.off()")
    cp.write(MS, lines)
    assert_only(cp, MS, at + 1, "forward-processing")


def test_a_motion_on_one_branch_only_counts_a_returning_branch_does_not():
    body = ["    IF a THEN", "        MOVE x.loc", "        RETURN", "    END",
            "    SIGNAL 1", "    IF a THEN", "        MOVES x.loc", "    ELSE",
            "        SIGNAL 2", "    END", "    SIGNAL 3"]
    text = "\n".join([".PROGRAM demo(a)", *body, ".END", ""])
    found = [(f.line, f.rule) for f in check_text(text, "d.v2")]
    assert found == [(12, "forward-processing")]       # only SIGNAL 3


@pytest.mark.parametrize("wait,found", [([], [(3, "forward-processing")]),
                                        (["        BREAK"], [])])
def test_a_motion_at_the_end_of_a_loop_reaches_its_start(wait, found):
    body = ["    WHILE a DO", "        SIGNAL 1", "        MOVE x.loc", *wait, "    END"]
    text = "\n".join([".PROGRAM demo(a)", *body, ".END", ""])
    assert [(f.line, f.rule) for f in check_text(text, "d.v2")] == found


# ---------------------------------------------------------------------------- text
def test_non_ascii_is_refused(cp):
    line = cp.insert(MS, "do.place", "; the arm \u2014 at the place")
    assert_only(cp, MS, line, "non-ascii")


def test_text_outside_programs_is_refused(cp):
    _, end = cp.span(MS, "do.place")
    lines = cp.lines(MS)
    lines.insert(end + 1, "; ---- moves")
    cp.write(MS, lines)
    assert_only(cp, MS, end + 2, "outside")


def test_a_long_line_is_refused(cp):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("AUTO"), "AUTO",
                      "AUTO" + " " * 80)
    assert_only(cp, MS, line, "long-line")


# ---------------------------------------------------------------------------- structure
def test_an_if_without_its_end_is_refused(cp):
    first_if = cp.find(MS, "do.place", lambda c: c.startswith("IF "))
    cp.delete(MS, "do.place", lambda c: c == "END")
    assert_only(cp, MS, first_if + 1, "structure")


def test_a_while_without_do_is_refused(cp):
    line = cp.replace("a_server.v2", "strip.eol", lambda c: c.startswith("WHILE"), " DO", "")
    assert_only(cp, "a_server.v2", line, "structure")


def test_a_case_without_its_opening_is_refused(cp):
    cp.delete("io_server.v2", "io_server", lambda c: c.startswith("CASE"))
    value = cp.find("io_server.v2", "io_server", lambda c: c.startswith("VALUE")) + 1
    found = cp.refused()
    assert ("io_server.v2", value, "structure") in found
    assert {r for _, _, r in found} == {"structure"}


@pytest.mark.parametrize("step,what", [("FOR n = 1 TO 2", "FOR is never closed"),
                                       ("UNTIL ok", "UNTIL without DO"),
                                       ("VALUE 3:", "VALUE outside CASE"),
                                       ("ANY", "ANY outside CASE")])
def test_an_unbalanced_step_is_refused(cp, step, what):
    line = cp.insert(MS, "do.place", step)
    assert_only(cp, MS, line, "structure")
    assert any(what in f.message for f in check_dir(cp.dir) if f.line == line)


# ---------------------------------------------------------------------------- programs
def test_a_call_of_an_undefined_program_is_refused(cp):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("CALL args.done"),
                      "args.done", "args.dome")
    assert_only(cp, MS, line, "undefined")


@pytest.mark.parametrize("args", ["$args", "$args, ok, ok"])
def test_a_call_with_the_wrong_number_of_arguments_is_refused(cp, args):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("CALL args.done"),
                      "($args, ok)", f"({args})")
    assert_only(cp, MS, line, "arguments")


@pytest.mark.parametrize("step", ["REACTE no.such.trap", "REACTI 1001, no.such.trap",
                                  "EXECUTE 4 no.such.task()"])
def test_a_reaction_naming_an_undefined_program_is_refused(cp, step):
    line = cp.insert(MS, "do.place", step)
    assert_only(cp, MS, line, "undefined")


def test_a_program_defined_twice_is_refused(cp):
    cp.write("zz_copy.v2", [".PROGRAM do.place($args, $reply)", "    RETURN", ".END", ""])
    assert_only(cp, "zz_copy.v2", 1, "duplicate")


def test_returne_outside_an_error_trap_is_refused(cp):
    line = cp.insert(MS, "do.place", "RETURNE")
    assert_only(cp, MS, line, "trap")


def test_returne_in_a_program_reacte_names_is_accepted(cp):
    cp.write("trap.v2", [".PROGRAM t.trap()", "    RETURNE", ".END", ""])
    cp.insert(MS, "do.place", "REACTE t.trap")
    assert cp.refused() == set()


# ---------------------------------------------------------------------------- steps
@pytest.mark.parametrize("step", ['ok = "yes"', "$reply = 5", "$reply = VAL($args)"])
def test_a_string_in_a_real_variable_and_the_reverse_are_refused(cp, step):
    line = cp.insert(MS, "do.place", step)
    assert_only(cp, MS, line, "type")


def test_string_comparisons_and_concatenations_are_not_type_errors(cp):
    cp.insert(MS, "do.place", 'ok = $args == "x"')
    cp.insert(MS, "do.place", '$reply = "OK "+$ENCODE(/I0, 1)')
    assert cp.refused() == set()


@pytest.mark.parametrize("old,new", [("SIGNAL", "SIGNL"), ("SIGNAL", "vacuum.set")])
def test_an_unknown_instruction_is_refused(cp, old, new):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("SIGNAL"), old, new)
    assert_only(cp, MS, line, "unknown-instruction")


def test_constructs_the_servers_use_are_accepted(cp):
    # what the rewritten programs (the audit's items 1 and 3) use: frames, INVERSE, traps
    cp.write("frames.v2", [
        ".PROGRAM f.demo()", "    AUTO c[6]",
        "    SET cell.frame = TRANS(100, -200, 0, 0, 0, 90)",
        "    SET p.loc = cell.frame:TRANS(10, 20, 30, 0, 180, 45)",
        "    DECOMPOSE c[0] = INVERSE(cell.frame):HERE",
        "    REACTI 2010, f.stop", "    REACTE f.trap",
        "    IF SIG(-1001) THEN", "        BRAKE", "    END", ".END", "",
        ".PROGRAM f.stop()", "    BRAKE", "    RETURN", ".END", "",
        ".PROGRAM f.trap()", "    DISABLE POWER", "    RETURNE", ".END", ""])
    assert cp.refused() == set()


# ---------------------------------------------------------------------------- values
def test_an_auto_variable_read_before_it_is_given_a_value_is_refused(cp):
    line = cp.replace(MS, "do.place", lambda c: c.startswith("AUTO"), "AUTO ", "AUTO tries, ")
    read = cp.insert(MS, "do.place", "tries = tries+1")
    assert_only(cp, MS, read, "unassigned")
    assert read > line


def test_a_global_no_program_assigns_is_refused(cp):
    line = cp.insert(MS, "do.place", "ok = stop.requested")          # typo of stop.req
    assert_only(cp, MS, line, "unassigned")


def test_a_variable_a_call_or_read_fills_counts_as_given(cp):
    cp.replace(MS, "do.place", lambda c: c.startswith("AUTO"), "AUTO ", "AUTO w, $word, ")
    cp.insert(MS, "do.place", "CALL next.word($args, $word)")
    cp.insert(MS, "do.place", "w = LEN($word)")
    assert cp.refused() == set()


def test_a_step_marked_nowait_may_run_while_the_arm_moves_and_only_it(cp):
    # the shipped do.pick reads the belt count "now" for its window check, marked @nowait;
    # the mark taken off, the same step is refused
    at = cp.find(MS, "do.pick", lambda c: c.startswith("CALL belt.moved(BELT("))
    lines = cp.lines(MS)
    assert "@nowait" in lines[at]
    assert not [f for f in check_dir(cp.dir) if f.rule == "forward-processing"]
    lines[at] = lines[at].split(";", 1)[0].rstrip()
    cp.write(MS, lines)
    # refused where the arm is still moving: the server loop's next request comes while
    # the last PLACE's departure runs
    found = [f for f in check_dir(cp.dir) if f.rule == "forward-processing"]
    assert found and "must wait for the arm" in found[0].message
