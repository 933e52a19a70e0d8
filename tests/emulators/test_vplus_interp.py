"""The V+ interpreter (feeder_bt/emulators/vplus) on small programs: each construct the
shipped programs use, as the V+ manuals describe it."""

from __future__ import annotations

import math
import threading
import time

import pytest

from feeder_bt.emulators.vplus.parse import SyntaxErr, tokenize
from feeder_bt.emulators.vplus.program import LoadError, load_text
from feeder_bt.emulators.vplus.task import VError
from tests.support.vplus_rig import g, make_runtime, run


def test_arithmetic_relations_and_logic():
    rt, _ = run("""
.PROGRAM main()
    a = 2+3*4
    b = (2+3)*4
    c = 2^3
    d = 7 MOD 3
    e = (1 < 2) AND NOT (3 == 4)
    f = (1 > 2) OR (2 <> 2)
    h = 10/4
.END
""")
    assert g(rt, "a") == 14 and g(rt, "b") == 20 and g(rt, "d") == 1 and g(rt, "h") == 2.5
    assert g(rt, "c") == 8
    assert g(rt, "e") == -1 and g(rt, "f") == 0          # TRUE is -1, FALSE 0


def test_string_functions():
    rt, _ = run("""
.PROGRAM main()
    $s = $ENCODE(/I0, 42)+" "+$ENCODE(/F0.3, -1.5)+" "+$ENCODE(/I0, -7)
    n = LEN($s)
    $m = $MID("abcdef", 2, 3)
    c = ASC("AB", 2)
    c0 = ASC("", 1)
    p = POS("+-.0123456789", "5", 1)
    q = POS("abc", "z", 1)
    v = VAL("12.5abc")
    i = INT(-3.7)
    $t = "  PICK 1 2"
    $w = $DECODE($t, " ", 0)
    $e = $ERROR(-610)
.END
""")
    assert g(rt, "$s") == "42 -1.500 -7" and g(rt, "n") == 12
    assert g(rt, "$m") == "bcd" and g(rt, "c") == 66 and g(rt, "c0") == -1
    assert g(rt, "p") == 9 and g(rt, "q") == 0 and g(rt, "v") == 12.5 and g(rt, "i") == -3
    assert g(rt, "$w") == "" and g(rt, "$t") == "  PICK 1 2"   # a blank first: nothing taken
    assert g(rt, "$e") == "*Location out of range*"


def test_decode_takes_the_word_off_the_variable():
    rt, _ = run("""
.PROGRAM main()
    $t = "PICK 17 2"
    $w = $DECODE($t, " ", 0)
.END
""")
    assert g(rt, "$w") == "PICK" and g(rt, "$t") == " 17 2"


def test_if_else_while_for_case():
    rt, _ = run("""
.PROGRAM main()
    IF 1 > 2 THEN
        a = 1
    ELSE
        a = 2
    END
    n = 0
    WHILE n < 5 DO
        n = n+1
    END
    s = 0
    FOR k = 1 TO 10 STEP 3
        s = s+k
    END
    down = 0
    FOR k = 3 TO 1 STEP -1
        down = down*10+k
    END
    $out = ""
    FOR k = 1 TO 4
        CASE k OF
            VALUE 1:
                $out = $out+"a"
            VALUE 2, 3:
                $out = $out+"b"
            ANY
                $out = $out+"z"
        END
    END
.END
""")
    assert g(rt, "a") == 2 and g(rt, "n") == 5
    assert g(rt, "s") == 1 + 4 + 7 + 10 and g(rt, "down") == 321
    assert g(rt, "$out") == "abbz"


def test_call_passes_variables_by_reference_and_autos_stay_local():
    rt, cells = run("""
.PROGRAM main(out)
    AUTO x, arr[3]
    x = 1
    arr[1] = 5
    CALL bump(x)
    CALL bump(arr[1])
    CALL bump(x+100)
    out = x*100+arr[1]
    shared = 7
.END

.PROGRAM bump(v)
    AUTO x
    x = 1000
    v = v+1
.END
""", args=(0.0,))
    assert cells[0].v == 2 * 100 + 6               # x and arr[1] bumped, x+100 a copy
    assert "x" not in rt.globals and g(rt, "shared") == 7     # AUTO local, global flat


def test_transformations_compose_invert_and_decompose():
    rt, _ = run("""
.PROGRAM main()
    AUTO c[6]
    SET f = INVERSE(TRANS(1370, 305, 0, 90, 0, 0))
    SET p = f:TRANS(1300, 100, 0, 0, 180, 30)
    DECOMPOSE c[0] = INVERSE(f):p
    x = c[0]
    y = c[1]
    pitch = c[4]
    roll = c[5]
    wx = DX(p)
    wy = DY(p)
    wz = DZ(p)
.END
""")
    assert g(rt, "x") == pytest.approx(1300) and g(rt, "y") == pytest.approx(100)
    assert g(rt, "pitch") == pytest.approx(180) and g(rt, "roll") == pytest.approx(30)
    # the point in robot world: turned -90 deg about the base at (1370, 305)
    assert (g(rt, "wx"), g(rt, "wy")) == (pytest.approx(-205), pytest.approx(70))
    assert g(rt, "wz") == pytest.approx(0)


