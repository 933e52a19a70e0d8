"""The operator's commands, executed on the tick thread (called from ``Bridge.pump``).

Each command checks everything before it changes anything: a bad value or a command that
does not fit the cell's state is refused with the reason and leaves the cell as it was.
Accepted commands are logged as ``operator`` events (message window, event log, report).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from feeder_bt.config import load_scenario
from feeder_bt.control.bridge import Command, Outcome
from feeder_bt.control.cell import Cell, CellCommandError, CellState
from feeder_bt.core.errors import FeederError
from feeder_bt.core.model import CellSpec
from feeder_bt.records.eventlog import ACCESS_KINDS

SPEED_KEYS = ("horizontal_mm_s", "incline_pct", "robot_speed_pct")
PCT_MAX = 200.0
SIMPLE = {"start": "start", "stop": "stop", "pause": "pause", "resume": "resume",
          "reset": "reset"}
COMMANDS = (*SIMPLE, "load", "speeds", "adjust")
MAX_AUDIT = 1000
MAX_NUMBER_CHARS = 32          # a speed given as text: longer is refused before conversion
# Physical floors: below them a speed is not a working speed but a stopped
# machine (pause the cell instead), and 1e-300 would only hide a mistake. The V+ speed
# factor is a percentage of full speed, 100 normal (V+ Operating System Reference Guide,
# SPEED monitor command); its lower bound here is ours: check at commissioning.
MIN_ROBOT_PCT = 1.0
MIN_BELT_MM_S = 1.0
MIN_INCLINE_PCT = 1.0          # or exactly 0: the incline stopped


@dataclass(frozen=True)
class Limits:
    """What an operator may set, from the cell description (and the scenario rules)."""

    horizontal_max_mm_s: float
    incline_max_mm_s: float
    incline_pct_max: float = PCT_MAX
    robot_pct_max: float = PCT_MAX

    @classmethod
    def of(cls, spec: CellSpec) -> Limits:
        return cls(spec.conveyors["horizontal"].max_mm_s, spec.conveyors["incline"].max_mm_s)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _num(v: float) -> str:
    return f"{v:g}"


def parse_speeds(args: Mapping[str, Any], limits: Limits, current: Mapping[str, float],
                 adjuster_max_mm_s: float | None = None) -> dict[str, float]:
    """The speeds in ``args``, checked against ``limits``; FeederError with the reason.

    ``current`` holds the speeds now (an incline percentage is checked against the
    horizontal speed it will apply to); ``adjuster_max_mm_s`` is how fast an engaged
    auto-adjuster may still drive the horizontal belt.
    """
    unknown = sorted(set(args) - set(SPEED_KEYS))
    if unknown:
        raise FeederError(f"unknown speed {unknown[0]!r} (one of: {', '.join(SPEED_KEYS)})")
    if not args:
        raise FeederError(f"no speed given (one of: {', '.join(SPEED_KEYS)})")
    out: dict[str, float] = {}
    for key, raw in args.items():
        if isinstance(raw, bool) or not isinstance(raw, int | float | str):
            raise FeederError(f"{key}: must be a number, got {str(raw)[:40]!r}")
        if isinstance(raw, str) and len(raw) > MAX_NUMBER_CHARS:
            raise FeederError(f"{key}: must be a number of at most {MAX_NUMBER_CHARS} "
                              "characters")
        if isinstance(raw, str) and not raw.isascii():     # float() reads "١٠٠" as 100
            raise FeederError(f"{key}: must be a number in ASCII digits, got {raw[:40]!r}")
        try:
            v = float(raw)
        except ValueError:
            raise FeederError(f"{key}: must be a number, got {str(raw)[:40]!r}") from None
        except OverflowError:                 # an integer of 400 digits
            raise FeederError(f"{key}: must be a finite number") from None
        if not math.isfinite(v):
            raise FeederError(f"{key}: must be a finite number, got {raw!r}")
        out[key] = v
    h = out.get("horizontal_mm_s", float(current.get("horizontal_mm_s", 0.0)))
    pct = out.get("incline_pct", float(current.get("incline_pct", 0.0)))
    if "horizontal_mm_s" in out:
        if h < MIN_BELT_MM_S:
            raise FeederError(f"horizontal speed must be at least {_num(MIN_BELT_MM_S)} mm/s, "
                              f"got {_num(h)} (pause the cell to stop the belts)")
        if h > limits.horizontal_max_mm_s:
            raise FeederError(f"horizontal speed {_num(h)} mm/s is above the horizontal "
                              f"conveyor's max_mm_s {_num(limits.horizontal_max_mm_s)}")
    if "incline_pct" in out and not (pct == 0 or MIN_INCLINE_PCT <= pct
                                     <= limits.incline_pct_max):
        raise FeederError(f"incline speed must be 0, or {_num(MIN_INCLINE_PCT)}-"
                          f"{_num(limits.incline_pct_max)} % of the horizontal speed, got "
                          f"{_num(pct)}")
    if "robot_speed_pct" in out:
        r = out["robot_speed_pct"]
        if not MIN_ROBOT_PCT <= r <= limits.robot_pct_max:
            raise FeederError(f"robot speed must be {_num(MIN_ROBOT_PCT)}-"
                              f"{_num(limits.robot_pct_max)} %, got {_num(r)}")
    belts = "horizontal_mm_s" in out or "incline_pct" in out
    for top, why in ((h, ""), (adjuster_max_mm_s, " (the engaged auto-adjuster may drive "
                                                   "the horizontal belt that fast)")):
        if belts and top is not None and top * pct / 100.0 > limits.incline_max_mm_s + 1e-9:
            raise FeederError(f"incline {_num(pct)} % of {_num(top)} mm/s = "
                              f"{_num(top * pct / 100.0)} mm/s is above the incline "
                              f"conveyor's max_mm_s {_num(limits.incline_max_mm_s)}{why}")
    return out


def blackboard_speeds(cell: Cell) -> dict[str, float | None]:
    """The speeds the cell's trees follow now (None before the first start)."""
    return cell.speeds()


