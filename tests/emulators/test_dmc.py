"""The DMC interpreter of the Galil emulator: Galil's expression rules, MG formatting,
program checks and threads, against a fake host (no plant, no sockets)."""

from __future__ import annotations

import threading

import pytest

from feeder_bt.emulators.galil.dmc import (
    DmcError,
    DmcInterpreter,
    Program,
    format_number,
    split_statements,
    tokenize,
)
from feeder_bt.hal.galil.driver import PROGRAMS_DIR
from feeder_bt.hal.galil.protocol import read_programs
from tests.support.galil_fixtures import wait_until


class FakeHost:
    """Operands from dicts; MG output and errors collected."""

    def __init__(self) -> None:
        self.operands: dict[str, float] = {"TPB": 0.0, "TPA": 7.0, "TI0": 0.0, "TI1": 0.0,
                                           "BGB": 0.0, "ED": 0.0, "ED1": 0.0}
        self.inputs: dict[int, float] = {}
        self.out: list[str] = []
        self.commands: list[tuple[str, int]] = []
        self.errors: list[tuple[int, int, int, str]] = []
        self.lock = threading.Lock()

    def operand(self, name: str, suffix: str) -> float:
        key = name + suffix
        if key not in self.operands:
            raise DmcError(1, f"_{key}")
        return self.operands[key]

    def function(self, name: str, arg: float) -> float:
        if name == "IN":
            return self.inputs.get(int(arg), 0.0)
        raise DmcError(57, name)

    def command(self, text: str, thread: int) -> None:
        if text.startswith("XX"):
            raise DmcError(1, text)
        with self.lock:
            self.commands.append((text, thread))

    def output(self, text: str) -> None:
        with self.lock:
            self.out.append(text)

    def thread_error(self, thread: int, error: DmcError, line: int, text: str,
                     trapped: bool = False) -> None:
        with self.lock:
            self.errors.append((thread, error.code, line, text))
            self.trapped = trapped

    def lines(self) -> list[str]:
        with self.lock:
            return [s.rstrip("\r\n") for s in self.out]


@pytest.fixture
def interp():
    host = FakeHost()
    it = DmcInterpreter(host)
    it.fake = host            # type: ignore[attr-defined]
    yield it
    it.halt()


# ---------------------------------------------------------------------------- expressions


@pytest.mark.parametrize(("expr", "value"), [
    ("1+2*3", 9.0),              # left to right, no precedence (Galil manual: MG 1+2*3 = 9)
    ("1+(2*3)", 7.0),
    ("10-4-3", 3.0),
    ("2*3+4/2", 5.0),            # ((2*3)+4)/2
    ("-5+2", -3.0),
    ("3*-2", -6.0),
    ("$FF&$0F", 15.0),
    ("4|1", 5.0),
    ("1+1>1", 1.0),              # (1+1) > 1: a comparison splits the two sides
    ("2>1+5", 0.0),              # 2 > (1+5)
    ("3=3", 1.0), ("3<>3", 0.0), ("2<=2", 1.0), ("2>=3", 0.0), ("1<2", 1.0),
    ("(1>0)&(2>3)", 0.0), ("(1>0)|(2>3)", 1.0),
    ("@ABS[-3]+1", 4.0), ("@INT[2.7]", 2.0), ("@FRAC[2.5]", 0.5), ("@RND[2.5]", 3.0),
    ("@SQR[16]", 4.0),
    ("_TPA*2", 14.0), ("@IN[2]", 1.0),
])
def test_expressions(interp, expr, value):
    interp.fake.inputs[2] = 1.0
    assert interp.evaluate(expr) == pytest.approx(value)


@pytest.mark.parametrize(("expr", "code"), [
    ("1/0", 6), ("(1+2", 59), ("@ABS[1", 55), ("UNDEF+1", 1), ("_XYB", 1), ("1+", 1),
    ("", 1), ("2 3", 1), ("@FOO[1]", 57), ("#", 1), ("@SQR[-1]", 6),
])
def test_expression_errors_have_galil_codes(interp, expr, code):
    with pytest.raises(DmcError) as err:
        interp.evaluate(expr)
    assert err.value.code == code


def test_variables(interp):
    interp.assign("STEP", "20*5")
    assert interp.evaluate("STEP+1") == 101
    with pytest.raises(DmcError) as err:
        interp.assign("TOOLONGNAME", "1")
    assert err.value.code == 9


@pytest.mark.parametrize("line", ["DNOW=_TP~a", "~a=1", "ST ~b", "JP #X,~b>=7", "MG ~a"])
def test_variable_axis_designators_are_refused_at_download(line):
    """Not confirmed on the DMC-21x3: a program relying on one fails at DL, not on a card."""
    with pytest.raises(DmcError, match="variable axis designator"):
        Program.parse(["#X", line, "EN"])
    with pytest.raises(DmcError):
        tokenize("_TP~a")
    Program.parse(["#X", 'MG "~a is text"', "EN"])           # inside a string it is text


