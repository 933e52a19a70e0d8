"""What every commissioning shares: asking the person, the report, steps, waiting."""

from __future__ import annotations

import datetime
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import yaml

from feeder_bt.core.errors import FeederError
from feeder_bt.core.jobs import Job, JobState
from feeder_bt.core.model import CellSpec


class CommissionError(FeederError):
    exit_code = 2


class Asker:
    """Questions to the person at the cell: from the answers file, else standard input.

    A question is one prompt ending in ``[KEY] `` (no newline) so a person types the answer
    after it; a rehearsal's driver (tests/cli/test_commission.py) matches the key."""

    def __init__(self, answers: dict[str, Any], stdin: TextIO, out: TextIO) -> None:
        self.answers, self.stdin, self.out = answers, stdin, out

    def __call__(self, key: str, question: str, default: str = "") -> str:
        if key in self.answers:
            answer = str(self.answers[key])
            print(f"{question} [{key}] -> {answer}", file=self.out, flush=True)
            return answer
        print(f"{question} [{key}] ", end="", file=self.out, flush=True)
        line = self.stdin.readline()
        answer = line.strip() if line else default
        if not line:
            print(f"(no answer: {default or 'nothing'})", file=self.out, flush=True)
        return answer

    def yes(self, key: str, question: str) -> bool:
        return self(key, f"{question} [yes/no]", "no").strip().lower() in ("y", "yes", "true")


def load_answers(path: str | None) -> dict[str, Any]:
    if not path:
        return {}
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise CommissionError(f"{p}: cannot read answers: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        raise CommissionError(f"{p}: not YAML: {str(e).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise CommissionError(f"{p}: answers must be a mapping of step keys to answers")
    return {str(k): v for k, v in data.items()}


class Report:
    """The steps and what each found; written as YAML or JSON."""

    def __init__(self, what: str, cell: CellSpec, out: TextIO) -> None:
        self.out = out
        self.data: dict[str, Any] = {
            "commission": what, "cell": cell.name, "cell_file": str(cell.path),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "steps": []}

    def step(self, name: str, ok: bool, **found: Any) -> bool:
        self.data["steps"].append({"step": name, "ok": bool(ok), **found})
        detail = ", ".join(f"{k}={v}" for k, v in found.items())
        print(f"{'ok  ' if ok else 'FAIL'} {name}: {detail}", file=self.out, flush=True)
        return ok

    @property
    def ok(self) -> bool:
        return all(s["ok"] for s in self.data["steps"]) and bool(self.data["steps"])

    def write(self, path: Path) -> None:
        self.data["ok"] = self.ok
        text = (json.dumps(self.data, indent=2) if path.suffix == ".json"
                else yaml.safe_dump(self.data, sort_keys=False))
        try:
            path.write_text(text, encoding="utf-8")
        except OSError as e:
            raise CommissionError(f"{path}: cannot write the report: {e.strerror or e}") from None


def wait(job: Job, timeout: float) -> Any:
    """Poll a HAL job until it ends; its result, or raise its error (or a time-out)."""
    end = time.monotonic() + timeout
    while not job.done and time.monotonic() < end:
        time.sleep(0.01)
    if job.state is JobState.SUCCEEDED:
        return job.result
    raise job.error if job.error is not None else TimeoutError(f"{job.name}: no end in "
                                                               f"{timeout:g} s")


def wait_for(cond: Callable[[], Any], timeout: float, period: float = 0.02) -> Any:
    """Poll ``cond`` until it is truthy or ``timeout`` passes; its last value."""
    end = time.monotonic() + timeout
    value = cond()
    while not value and time.monotonic() < end:
        time.sleep(period)
        value = cond()
    return value


def try_step(report: Report, name: str, fn: Callable[[], dict[str, Any]]) -> bool:
    """Run one step; an exception is that step's failure, in one line."""
    try:
        found = fn()
    except Exception as e:                       # noqa: BLE001 - any failure is a finding
        return report.step(name, False, error=f"{type(e).__name__}: {e}")
    ok = bool(found.pop("ok", True))
    return report.step(name, ok, **found)


def active_low(cell: CellSpec, name: str) -> bool:
    """Whether input ``name`` reads 0 while active: ``io.NAME.active: low`` (or the older
    ``active_low: true``). Check at commissioning: the e-stop step shows which it is."""
    sig = cell.io.get(name)
    if sig is None:
        return False
    active = getattr(sig, "active", None)
    if active is not None:
        return str(active).lower() == "low"
    return bool(getattr(sig, "active_low", False))


def estop_step(ask: Asker, active: Callable[[], bool | None], where: str, wait_s: float
               ) -> dict[str, Any]:
    """The e-stop, pressed then released: ``active()`` (the input turned by the cell's
    polarity; None: unknown) must follow the person's hands both ways."""
    was = active()
    if was:
        return {"ok": False, "error": "the e-stop reads active before it was pressed: release "
                                      "it, or check io.estop.active (high|low)", "where": where}
    ask("estop.press", f"Press the e-stop ({where}), then press Enter")
    pressed = wait_for(lambda: active() is True, wait_s)
    ask("estop.release", "Release (reset) the e-stop, then press Enter")
    released = wait_for(lambda: active() is False, wait_s)
    return {"ok": bool(pressed and released), "where": where, "pressed_seen": bool(pressed),
            "released_seen": bool(released)}


def motor_off(ctl: Any, axis: str, timeout: float) -> bool:
    """``_MOx`` read now (1: the amplifier is off), not the status cache: an e-stop a moment
    ago has turned it off whatever the last status poll said."""
    return ctl.submit(ctl.ask_number, f"MG _MO{axis.upper()}").result(timeout) == 1


def ensure_motor_on(ctl: Any, conv: Any, name: str, ask: Asker, timeout: float) -> bool:
    """Turn the motor of ``conv`` on only if the person says so (the first ``SH`` is
    theirs); False if they say no."""
    if not motor_off(ctl, conv.axis, timeout):
        return True
    if not ask.yes(f"servo.{name}", f"The motor of {name} (axis {conv.axis}) is off. Turn it "
                                    "on?"):
        return False
    wait(conv.servo(True), timeout)
    return True