def scenario_files(folder: Path) -> dict[str, Path]:
    """The scenarios an operator may switch to: the ``*.yaml`` files of one folder."""
    try:
        return {p.stem: p for p in sorted(folder.glob("*.yaml")) if p.is_file()}
    except OSError:
        return {}


class CellOps:
    """Executes operator commands on the cell; tick thread only."""

    def __init__(self, cell: Cell, scenarios_dir: Path, cell_file: Path) -> None:
        self.cell = cell
        self.scenarios_dir, self.cell_file = Path(scenarios_dir), Path(cell_file)
        self.limits = Limits.of(cell.cell)
        self.scenarios = scenario_files(self.scenarios_dir)
        self.audit: list[dict[str, Any]] = []       # accepted commands, for the report
        self.dropped = 0
        self.access: dict[str, int] = {}            # access events by kind, for the report

    def execute(self, cmd: Command) -> Outcome:
        """Run one command; every refusal says why and changes nothing."""
        name, args = cmd.name, dict(cmd.args)
        if name == "note":                          # login, logout, control: audit only
            self._log(cmd.user, str(args.get("action", "?")), {})
            return Outcome.done("noted")
        if name == "access":                        # a refusal or lock-out: the event log
            kind = args.pop("kind", None)
            if kind not in ACCESS_KINDS:
                return Outcome.refused(f"unknown access event {kind!r}", 400)
            self.cell.stats.emit(self.cell.clock.now(), kind, user=cmd.user, **args)
            self.access[kind] = self.access.get(kind, 0) + 1
            return Outcome.done("recorded")
        if name in SIMPLE:
            if args:
                return Outcome.refused(f"{name} takes no arguments", 400)
            return self._simple(cmd.user, name)
        if name == "load":
            return self._load(cmd.user, args)
        if name == "speeds":
            return self._speeds(cmd.user, args)
        if name == "adjust":
            return self._adjust(cmd.user, args)
        return Outcome.refused(f"unknown command {name!r} (one of: {', '.join(COMMANDS)})", 400)

    # ------------------------------------------------------------------ commands
    def _simple(self, user: str, name: str) -> Outcome:
        cell = self.cell
        if name == "start" and cell.state is CellState.FAULT:
            return Outcome.refused("refused: the cell is in FAULT; reset it first "
                                   f"({cell.fault_reason})")
        if name == "stop" and cell.state in (CellState.STOPPED, CellState.STOPPING,
                                             CellState.FAULT, CellState.FAULTING):
            return Outcome.refused(f"refused: nothing to stop, the cell is {cell.state.value}")
        try:
            getattr(cell, SIMPLE[name])()
        except CellCommandError as e:
            return Outcome.refused(f"refused: {e}")
        self._log(user, name, {})
        return Outcome.done(f"{name}: the cell is {cell.state.value}")

    def _load(self, user: str, args: dict[str, Any]) -> Outcome:
        name = args.get("scenario")
        if set(args) != {"scenario"} or not isinstance(name, str):
            return Outcome.refused("load needs {\"scenario\": NAME}", 400)
        if self.cell.state not in (CellState.STOPPED, CellState.FAULT):
            return Outcome.refused(f"refused: stop the cell before switching scenario (it is "
                                   f"{self.cell.state.value})")
        self.scenarios = scenario_files(self.scenarios_dir)
        path = self.scenarios.get(name)
        if path is None:                      # no server path in what a client is told
            return Outcome.refused(f"no scenario {name[:64]!r} (one of: "
                                   f"{', '.join(self.scenarios) or 'none'})", 400)
        # the run's scenario again: with the overlay it was run with (feeder run --overlay)
        now = self.cell.scenario
        overlay = (now.overlay_path if now is not None and now.overlay_path is not None
                   and Path(now.path).resolve() == Path(path).resolve() else None)
        try:
            scenario, _ = load_scenario(path, self.cell_file, overlay=overlay)
            self.cell.load(scenario)
        except CellCommandError as e:
            return Outcome.refused(f"refused: {self._no_paths(str(e))}")
        except FeederError as e:              # a YAML mistake: FILE:LINE: key: what
            return Outcome.refused(f"cannot load: {self._no_paths(str(e))}", 400)
        self._log(user, "load", {"scenario": name, **({"overlay": overlay.name} if overlay
                                                       else {})})
        return Outcome.done(f"scenario {scenario.name} loaded"
                            + (f" with its overlay {overlay.name}" if overlay else ""))

    def _speeds(self, user: str, args: dict[str, Any]) -> Outcome:
        cell = self.cell
        if cell.state not in (CellState.STARTING, CellState.RUNNING, CellState.PAUSED):
            return Outcome.refused("refused: speeds can be set while the cell runs or is "
                                   f"paused (it is {cell.state.value}); start it first")
        current = {k: v for k, v in blackboard_speeds(cell).items() if v is not None}
        try:
            speeds = parse_speeds(args, self.limits, current, self._adjuster_max())
        except FeederError as e:
            return Outcome.refused(str(e), 400)
        cell.set_speeds(**speeds)
        self._log(user, "speeds", speeds)
        text = ", ".join(f"{k} {_num(v)}" for k, v in speeds.items())
        note = ""
        if "horizontal_mm_s" in speeds and getattr(cell, "auto_adjust", False):
            note = "; the auto-adjuster is engaged and may change it (disengage it to hold)"
        return Outcome.done(f"speeds set: {text}{note}")

    def _adjust(self, user: str, args: dict[str, Any]) -> Outcome:
        engaged = args.get("engaged")
        if set(args) != {"engaged"} or not isinstance(engaged, bool):
            return Outcome.refused("adjust needs {\"engaged\": true|false}", 400)
        self.cell.set_auto_adjust(engaged)
        self._log(user, "adjust", {"engaged": engaged})
        return Outcome.done("auto-adjuster " + ("engaged" if engaged else "disengaged: the "
                                                "speeds stay where the operator puts them"))

    # ------------------------------------------------------------------ helpers
    def _no_paths(self, text: str) -> str:
        """A message for a client: the controller's folders replaced by file names."""
        for folder in sorted({str(self.scenarios_dir.resolve()), str(self.scenarios_dir),
                              str(self.cell_file.resolve().parent),
                              str(self.cell_file.parent)}, key=len, reverse=True):
            if folder not in ("", "."):
                text = text.replace(folder + "/", "").replace(folder, "")
        return text

    def _adjuster_max(self) -> float | None:
        ctx = self.cell.ctx
        if not getattr(self.cell, "auto_adjust", False) or ctx is None or ctx.adjuster is None:
            return None
        params = getattr(ctx.adjuster, "params", None) or {}
        v = params.get("max_mm_s")
        return float(v) if isinstance(v, int | float) else None

    def _log(self, user: str, action: str, args: dict[str, Any]) -> None:
        t = self.cell.clock.now()
        self.cell.stats.emit(t, "operator", user=user, action=action, **args)
        if len(self.audit) < MAX_AUDIT:
            self.audit.append({"t": round(t, 3), "user": user, "action": action, **args})
        else:
            self.dropped += 1

    def report(self) -> dict[str, Any]:
        """The report's ``operator`` section: what operators did, in order."""
        return {"commands": list(self.audit), "commands_not_listed": self.dropped,
                "access": dict(sorted(self.access.items()))}