def test_tokens():
    kinds = [t.kind for t in tokenize('_TPB>=DSTEP "s" @IN[1] $1F .5')]
    assert kinds == ["opnd", "cmp", "name", "str", "func", "punct", "num", "punct", "num",
                     "num"]
    with pytest.raises(DmcError):
        tokenize("1 ! 2")


# ---------------------------------------------------------------------------- MG


@pytest.mark.parametrize(("value", "kind", "m", "n", "text"), [
    (5, "", 10, 4, " 5.0000"),
    (-12.5, "", 10, 4, "-12.5000"),
    (4.1, "F", 5, 2, " 00004.10"),          # the Galil manual's example
    (999999.999, "F", 5, 2, " 99999.99"),   # too big: all nines
    (12345, "F", 10, 0, " 0000012345"),
    (-20, "F", 10, 0, "-0000000020"),
    (5, "F", 3, 0, " 005"),
    (5, "Z", 3, 0, " 5"),
    (255, "$", 4, 0, " $00FF"),
])
def test_number_formats(value, kind, m, n, text):
    assert format_number(value, kind, m, n) == text


def test_message_formatting(interp):
    interp.assign("X", "5")
    assert interp.message('"I", X {F3.0}') == "I 005\r\n"
    assert interp.message('"a", "b"') == "ab\r\n"
    assert interp.message('"v=", X {N}') == "v= 5.0000"
    assert interp.message('"x", {^65}') == "xA\r\n"
    assert interp.message("") == "\r\n"
    assert interp.message('"a;b, c"') == "a;b, c\r\n"
    for bad in ('"open', 'X {Q}', 'X {F}'):
        with pytest.raises(DmcError):
            interp.message(bad)


# ---------------------------------------------------------------------------- programs


def test_program_parse_and_checks():
    p = Program.parse('#A;MG "x;y"\nIF X>1\nIF Y>1\nELSE\nENDIF\nENDIF\nJP #A\nEN')
    assert list(p.labels) == ["#A"]
    assert split_statements('MG "x;y";JP #A;') == ['MG "x;y"', "JP #A"]
    for text, code in [("#A\nIF 1\nEN", 63), ("ENDIF", 63), ("ELSE", 63), ("#A\n#A", 61),
                       ("#TOOLONGX", 61), ("#1A", 61), ("JP #NOWHERE", 10),
                       ("MG 1;#A", 61), ("X" * 81, 60), ("EN\n" * 1001, 60),
                       ("JP", 11), ("WT (1", 1)]:
        try:
            Program.parse(text)
        except DmcError as e:
            assert e.code == code, (text[:20], e)
        else:
            if code != 1:
                pytest.fail(f"{text[:20]!r} parsed")


def test_threads_loops_subroutines_if_else(interp):
    prog = Program.parse("\n".join([
        "#MAIN",
        "N=0",
        "#LOOP",
        "N=N+1",
        "JS #SUB,N=2",
        "IF N<3",
        "  IF N=1",
        '    MG "one"',
        "  ELSE",
        '    MG "two"',
        "  ENDIF",
        "ELSE",
        '  MG "done", N {F1.0}',
        "  EN",
        "ENDIF",
        "JP #LOOP",
        "#SUB",
        'MG "sub"',
        "SB 1",
        "EN",
    ]))
    interp.load(prog)
    interp.execute("#MAIN", 0)
    assert wait_until(lambda: not interp.running())
    assert interp.fake.lines() == ["one", "sub", "two", "done 3"]
    assert interp.fake.commands == [("SB 1", 0)]
    assert interp.fake.errors == []


def test_wait_halt_and_two_threads(interp):
    interp.load(Program.parse("#A\nWT 10\nJP #A\n#B\nMG \"b\"\nWT 5\nJP #B\n#C\nJP #C"))
    interp.execute("#A", 0)
    interp.execute("#B", 1)
    interp.execute("#C", 2)                 # a loop with no WT still yields
    with pytest.raises(DmcError) as err:
        interp.execute("#A", 0)
    assert err.value.code == 19
    assert wait_until(lambda: len(interp.fake.lines()) >= 3)
    assert interp.running() == [0, 1, 2]
    with pytest.raises(DmcError) as err:
        interp.load(Program.parse("EN"))
    assert err.value.code == 17
    interp.halt(1)
    assert interp.running() == [0, 2]
    interp.halt()
    assert interp.running() == []
    for label, thread, code in [("#NONE", 0, 10), ("#A", 8, 6)]:
        with pytest.raises(DmcError) as err:
            interp.execute(label, thread)
        assert err.value.code == code


def test_an_error_stops_its_thread_with_a_code(interp):
    interp.load(Program.parse("#A\nMG \"before\"\nXX 1\nMG \"after\"\nEN\n#B\nY=UNDEF\nEN\n"
                              "#C\nJS #C"))
    interp.execute("#A", 3)
    interp.execute("#B", 4)
    interp.execute("#C", 5)
    assert wait_until(lambda: len(interp.fake.errors) == 3)
    errors = sorted(interp.fake.errors)
    assert errors[0] == (3, 1, 3, "XX 1")
    assert errors[1][:3] == (4, 1, 7)
    assert errors[2][:2] == (5, 12)                 # subroutines more than 16 deep
    assert interp.fake.lines() == ["before"]
    assert not interp.running()


