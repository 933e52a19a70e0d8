"""The part server's side of retrieval: robots ask for parts, the cell hands them out.

With a part server the robot is the master (docs/part-server.md): instead of the retrieve
tree commanding a robot, ``ServeRobots`` answers the robots' requests every tick. It
chooses parts exactly as ``NextPart`` does (the scenario's policy, the ``too_far`` check)
and keeps each part it hands out on record (``Desk.handed``) until the robot reports it
picked, placed, missed or released. A part never reported back is *expired* after a
time-out: by then it has passed ``too_far`` and gone round the return conveyor, so it is
counted as recirculated (a late report still counts it where the robot says it is).

The ``Desk`` outlives the feeding tree: requests that arrive while the cell is stopped or
paused are answered too (``serve_idle``), and the records survive a stop, so a robot that
finishes a pick during a stop can still report it.
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx
from feeder_bt.behaviours.keys import SPEEDS
from feeder_bt.behaviours.policies import gone_by
from feeder_bt.behaviours.retrieve import NextPart, count_retrieved
from feeder_bt.core.clock import Clock
from feeder_bt.core.model import belt_window
from feeder_bt.core.part_protocol import (
    USAGE,
    Offer,
    ProtocolError,
    Request,
    help_line,
    parse_request,
    status_line,
)
from feeder_bt.core.parts import Part

# ----------------------------------------------------------------------
# The part server's distrust of robots (docs/part-server.md, "Robots must be
# trusted"), as rules of the ``Desk`` below, tick thread only:
#
# - a robot is named by its connection (``NAME#N@HOST:PORT`` once it said who it is: one
#   robot across its connections; else the connection alone, ``robot_of``);
# - a robot whose parts expire unreported ``max_outstanding`` times in a row is cut off for
#   ``cut_off_s``, with a ``robot_cut_off`` fault for the operator;
# - on the simulated cell a ``PLACED`` the world did not see is a mismatch, not a part
#   retrieved (``verify_placed``, set by plant/adapters.py).

CUT_OFF_S = 600.0         # a robot whose parts expire unreported is refused this long


def robot_of(conn: Hashable) -> str:
    """The robot a connection name belongs to: ``NAME`` of ``NAME#N@HOST:PORT`` (a robot
    that said who it is); otherwise the connection itself (each on its own)."""
    text = str(conn)
    head = text.split("@", 1)[0]
    return head.split("#", 1)[0] if "#" in head else text


class TrustRules:
    """Mixed into ``Desk``: the attributes it sets (``max_outstanding``, ``cut_off_s``,
    ``unreported``, ``cut_until``, ``verify_placed``) and the rules on them."""

    max_outstanding: int
    cut_off_s: float
    unreported: Counter
    cut_until: dict[str, float]
    verify_placed: Callable[[Any], bool] | None
    handed: dict[int, Handed]
    counts: Counter
    ctx: Any
    clock: Any

    def _mismatch(self, rec: Handed, conn: Hashable) -> str:
        """A PLACED the simulated world did not see: not counted as retrieved."""
        pid = rec.part.id
        self.counts["mismatch"] += 1
        if self.ctx is not None:
            self.ctx.stats.count("placed_mismatch")
            self.ctx.stats.faults["placed_mismatch"] += 1
            self.ctx.stats.emit(self.clock.now(), "fault", kind="placed_mismatch", id=pid,
                                message=f"{conn}: reported part {pid} placed, but no "
                                        f"{rec.part.type} was placed")
        return (f"ERR PLACED {pid}: no {rec.part.type} was placed: counted as a mismatch, "
                "not as retrieved")

    def is_cut_off(self, robot: str) -> bool:
        """Any thread: is ``robot`` cut off now?"""
        until = self.cut_until.get(robot)
        return until is not None and self.clock.now() < until

    def _unreported(self, rec: Handed, now: float) -> None:
        """One more of a robot's parts expired unreported; enough in a row cut it off and
        raise a fault for the operator."""
        robot = robot_of(rec.owner)
        self.unreported[robot] += 1
        if self.unreported[robot] < self.max_outstanding or self.is_cut_off(robot):
            return
        self.cut_until[robot] = now + self.cut_off_s
        self.unreported.pop(robot, None)
        self.counts["cut_off"] += 1
        for r in list(self.handed.values()):        # what it still holds goes back
            if robot_of(r.owner) == robot and not r.picked:
                r.until = now
        if self.ctx is not None:
            self.ctx.stats.faults["robot_cut_off"] += 1
            self.ctx.stats.emit(now, "fault", kind="robot_cut_off", robot=robot,
                                message=f"robot {robot} took parts and never reported "
                                        f"them: refused for {self.cut_off_s:g} s")

PICK_GRACE_S = 5.0        # after a part passes too_far, before its record expires
PLACE_TIMEOUT_S = 30.0    # from PICKED to PLACED, before a held part's record expires
STATIONARY_S = 60.0       # a part on a belt that does not move: its pick time-out
ROBOT_IDLE_S = 30.0       # parts waiting and no robot asking this long: tell the operator
FORGET = 1000             # expired ids remembered for late reports
# MISSED id WHY: a first word naming a fault kind counts the miss under that kind
MISS_KINDS = {"servo_timeout": "servo_timeout", "servo": "servo_timeout",
              "comms_lost": "comms_lost", "dropped": "dropped", "missed_grab": "missed_grab"}


@dataclass
class Pending:
    """One request line from a robot, waiting for its answer.

    ``answer`` must not block: it is called on the tick thread (a TCP connection's thread
    waits for it; an in-process link keeps it). ``cancelled``: the robot went away."""

    conn: Hashable
    line: str
    answer: Callable[[str], None]
    request: Request | None = None
    until: float | None = None          # PART ... WAIT s: answer NONE after this time
    cancelled: bool = False


class Inbox:
    """Requests from any thread, drained by the tick thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: deque[Pending] = deque()

    def put(self, item: Pending) -> None:
        with self._lock:
            self._items.append(item)

    def drain(self) -> list[Pending]:
        with self._lock:
            out = list(self._items)
            self._items.clear()
            return out


