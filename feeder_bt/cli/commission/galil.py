"""``feeder commission galil``: the conveyor controller, wire by wire, with the person.

Connect (handle, ``CF``), firmware (``^R^V``), the card's program threads (``_XQ``), every
input the cell names (the person toggles it; the input monitor must report the change),
every output (set on, then off; the person says what they saw), the limit switches of
each conveyor axis (pressed, then released: ``_LF``/``_LR`` read 0 while a switch is
active, Galil DMC-21x3 command reference, "LF"/"LR" operands), the e-stop when it is
wired to this card, the encoder sign with the motors off (the person pushes the belt
forward by hand; the count must rise), the latch (the person fires the camera trigger;
the latched count is read, ``RL``), and per axis a short powered jog whose direction the
person confirms — the first ``SH`` only when the person says yes.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from feeder_bt.cli.commission.steps import (
    Asker,
    Report,
    active_low,
    ensure_motor_on,
    estop_step,
    motor_off,
    try_step,
    wait,
    wait_for,
)
from feeder_bt.core.clock import RealClock
from feeder_bt.core.encoder import diff
from feeder_bt.core.model import CellSpec

JOG_S = 1.0
PUSH_MM = 50.0           # how far the person pushes a belt by hand for the encoder sign
PUSH_MIN_MM = 10.0       # less than this after a push: the encoder did not see it


def commission_galil(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                     ) -> None:
    from feeder_bt.hal.galil import make_galil
    ctl, conveyors, io = make_galil(cell, RealClock())
    t = cell.galil.timeout_s + 1
    try:
        def connect() -> dict[str, Any]:
            ctl.ready.result(cell.galil.timeout_s * 4 + 5)
            return {"url": cell.galil.url, "handle": ctl.handle or "serial",
                    "servo": ctl.servo_refused or "on"}
        if not try_step(report, "galil.connect", connect):
            return

        def firmware() -> dict[str, Any]:
            text = ctl.command("\x12\x16").result(t).strip()
            ctl.firmware = text
            return {"ok": "DMC" in text, "firmware": text}
        try_step(report, "galil.firmware", firmware)

        def threads() -> dict[str, Any]:
            wait_for(lambda: len(ctl.thread_lines) >= 3, 2.0, 0.05)
            lines = dict(ctl.thread_lines)
            return {"ok": bool(lines) and all(v >= 0 for v in lines.values())
                    and not ctl.program_errors,
                    "threads": {f"thread{k}": v for k, v in sorted(lines.items())},
                    "program_errors": list(ctl.program_errors)}
        try_step(report, "galil.programs", threads)

        for name, bit in sorted(io.inputs.items(), key=lambda kv: kv[1]):
            if name == "estop":
                continue                                     # its own step, both ways
            try_step(report, f"galil.input.{name}",
                     lambda n=name, b=bit: _input(io, ask, n, b, opts.input_wait))
        for name, bit in sorted(io.outputs.items(), key=lambda kv: kv[1]):
            try_step(report, f"galil.output.{name}", lambda n=name, b=bit: _output(io, ask, n, b, t))
        for name, conv in conveyors.items():
            for forward in (True, False):
                which = "forward" if forward else "reverse"
                try_step(report, f"galil.limit.{name}.{which}",
                         lambda n=name, c=conv, f=forward: _limit(ctl, ask, n, c.axis, f, t,
                                                                  opts.input_wait))
        if "estop" in io.inputs:
            low = active_low(cell, "estop")
            try_step(report, "galil.estop", lambda: estop_step(
                ask, lambda: _raw_input(ctl, io.inputs["estop"], low),
                f"Galil input {io.inputs['estop']}", opts.input_wait))
        for name, conv in conveyors.items():
            try_step(report, f"galil.encoder.{name}", lambda n=name, c=conv: _encoder_sign(
                cell, ctl, ask, n, c, t))
        try_step(report, "galil.latch", lambda: _latch(cell, conveyors, ctl, ask))
        for name, conv in conveyors.items():
            try_step(report, f"galil.axis.{name}",
                     lambda n=name, c=conv: _axis(cell, ctl, n, c, ask, opts))
    finally:
        ctl.close()


def _raw_input(ctl: Any, bit: int, low: bool) -> bool | None:
    mask = ctl.inputs_mask
    if mask is None:
        return None
    return bool(mask >> (bit - 1) & 1) != low


def _input(io: Any, ask: Asker, name: str, bit: int, wait_s: float) -> dict[str, Any]:
    io.changes()                                  # forget what came before the question
    before = io.get(name)
    ask(f"input.{name}", f"Toggle input {name!r} (Galil input {bit}) now, then press Enter")
    seen: list[bool] = []

    def changed() -> bool:
        seen.extend(c.value for c in io.changes() if c.signal == name)
        return bool(seen)
    wait_for(changed, wait_s)
    return {"ok": bool(seen), "bit": bit, "was": before, "changes_seen": len(seen)}


def _output(io: Any, ask: Asker, name: str, bit: int, t: float) -> dict[str, Any]:
    wait(io.set(name, True), t)
    on = ask.yes(f"output.{name}.on", f"Output {name!r} (Galil output {bit}) is set ON: "
                                      "is it on at the cell?")
    wait(io.set(name, False), t)
    off = ask.yes(f"output.{name}.off", f"Output {name!r} is now OFF: is it off?")
    return {"ok": on and off, "bit": bit, "seen_on": on, "seen_off": off}


def _limit(ctl: Any, ask: Asker, name: str, axis: str, forward: bool, t: float,
           wait_s: float) -> dict[str, Any]:
    op = f"_L{'F' if forward else 'R'}{axis.upper()}"
    which = "forward" if forward else "reverse"

    def level() -> int:
        return ctl.submit(ctl.ask_number, f"MG {op}").result(t)
    before = level()
    if before == 0:
        return {"ok": False, "operand": op, "error": f"the {which} limit reads active before "
                                                     "it was pressed"}
    ask(f"limit.{name}.{which}.press", f"Press and hold the {which} limit switch of {name} "
                                       f"(axis {axis}), then press Enter")
    pressed = wait_for(lambda: level() == 0, wait_s, 0.1)
    ask(f"limit.{name}.{which}.release", f"Release the {which} limit switch of {name}, "
                                         "then press Enter")
    released = wait_for(lambda: level() == 1, wait_s, 0.1)
    return {"ok": bool(pressed and released), "operand": op, "pressed_seen": bool(pressed),
            "released_seen": bool(released)}


def _encoder_sign(cell: CellSpec, ctl: Any, ask: Asker, name: str, conv: Any, t: float
                  ) -> dict[str, Any]:
    if not motor_off(ctl, conv.axis, t):
        wait(conv.servo(False), t)                   # MO: a motor that is off never runs away
    before = ctl.submit(ctl.read_position, conv.axis).result(t)
    ask(f"push.{name}", f"Motor of {name} (axis {conv.axis}) is OFF. Push the {name} belt "
                        f"FORWARD (towards the robot) by hand, about {PUSH_MM:g} mm, then "
                        "press Enter")
    after = ctl.submit(ctl.read_position, conv.axis).result(t)
    counts = diff(after, before, cell.encoder.conveyor_bits)
    mm = counts / cell.encoder.counts_per_mm
    direction = "up" if mm >= PUSH_MIN_MM else "down" if mm <= -PUSH_MIN_MM else "none"
    found: dict[str, Any] = {"ok": direction == "up", "axis": conv.axis, "counts": counts,
                             "mm": round(mm, 1), "encoder_direction": direction}
    if direction == "down":
        found["error"] = ("the count falls as the belt moves forward: swap the encoder's A and "
                          "B channels (or CE) before the first SH")
    elif direction == "none":
        found["error"] = f"the count moved {mm:.1f} mm: is the encoder connected?"
    return found


def _latch(cell: CellSpec, conveyors: dict[str, Any], ctl: Any, ask: Asker
           ) -> dict[str, Any]:
    g = cell.galil
    axis = g.latch_axis.upper()
    name = next((n for n, a in g.axes.items() if a.upper() == axis), None)
    if name is None:
        return {"ok": False, "error": f"no conveyor on the latch axis {axis}"}
    conv = conveyors[name]
    wait(conv.arm_latch(), g.timeout_s + 1)
    ask("latch", f"Fire the camera trigger once (latch input {g.latch_input or 'of ' + axis}), "
                 f"then press Enter")
    count = wait(conv.read_latch(timeout_s=5.0), 7.0)
    return {"axis": axis, "input": g.latch_input or "ABCDEFGH".index(axis) + 1,
            "latched": count, "position_now": ctl.position(axis)}


def _axis(cell: CellSpec, ctl: Any, name: str, conv: Any, ask: Asker,
          opts: argparse.Namespace) -> dict[str, Any]:
    axis = conv.axis
    if not ensure_motor_on(ctl, conv, name, ask, cell.galil.timeout_s + 1):
        return {"ok": False, "axis": axis, "motor": "off (left off)"}
    before = ctl.submit(ctl.read_position, axis).result(cell.galil.timeout_s + 1)
    wait(conv.set_speed(opts.jog_mm_s), 10.0)
    time.sleep(JOG_S)
    wait(conv.stop(), 10.0)
    after = ctl.submit(ctl.read_position, axis).result(cell.galil.timeout_s + 1)
    moved = diff(after, before, cell.encoder.conveyor_bits)
    forward = ask.yes(f"direction.{name}", f"Did the {name} belt move forward (towards the "
                                            f"robot) just now?")
    mm = moved / cell.encoder.counts_per_mm
    return {"ok": moved > 0 and forward, "axis": axis, "counts": moved, "mm": round(mm, 2),
            "encoder_direction": "up" if moved > 0 else "down" if moved < 0 else "none",
            "belt_forward": forward}