def test_reacte_returne_goes_on_after_the_failed_step_and_return_retries():
    rt, _ = run("""
.PROGRAM main()
    tries = 0
    after = 0
    REACTE trap1
    x = undefined.thing
    after = 1
    REACTE trap2
    x = retry.me
    done = 1
.END

.PROGRAM trap1()
    code = ERROR(-1, 0)
    RETURNE
.END

.PROGRAM trap2()
    tries = tries+1
    retry.me = 5
    RETURN
.END
""")
    assert g(rt, "after") == 1 and g(rt, "code") == -401          # the step was skipped
    assert g(rt, "tries") == 1 and g(rt, "x") == 5 and g(rt, "done") == 1   # retried


def test_an_error_without_a_trap_stops_the_program():
    with pytest.raises(VError, match="-401"):
        run(".PROGRAM main()\n    x = nowhere\n.END\n")


def test_statements_outside_the_subset_are_refused_with_file_and_line():
    with pytest.raises(LoadError, match=r"test.v2:2: .*GOTO"):
        load_text(".PROGRAM main()\n    GOTO 10\n.END\n", "test.v2")
    with pytest.raises(SyntaxErr):
        tokenize("a = 1 @ 2")


def test_signals_outputs_inputs_soft_and_complement():
    rt, _ = run("""
.PROGRAM main()
    SIGNAL 2, 2005
    on2 = SIG(2)
    soft = SIG(2005)
    SIGNAL -2005
    soft.off = SIG(-2005)
    estop = SIG(1001)
    not.estop = SIG(-1001)
    SIGNAL -2
.END
""")
    assert g(rt, "on2") == -1 and g(rt, "soft") == -1 and g(rt, "soft.off") == -1
    assert g(rt, "estop") == 0 and g(rt, "not.estop") == -1


ARM = """
.PROGRAM main()
    SPEED 5 ALWAYS
    SET f = INVERSE(TRANS(1370, 305, 0, 0, 0, 0))
    SET a = f:TRANS(1370, -150, 0, 0, 180, 0)
    SET b = f:TRANS(1100, 100, 0, 0, 180, 0)
    MOVE a
    BREAK
    t0 = TIMER(-3)
    MOVE b
    x.moving = DX(HERE)
    SIGNAL 2010
    BREAK
    t1 = TIMER(-3)
    x.there = DX(HERE)
.END
"""


def test_forward_processing_runs_ahead_until_break():
    rt, _ = run(ARM)
    assert g(rt, "x.moving") == pytest.approx(0.0, abs=60)  # still near a (robot x 0)
    assert rt.soft[2010]                                       # signalled while moving
    assert g(rt, "x.there") == pytest.approx(-270.0, abs=1e-6)  # at b after BREAK
    assert g(rt, "t1") - g(rt, "t0") > 1.0                     # 5 %: a slow move


def test_a_target_outside_the_reach_is_refused_before_moving():
    with pytest.raises(VError, match="-610"):
        run("""
.PROGRAM main()
    SET far = TRANS(2000, 0, 0, 0, 180, 0)
    x.before = DX(HERE)
    MOVE far
.END
""")
    rt = make_runtime(".PROGRAM main()\n    SET near = TRANS(10, 0, 0, 0, 180, 0)\n"
                      "    r = INRANGE(near)\n.END\n")
    run("", rt=rt)
    assert g(rt, "r") != 0                          # inside the inner reach


def test_brake_from_another_task_stops_the_motion_where_it_is():
    rt = make_runtime(ARM.replace("    SIGNAL 2010\n", ""))
    result = {}

    def go():
        run("", rt=rt)
        result["done"] = True

    t = threading.Thread(target=go, daemon=True)
    t.start()
    deadline = time.monotonic() + 20
    while not (rt.arm.motion and rt.arm.motion.kind == "move" and "t0" in rt.globals):
        assert time.monotonic() < deadline
        time.sleep(0.005)
    with rt.lock:
        rt.arm.brake()
    t.join(20)
    assert result.get("done")
    x = g(rt, "x.there")
    assert -270.0 + 1.0 < x < 0.0 + 1e-6 and not math.isclose(x, -270.0)


def test_belt_locations_move_with_the_belt_count():
    rt = make_runtime("""
.PROGRAM main()
    SET nom = INVERSE(TRANS(1370, 305, 0, 0, 0, 0))
    DEFBELT %b = nom, 1, 16, 0.05
    SETBELT %b = BELT(%b, 0)-2000
    SET loc = TRANS(800, 300, 0, 0, 180, 0)
    SET w = %b:loc
    wx = DX(w)
    wy = DY(w)
.END
""")
    run("", rt=rt)
    # 2000 counts at 0.05 mm per count: 100 mm along the belt, in robot world
    assert g(rt, "wx") == pytest.approx(800 + 100 - 1370, abs=1e-6)
    assert g(rt, "wy") == pytest.approx(300 - 305, abs=1e-6)


def test_execute_starts_a_task_that_shares_global_memory():
    rt = make_runtime("""
.PROGRAM main()
    flag = 0
    EXECUTE 1 helper(41)
    t0 = TIMER(-3)
    WHILE flag == 0 DO
        WAIT
    END
.END

.PROGRAM helper(n)
    flag = n+1
.END
""")
    done = threading.Event()

    def go():
        run("", rt=rt)
        done.set()

    threading.Thread(target=go, daemon=True).start()
    assert done.wait(30)
    assert g(rt, "flag") == 42 and rt.tasks[1].number == 1
    rt.stop()