@dataclass
class Handed:
    """A part handed to a robot and not yet reported back."""

    part: Part
    owner: Hashable
    t: float
    until: float                        # the record expires then
    picked: bool = False


# where a part handed out ends: handed_out = the sum of these + outstanding
LEDGER = ("placed", "missed", "released", "expired", "held_expired", "mismatch")


@dataclass
class DeskCounts:
    """What the desk did, for the report (``part_server``) and STATUS."""

    counts: Counter = field(default_factory=Counter)

    def as_dict(self, outstanding: int) -> dict[str, int]:
        keys = ("requests", "handed_out", "picked", "placed", "missed", "released",
                "expired", "held_expired", "late_reports", "refused", "mismatch",
                "over_limit", "cut_off")
        out = {**{k: int(self.counts[k]) for k in keys}, "outstanding": outstanding}
        # every part handed out ends in one of these, or is still out: 0 when the ledger
        # balances (docs/part-server.md)
        out["unaccounted"] = out["handed_out"] - outstanding - sum(out[k] for k in LEDGER)
        return out


class Desk(TrustRules):
    """The part server's records and answers; every method but ``inbox.put`` runs on the
    tick thread. ``status()`` gives the cell's side of a STATUS reply (state, scenario)."""

    def __init__(self, clock: Clock, status: Callable[[], dict[str, object]] | None = None,
                 pick_grace_s: float = PICK_GRACE_S,
                 place_timeout_s: float = PLACE_TIMEOUT_S) -> None:
        self.clock = clock
        self.status = status or (lambda: {})
        self.pick_grace_s, self.place_timeout_s = pick_grace_s, place_timeout_s
        self.inbox = Inbox()
        self.handed: dict[int, Handed] = {}
        self.expired: dict[int, Handed] = {}
        self.queues: dict[Hashable, deque[Pending]] = {}     # per robot, in order
        self.totals = DeskCounts()
        self.wanted: Counter[str] = Counter()
        self.ctx: Ctx | None = None          # the feeding run the records belong to
        self.last_request = clock.now()
        self.idle_told = False               # "no robot is asking" was told the operator
        self.chooser: ServeRobots | None = None
        # is a robot's connection still open? (the TCP server knows; in process: yes)
        self.alive: Callable[[Hashable], bool] = lambda conn: True
        # trust: at most this many parts with one robot and not yet reported;
        # a robot whose parts expire unreported that many times running is cut off
        self.max_outstanding = 4
        self.cut_off_s = CUT_OFF_S
        self.unreported: Counter[str] = Counter()    # per robot, since its last report
        self.cut_until: dict[str, float] = {}
        # the simulated cell: did the world see a part of this type placed? (None: trust)
        self.verify_placed: Callable[[Part], bool] | None = None

    @property
    def counts(self) -> Counter:
        return self.totals.counts

    def report(self) -> dict[str, int]:
        return self.totals.as_dict(len(self.handed))

    # ------------------------------------------------------------------ tick thread
    def serve_idle(self) -> None:
        """Answer requests while no feeding tree serves them (stopped, paused, fault)."""
        if self.chooser is None:
            self.serve()

    def serve(self) -> int:
        """Answer what arrived, keep waiting PART requests, expire old records. Each
        robot's requests are answered in the order it sent them: a PART that waits holds
        back what the same robot sent after it. Returns the number of answers given."""
        now = self.clock.now()
        for item in self.inbox.drain():
            if item.cancelled:
                continue
            self.counts["requests"] += 1
            self.queues.setdefault(item.conn, deque()).append(item)
            self.last_request = now
        answered = 0
        for conn, queue in list(self.queues.items()):
            while queue:
                item = queue[0]
                if item.cancelled:
                    queue.popleft()
                    continue
                reply = self._reply(item, now)
                if reply is None:
                    self.clock.wake_at(item.until or now)
                    break
                queue.popleft()
                item.answer(reply)
                answered += 1
            if not queue:
                del self.queues[conn]
        self._expire(now)
        return answered

    @property
    def waiting(self) -> int:
        """Robots whose PART request waits for a part."""
        return len(self.queues)

    def _reply(self, item: Pending, now: float) -> str | None:
        if item.request is None:
            try:
                item.request = parse_request(item.line)
            except ProtocolError as e:
                self.counts["refused"] += 1
                return f"ERR {e}"
        if item.request.command == "PART":
            if item.until is None:
                item.until = now + item.request.wait_s
            return self._part(item, now)
        return self._answer(item)

    def _part(self, item: Pending, now: float) -> str | None:
        """The answer to a PART request, or None to keep it waiting."""
        req = item.request
        assert req is not None
        ctx = self.ctx
        if req.part_type is not None and ctx is not None \
                and req.part_type not in ctx.scenario.parts:
            self.counts["refused"] += 1
            return (f"ERR PART: unknown part type {req.part_type!r} (one of: "
                    f"{', '.join(ctx.scenario.parts)})")
        robot = robot_of(item.conn)
        if self.is_cut_off(robot):
            self.counts["refused"] += 1
            return f"ERR PART: robot {robot} is cut off: parts handed to it were never reported"
        held = sum(1 for r in self.handed.values() if robot_of(r.owner) == robot)
        if held >= self.max_outstanding:
            self.counts["over_limit"] += 1
            self.counts["refused"] += 1
            return (f"ERR PART: robot {robot} holds {held} parts not yet reported (at most "
                    f"{self.max_outstanding}): report them first")
        chosen = None
        if self.chooser is not None:
            chosen = self.chooser.choose(req.part_type, req.within_s)
        if chosen is None:
            if item.until is not None and now < item.until:
                return None
            why = "empty" if self.chooser is not None else str(
                self.status().get("state", "stopped")).replace(" ", "_")
            return f"OK NONE {why}"
        part, offer = chosen
        left = offer.left_s if math.isfinite(offer.left_s) else STATIONARY_S
        until = now + min(left, STATIONARY_S) + self.pick_grace_s
        self.handed[part.id] = Handed(part, item.conn, now, until)
        self.clock.wake_at(until)
        self.counts["handed_out"] += 1
        for key in (part.type, "*"):               # the announced demand, served
            if self.wanted[key] > 0:
                self.wanted[key] -= 1
                break
        return offer.line()

    def _record(self, req: Request, conn: Hashable) -> tuple[Handed | None, str | None]:
        """The record a report is about, or the refusal."""
        pid = req.part_id
        assert pid is not None
        rec = self.handed.get(pid)
        if rec is None:
            late = self.expired.get(pid)
            if late is not None and self._owns(late, conn):
                return late, None
            self.counts["refused"] += 1
            return None, (f"ERR {req.command} {pid}: part {pid} was not handed to a robot "
                          "(or was already reported)")
        if not self._owns(rec, conn):
            self.counts["refused"] += 1
            return None, f"ERR {req.command} {pid}: part {pid} was handed to another robot"
        return rec, None

    def _owns(self, rec: Handed, conn: Hashable) -> bool:
        """The robot that took the part, on its connection; or the same host on a new
        connection once the old one has closed (a robot that reconnected after a crash
        reports what it did)."""
        if rec.owner == conn:
            return True
        host = _host(conn)
        if host is not None and host == _host(rec.owner) and not self.alive(rec.owner):
            rec.owner = conn
            return True
        return False

    def _answer(self, item: Pending) -> str:
        req = item.request
        assert req is not None
        cmd = req.command
        if cmd == "HELP":
            return help_line(req.topic)
        if cmd == "QUIT":
            return "OK BYE"
        if cmd == "STATUS":
            return self._status()
        if cmd == "PREPARE":
            return self._prepare(req)
        rec, refusal = self._record(req, item.conn)
        if rec is None:
            return refusal or f"ERR {USAGE[cmd]}"
        pid = rec.part.id
        now = self.clock.now()
        self.unreported.pop(robot_of(item.conn), None)     # it reports: it is honest
        late = pid not in self.handed
        if late and cmd in ("PICKED", "PLACED"):       # expired, then reported after all
            self.counts["held_expired" if rec.picked else "expired"] -= 1
            self.counts["late_reports"] += 1
            del self.expired[pid]
            self.handed[pid] = rec
        elif late:
            del self.expired[pid]                      # missed or released: it is gone
            self.counts["late_reports"] += 1
            return f"OK {cmd} {pid}"
        if cmd == "PICKED":
            rec.picked = True
            rec.until = now + self.place_timeout_s
            self.clock.wake_at(rec.until)
            self.counts["picked"] += 1
            return f"OK PICKED {pid}"
        del self.handed[pid]
        if cmd == "PLACED":
            if self.verify_placed is not None and not self.verify_placed(rec.part):
                return self._mismatch(rec, item.conn)
            if not rec.picked:
                self.counts["picked"] += 1
            self.counts["placed"] += 1
            if self.ctx is not None:
                count_retrieved(self.ctx, rec.part, robot=str(item.conn))
            total = self.ctx.stats.total_retrieved if self.ctx is not None else 0
            return f"OK PLACED {pid} {total}"
        if cmd == "MISSED":
            self.counts["missed"] += 1
            self._count_miss(rec, req.why, item.conn)
            return f"OK MISSED {pid}"
        # RELEASE
        if rec.picked:
            self.handed[pid] = rec
            self.counts["refused"] += 1
            return (f"ERR RELEASE {pid}: you reported part {pid} picked: place it "
                    "(PLACED) or report it MISSED")
        self.counts["released"] += 1
        if self.ctx is not None and self.chooser is not None:
            self.ctx.queue.put_front(rec.part)        # too far by now: dropped there
            return f"OK RELEASE {pid} queued"
        return f"OK RELEASE {pid} gone"

    def _count_miss(self, rec: Handed, why: str, conn: Hashable) -> None:
        ctx = self.ctx
        if ctx is None:
            return
        word = (why.split() or ["missed_grab"])[0].lower()
        unreachable = word.startswith(("unreach", "envelope", "reach"))
        kind = "envelope" if unreachable else MISS_KINDS.get(word, "missed_grab")
        ctx.stats.faults[kind] += 1
        ctx.stats.count({"envelope": "unreachable", "dropped": "dropped"}.get(kind, "missed"))
        ctx.stats.emit(ctx.now(), "fault", kind=kind, id=rec.part.id,
                       message=f"{conn}: {why or 'missed'}")

    def _prepare(self, req: Request) -> str:
        ctx = self.ctx
        if req.part_type is not None and ctx is not None \
                and req.part_type not in ctx.scenario.parts:
            self.counts["refused"] += 1
            return (f"ERR PREPARE: unknown part type {req.part_type!r} (one of: "
                    f"{', '.join(ctx.scenario.parts)})")
        key = req.part_type or "*"
        self.wanted[key] = req.count
        ready = 0
        if ctx is not None and self.chooser is not None:
            ready = (ctx.queue.count(req.part_type) if req.part_type else len(ctx.queue))
        return f"OK PREPARE {ready} {req.count}"

    def _status(self) -> str:
        ctx = self.ctx
        values: dict[str, object] = dict(self.status())
        values["queue"] = len(ctx.queue) if ctx is not None and self.chooser else 0
        values["handed"] = len(self.handed)
        values["retrieved"] = ctx.stats.total_retrieved if ctx is not None else 0
        if ctx is not None:
            enc = ctx.cell.encoder
            values["counts_per_mm"] = float(enc.counts_per_mm)
            values["encoder_bits"] = int(enc.robot_bits)
            values["tracking"] = int(ctx.scenario.retrieve.tracking)
            values["types"] = ",".join(ctx.scenario.parts)
        for k in LEDGER:
            values[k] = int(self.counts[k])
        values["wanted"] = int(sum(self.wanted.values()))
        return status_line(values)

    def _expire(self, now: float) -> None:
        for pid, rec in list(self.handed.items()):
            if now < rec.until:
                continue
            del self.handed[pid]
            self.expired[pid] = rec
            if len(self.expired) > FORGET:
                self.expired.pop(next(iter(self.expired)))
            held = rec.picked
            self.counts["held_expired" if held else "expired"] += 1
            self._unreported(rec, now)
            if self.ctx is not None:
                self.ctx.stats.count("unreported")
                self.ctx.stats.emit(now, "part_expired", id=pid, type=rec.part.type,
                                    robot=str(rec.owner), picked=held,
                                    message=("reported picked, never placed" if held else
                                             "handed out, never reported: recirculated"))


