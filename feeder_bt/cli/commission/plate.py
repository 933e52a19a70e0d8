"""``feeder commission plate``: an AnyFeeder-class plate feeder, action by action, with the
person at the plate.

Connect (the port opened, the echo probed: a parameter set the feeder does not answer,
Rev. A p. 31, so a line coming back is its echo), init (``plate.commands.init``), the
parameters the cell file sets written after it and read back as the feeder answered them,
each action jogged once (one repetition) and confirmed by the person who watched the
plate (the command numbers are cell settings: a wrong number moves the wrong drive or is
refused), the error reset (which homes the plate, anyfeeder_connector) and the stop on
an idle feeder. The manuals publish no command that reads a parameter back: the report
keeps each parameter written with the feeder's answer. docs/plate-feeders.md has the
sources and the checks this makes.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from feeder_bt.cli.commission.steps import Asker, Report, try_step, wait
from feeder_bt.core.clock import RealClock
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CellSpec

#: (name, how to run it once, what the person should see)
ACTIONS: tuple[tuple[str, Callable[[Any], Job], str], ...] = (
    ("dispense", lambda f: f.dispense(1),
     "parts drop from the bulk container onto the rear of the plate"),
    ("feed_forward", lambda f: f.feed(1, 1), "the parts move forward, away from the bulk"),
    ("feed_backward", lambda f: f.feed(-1, 1), "the parts move back, towards the bulk"),
    ("flip", lambda f: f.flip(1), "the parts jump and land in place"),
    ("flip_forward", lambda f: f.flip(1, 1), "the parts jump and move forward"),
    ("flip_backward", lambda f: f.flip(1, -1), "the parts jump and move back"),
    ("heavy_dispense", lambda f: f.heavy_dispense(1),
     "more parts drop from the bulk container than a dispense drops"),
    ("purge", lambda f: f.purge(1), "the parts move back over the rear edge into the bulk "
                                    "(purge gate open)"),
)


def commission_plate(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                     ) -> None:
    from feeder_bt.hal.anyfeeder.driver import AnyFeeder
    plate = cell.plate
    if cell.presentation != "plate":
        report.step("plate.connect", False, error=f"{cell.path}: not a plate cell "
                                                  "(presentation: plate)")
        return
    feeder = AnyFeeder(plate, RealClock())
    t = plate.timeout_s + plate.init_s + 30.0
    c = plate.commands
    try:
        if not try_step(report, "plate.connect", lambda: wait(feeder.connect(), t)):
            return

        def init() -> dict[str, Any]:
            codes = wait(feeder.init(), t)
            seen = ask.yes("action.init", "The plate was told to initialise (home both "
                                          "drives): did both drives move to home?")
            return {"ok": seen, "command": f"x={c.init}", "replies": codes, "seen": seen}
        if not try_step(report, "plate.init", init):
            return

        def parameters() -> dict[str, Any]:
            written = dict(feeder.params)
            refused = [k for k, v in written.items() if any(
                a[-1] not in "01" for a in v["answer"])]
            return {"ok": not refused, "written": written, "refused": refused,
                    "note": "no read command is published: each parameter as written and "
                            "the feeder's answer" if written else
                            "the cell sets no speeds or repetitions: the feeder's own"}
        try_step(report, "plate.parameters", parameters)

        for name, run, what in ACTIONS:
            try_step(report, f"plate.{name}",
                     lambda n=name, r=run, w=what: _jog(feeder, ask, n, r, w, t))

        def reset() -> dict[str, Any]:
            codes = wait(feeder.reset(), t)
            seen = ask.yes("action.reset", "The plate was sent the error reset: did it "
                                           "move to home?")
            return {"ok": seen, "command": f"x={c.reset}", "replies": codes, "seen": seen}
        try_step(report, "plate.reset", reset)
        try_step(report, "plate.stop", lambda: {"command": f"x={c.stop}",
                                                "replies": wait(feeder.stop(), t)})
    finally:
        feeder.close()


def _jog(feeder: Any, ask: Asker, name: str, run: Callable[[Any], Job], what: str,
         t: float) -> dict[str, Any]:
    number = getattr(feeder.spec.commands, name)
    codes = wait(run(feeder), t)
    seen = ask.yes(f"action.{name}", f"The plate ran {name} (x={number}) once: "
                                     f"did {what}?")
    return {"ok": seen, "command": f"x={number}", "replies": codes, "seen": seen}
