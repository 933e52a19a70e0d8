"""What the dashboard shows (thesis Figure 4-3), read from the cell on the tick thread.

``CellPanel.snapshot()`` returns plain data only — numbers, strings, tuples — so that the
bridge can publish it to the web thread without sharing anything mutable with the cell.
It also keeps what the page charts (parts/min over a rolling minute and queue length,
sampled every second) and the message window (events and faults, not the per-part ones).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from feeder_bt.behaviours.base import Event, Stats
from feeder_bt.control.bridge import Message, Snapshot
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.figures import figures, tree_text
from feeder_bt.control.operate import Limits, blackboard_speeds
from feeder_bt.core.vocabulary import MISS_KINDS, split
from feeder_bt.records.eventlog import ACCESS_KINDS

QUIET = frozenset({"located", "retrieved", "speeds"})   # too many for a message window
HISTORY_POINTS = 600           # 10 minutes at one sample a second
SAMPLE_S = 1.0
PPM_WINDOW_S = 60.0
MAX_MESSAGES = 200
SPEED_WORDS = {"horizontal_mm_s": "horizontal speed (mm/s)",
               "incline_pct": "inclined speed (% of horizontal)",
               "robot_speed_pct": "robot speed (%)"}


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def message_text(ev: Event) -> str:
    """One line for the message window."""
    d = ev.data
    if ev.kind == "state":
        return f"state {d.get('old')} \u2192 {d.get('new')}"
    if ev.kind == "fault":
        word = "miss" if d.get("kind") in MISS_KINDS else "fault"     # vocabulary.py
        return f"{word} ({d.get('kind', '?')}): {d.get('message', '')}"
    if ev.kind == "operator":
        who, action = d.get("user", "?"), d.get("action", "?")
        rest = {k: v for k, v in d.items() if k not in ("user", "action")}
        if action == "adjust":
            return f"{who}: auto-adjuster {'engaged' if rest.get('engaged') else 'disengaged'}"
        if action == "speeds":
            return f"{who}: set " + ", ".join(f"{SPEED_WORDS.get(k, k)} {_fmt(v)}"
                                              for k, v in rest.items())
        args = " ".join(f"{k}={_fmt(v)}" for k, v in rest.items())
        return f"{who}: {action}{' ' + args if args else ''}"
    if ev.kind in ACCESS_KINDS:
        rest = " ".join(f"{k}={_fmt(v)}" for k, v in d.items() if k != "user")
        return f"{ev.kind.replace('_', ' ')}: {d.get('user', '-')} {rest}".rstrip()
    if ev.kind == "golden_image":
        return f"golden image taken (frame {d.get('frame')})"
    return f"{ev.kind}: " + " ".join(f"{k}={_fmt(v)}" for k, v in d.items())


class CellPanel:
    """Follows one cell for the dashboard; every method runs on the tick thread."""

    def __init__(self, cell: Cell, limits: Limits, scenarios: Callable[[], list[str]],
                 t0: float | None = None) -> None:
        self.cell, self.limits, self.scenarios = cell, limits, scenarios
        self.t0 = cell.clock.now() if t0 is None else t0
        self._messages: deque[Message] = deque(maxlen=MAX_MESSAGES)
        self._msg_seq = 0
        self._history: deque[tuple[float, float, int]] = deque(maxlen=HISTORY_POINTS)
        self._fed: deque[tuple[float, int]] = deque()     # (t, cumulative fed) in the window
        self._fed_before = 0            # parts fed in earlier starts (stats reset at start)
        self._next_sample = self.t0
        self._last_part: dict[str, Any] | None = None
        self._stats: Stats | None = None
        self._bind(cell.stats)
        cell.listeners.append(lambda old, new: self._bind(cell.stats))

    # ------------------------------------------------------------------ events
    def _bind(self, stats: Stats) -> None:
        if stats is self._stats:
            return
        if self._stats is not None:
            self._fed_before += self._stats.total_retrieved
            if self._on_event in self._stats.listeners:
                self._stats.listeners.remove(self._on_event)
        for ev in stats.events:           # emitted before we heard of the new Stats
            self._on_event(ev)
        stats.listeners.append(self._on_event)
        self._stats = stats

    def _on_event(self, ev: Event) -> None:
        if ev.kind == "retrieved":
            self._last_part = {"type": ev.data.get("type"), "id": ev.data.get("id"),
                               "t": round(ev.t - self.t0, 2)}
        if ev.kind in QUIET:
            return
        self._msg_seq += 1
        self._messages.append(Message(self._msg_seq, round(ev.t - self.t0, 2), ev.kind,
                                      message_text(ev)))

    # ------------------------------------------------------------------ snapshot
    def _sample(self, now: float, fed_total: int, queue: int) -> None:
        if now < self._next_sample:
            return
        self._next_sample = now + SAMPLE_S
        self._fed.append((now, fed_total))
        while len(self._fed) > 2 and self._fed[1][0] <= now - PPM_WINDOW_S:
            self._fed.popleft()
        t_old, n_old = self._fed[0]
        ppm = (fed_total - n_old) * 60.0 / (now - t_old) if now > t_old else 0.0
        self._history.append((round(now - self.t0, 2), round(ppm, 2), queue))

    def snapshot(self) -> Snapshot:
        cell = self.cell
        f = figures(cell)
        now = cell.clock.now()
        s = cell.stats
        self._sample(now, self._fed_before + s.total_retrieved, int(f["queue"]))
        tree = cell.root if cell.root is not None else cell.feeding
        part = {CellState.STARTING: "set-up", CellState.STOPPING: "clean-up",
                CellState.FAULTING: "clean-up"}.get(cell.state, "feeding")
        running = cell.state in (CellState.STARTING, CellState.RUNNING, CellState.PAUSED)
        status: dict[str, Any] = {
            "state": cell.state.value,
            "scenario": cell.scenario.name if cell.scenario else None,
            "scenario_file": cell.scenario.path.stem if cell.scenario else None,
            "scenarios": self.scenarios(),
            "cell": cell.cell.name,
            "fault": cell.fault_reason,
            "up_time_s": round(now - self.t0, 2),
            "run_time_s": (round(now - s.started_at, 2)
                           if s.started_at is not None and running else None),
            "total_fed": s.total_retrieved,
            "fed_by_type": dict(s.retrieved),
            "last_part": self._last_part,
            "ppm": round(float(f["ppm"]), 2),
            "ppm_window": self._history[-1][1] if self._history else 0.0,
            "located": s.counts["located"],
            "missed": s.counts["missed"],
            "too_far": s.counts["too_far"],
            # parts placed turned or face-down: only a simulated cell can know (its world's
            # count, as in ``feeder report``); None on a real cell
            "misoriented": self._world_count("misoriented"),
            # parts worn past their max_passes: the simulated world's count too
            "scrapped": self._world_count("scrapped"),
            # faults (recovered so far) and misses apart: vocabulary.py
            "faults": sum(split(s.faults)[0].values()),
            "recovered": sum(s.recoveries.values()),
            "misses": sum(split(s.faults)[1].values()),
            "queue": int(f["queue"]),
            "speeds": blackboard_speeds(cell) if cell.ctx is not None else
            dict.fromkeys(("horizontal_mm_s", "incline_pct", "robot_speed_pct")),
            "hal": self._hal_speeds(),
            "auto_adjust": bool(cell.auto_adjust),
            "adjuster": cell.scenario.adjust.algorithm if cell.scenario else None,
            "limits": self.limits.as_dict(),
            "tree_part": part if tree is not None else None,
            "tree": tree_text(tree, "unicode") if tree is not None else "",
        }
        return status, tuple(self._history), tuple(self._messages)

    def _world_count(self, key: str) -> int | None:
        """A count only the simulated world can know (as ``report.parts`` has it); None
        on a real cell."""
        world = self.cell.hal.truth
        counts = getattr(world, "counts", None)
        return int(counts[key]) if counts is not None else None

    def _hal_speeds(self) -> dict[str, float | None]:
        """What the conveyors' controller reports (mm/s), not what the trees asked for."""
        out: dict[str, float | None] = {}
        for name in ("horizontal", "incline"):
            try:
                out[f"{name}_mm_s"] = round(float(self.cell.hal.conveyors[name].speed()), 2)
            except Exception:        # a HAL that cannot answer now: show nothing, keep going
                out[f"{name}_mm_s"] = None
        return out