def _host(conn: Hashable) -> str | None:
    """The peer address of a TCP robot's connection name (``robot-N@HOST:PORT``)."""
    if not isinstance(conn, str) or "@" not in conn:
        return None
    return conn.split("@", 1)[1].rpartition(":")[0] or None


class ServeRobots(NextPart):
    """The serving branch's one leaf: RUNNING for ever, answering robots every tick.

    It is ``NextPart`` turned round: the same policy, ``too_far`` check and assembly
    sequence choose the part, but a robot's request starts the choice, and the part goes
    to the robot instead of to ``Pick``."""

    def __init__(self, name: str, ctx: Ctx, desk: Desk) -> None:
        super().__init__(name, ctx)
        self.desk = desk
        self.v_mm_s = 0.0
        self.hinted: float | None = None

    def initialise(self) -> None:
        self.desk.ctx, self.desk.chooser = self.ctx, self

    def terminate(self, new_status: Status) -> None:
        if self.desk.chooser is self:
            self.desk.chooser = None

    def update(self) -> Status:
        self.desk.ctx, self.desk.chooser = self.ctx, self
        self.desk.serve()
        self._watch_robots()
        n = len(self.desk.handed)
        self.feedback_message = f"{n} part(s) with robots, {self.desk.waiting} waiting"
        return Status.RUNNING

    def _watch_robots(self) -> None:
        """Parts are waiting and no robot has asked for ``ROBOT_IDLE_S``: a fault event for
        the operator (the cell feeds on; the parts recirculate), once, and a recovery
        event when a robot asks again."""
        desk, stats, now = self.desk, self.ctx.stats, self.ctx.now()
        quiet = now - desk.last_request
        if desk.idle_told and (quiet < ROBOT_IDLE_S or desk.queues):
            desk.idle_told = False
            stats.recovered(now, "robot_idle")
        elif not desk.idle_told and quiet >= ROBOT_IDLE_S and len(self.ctx.queue) \
                and not desk.queues and not desk.handed:
            desk.idle_told = True
            stats.faults["robot_idle"] += 1
            stats.emit(now, "fault", kind="robot_idle",
                       message=f"no robot has asked for a part for {quiet:.0f} s")
        elif not desk.idle_told and self.hinted != desk.last_request:
            self.hinted = desk.last_request           # one hint per quiet spell
            self.ctx.clock.wake_at(desk.last_request + ROBOT_IDLE_S)

    def enter_s(self, part: Part) -> float:
        """Seconds until the part's grip point is inside the robot's reach (0: it is)."""
        sp = self.ctx.cell.robot
        ox, oy, _ = self.ctx.scenario.parts[part.type].tool_offset
        bx, by = sp.base_mm
        y = part.y_mm + oy
        if abs(y - by) >= sp.reach_mm:
            return math.inf
        x_enter = max(bx - math.sqrt(sp.reach_mm ** 2 - (y - by) ** 2),
                      belt_window(self.ctx.cell)[0])
        x = self.x_now(part) + ox
        if x >= x_enter:
            return 0.0
        v = self.v_mm_s if self.ctx.scenario.retrieve.tracking else 0.0
        return (x_enter - x) / v if v > 0 else math.inf

    def choose(self, ptype: str | None, within_s: float | None) -> tuple[Part, Offer] | None:
        """Take the next part (of ``ptype``; reachable within ``within_s``) off the queue."""
        r = self.ctx.scenario.retrieve
        queue = self.ctx.queue
        if len(queue) == 0:
            return None
        self.v_mm_s = self.policy.belt_mm_s = float(self.bb.get(SPEEDS.HORIZONTAL))
        self.policy.robot_pct = float(self.bb.get(SPEEDS.ROBOT))
        lead = self.policy.belt_mm_s * self.policy.lead_s() if r.tracking else 0.0
        gone = queue.take(gone_by(self.ctx, self.x_now, lead))
        if gone:
            self.ctx.stats.count("too_far", len(gone))
        wanted = None if ptype is None else {ptype}
        kit = self.ctx.stats.kit
        if ptype is None and kit is not None:   # what the kit lacks, less what robots hold
            wanted = kit.wanted(Counter(h.part.type for h in self.desk.handed.values()))
        parts = [p for p in queue.peek_all() if wanted is None or p.type in wanted]
        if within_s is not None:
            enter = {p.id: self.enter_s(p) for p in parts}
            later = [t - within_s for t in enter.values() if within_s < t < math.inf]
            if later:               # a waiting request is worth a look when one comes near
                self.ctx.clock.wake_at(self.ctx.now() + min(later))
            parts = [p for p in parts if enter[p.id] <= within_s]
        part = self.policy.choose(parts, self.x_now)
        if part is None or not queue.remove(part.id):
            return None
        spec = self.ctx.scenario.parts[part.type]
        ox, oy, oz = spec.tool_offset
        ox, oy = ox + part.grip_dx_mm, oy + part.grip_dy_mm      # the grip offered
        v = self.v_mm_s if r.tracking else 0.0
        left = (r.too_far_mm - self.x_now(part)) / v if v > 0 else math.inf
        return part, Offer(part.id, part.type, part.x_mm + ox, part.y_mm + oy, oz,
                           part.angle_deg, part.latch, max(0.0, left))