def test_no_program_and_empty_download(interp):
    with pytest.raises(DmcError) as err:
        interp.execute("#A", 0)
    assert err.value.code == 10


def test_shipped_programs_run(interp):
    """galil_programs/: the input monitor reports changes, the notifier every DSTEP."""
    lines = read_programs(PROGRAMS_DIR, sorted(p.name for p in PROGRAMS_DIR.glob("*.dmc")))
    interp.load(Program.parse([pl.text for pl in lines]))
    interp.assign("DSTEP", "100")
    interp.assign("INBANKS", "2")                     # a 16-input card: _TI1 is read
    interp.assign("DAXIS", "1")                       # the latch axis: B
    host = interp.fake
    interp.execute("#INMON", 0)
    interp.execute("#DIST", 1)
    assert wait_until(lambda: "I 00000" in host.lines())
    host.operands["TI0"] = 5.0
    assert wait_until(lambda: "I 00005" in host.lines())
    host.operands["TI1"] = 2.0                        # input 10: the second bank too
    assert wait_until(lambda: "I 00517" in host.lines())
    host.operands["TPB"] = 99.0
    host.operands["TPB"] = 250.0
    assert wait_until(lambda: "D 0000000250" in host.lines())
    host.operands["TPB"] = 120.0                      # back 130 counts: a step the other way
    assert wait_until(lambda: "D 0000000120" in host.lines())
    assert host.errors == []
    assert interp.running() == [0, 1]


@pytest.mark.parametrize(("daxis", "axis"), list(enumerate("ABCDEFGH")))
def test_the_notifier_watches_the_axis_daxis_names(interp, daxis, axis):
    lines = read_programs(PROGRAMS_DIR, sorted(p.name for p in PROGRAMS_DIR.glob("*.dmc")))
    interp.load(Program.parse([pl.text for pl in lines]))
    interp.assign("DSTEP", "100")
    interp.assign("DAXIS", str(daxis))
    host = interp.fake
    host.operands.update({f"TP{a}": 0.0 for a in "ABCDEFGH"})
    interp.execute("#DIST", 1)
    assert wait_until(lambda: "DLAST" in interp.variables)     # its start count taken
    host.operands[f"TP{axis}"] = 300.0
    assert wait_until(lambda: "D 0000000300" in host.lines())
    assert host.errors == []


@pytest.mark.parametrize("wdaxes", [1, 2, 3, 0b10100000, 255])
def test_the_watchdog_stops_exactly_our_axes_by_name(interp, wdaxes):
    """#WDSTOP: ST of each axis in WDAXES, named by its letter, never a bare ST."""
    lines = read_programs(PROGRAMS_DIR, sorted(p.name for p in PROGRAMS_DIR.glob("*.dmc")))
    interp.load(Program.parse([pl.text for pl in lines]))
    interp.assign("WDAXES", str(wdaxes))
    interp.execute("#WDSTOP", 2)
    want = [f"ST {a}" for k, a in enumerate("ABCDEFGH") if wdaxes & (1 << k)]
    assert wait_until(lambda: not interp.running())
    assert [c for c, _ in interp.fake.commands] == want
    assert interp.fake.errors == []


def test_automatic_subroutines_interrupt_thread_0_and_return(interp):
    """#POSERR (and #LIMSWI, #AMPERR) run on the event, then RE goes back to the loop."""
    interp.load(Program.parse('#MAIN\n#LOOP\nN=N+1\nWT 5\nJP #LOOP\n'
                              '#POSERR\nMG "E POSERR"\nRE\n'))
    interp.assign("N", "0")
    interp.execute("#MAIN", 0)
    assert interp.interrupt("#POSERR", 0)
    assert wait_until(lambda: "E POSERR" in interp.fake.lines())
    n = interp.variables["N"]
    assert wait_until(lambda: interp.variables["N"] > n + 2)       # the loop went on
    assert interp.running() == [0]
    assert not interp.interrupt("#LIMSWI", 0)                       # no such label


def test_cmderr_catches_a_program_error_with_its_line_and_thread(interp):
    interp.load(Program.parse('#A\nXX 1\nEN\n#CMDERR\nMG "E CMDERR", _ED1 {F1.0}, _ED {F4.0}\nEN'))
    interp.fake.operands["ED"] = 2.0
    interp.fake.operands["ED1"] = 3.0
    interp.execute("#A", 3)
    assert wait_until(lambda: "E CMDERR 3 0002" in interp.fake.lines())
    assert interp.error_line == 2 and interp.error_thread == 3
    assert interp.fake.trapped
    assert wait_until(lambda: interp.thread_line(3) == -1)          # _XQ3: not running


def test_program_memory_refuses_more_labels_than_a_dmc():
    from feeder_bt.hal.galil.protocol import MAX_LABELS
    with pytest.raises(DmcError) as err:
        Program.parse("\n".join(f"#L{i}" for i in range(MAX_LABELS + 1)))
    assert err.value.code == 60
