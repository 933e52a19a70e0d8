"""Selection-aware robot yardsticks: what the robot could do with the parts the run
really had, not with a part always waiting at the best corner of its window.

``robot_bound_ppm`` (``report.robot_bound``) is 60 over the shortest pick-and-place cycle
anywhere in the pick window: the corner case, which no part may ever offer, and a true
bound. Two rates closer to a run (yardsticks, not bounds: each moves with the run's own
setting and picks, and the report never takes either for its ceiling; the ``_bound``
in their keys is historical), from the simulated world's record of it (``sim/passlog.py``), priced
with the world's own arm (a SCARA, ``feeder_bt.robot.scara``):

- ``mean_bound``: 60 over the mean cycle (place pose → pick → place pose, with settle,
  grip and release) over where the run's robot really picked: the rate at which this
  run's picks could have been made back to back;
- ``selection_bound``: a replay of the run's parts under a robot that never waits for
  vision or a decision: each time it is free it takes, of the parts that passed within
  reach (and could be picked: lying pickable and singulated, or picked by the run), the
  one with the shortest cycle from where it is (nearest first), intercepting it on the
  belt as recorded; parts move with the belt as it really moved. Its parts per minute of
  feeding is what nearest-first picking could have placed from this run's supply. It is
  not an optimum (a lookahead policy may beat nearest-first on a stream), so it is a
  yardstick, not a proof: a run may place more.
  With a kit, the replay takes only the types the kit wants next (``KitTracker``), and
  the kits it completes are the report's ``kits.selection_bound_kpm``.

A part picked in the replay is gone for the rest of its pass; a part the run's robot
picked stays available to the replay until it leaves the reach. A pass the run's robot
left to recirculate comes back as a new pass, as it did. Where placed parts go back to
the hopper (the closed loop), that later pass stands in for the replay's own placed part
coming back the same way, so the replay may take it again. Where placed parts leave the
cell (a supply plan's ``ship_placed``), nothing the replay placed comes back: none of that
part's passes is offered to it again, and it never places more parts than came. It sees a
part the run placed only on the passes the run gave it, so a run that chose better than
nearest-first can place more than the replay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.policy.kits import KitTracker
from feeder_bt.robot.model import RobotModel


@dataclass
class Pricing:
    """What a cycle costs beside the moves, and where each part type goes."""

    model: RobotModel
    speed_pct: float
    fixed_s: float                                # overheads, settle, grip, release
    hold_s: float                                 # arrival to grip (settle + grip)
    places: dict[str, tuple[float, float]]
    offsets: dict[str, tuple[float, float]]
    x_hi: float                                   # too_far (or the belt's end)
    belt_end: float

    @classmethod
    def of(cls, model: RobotModel, cell: CellSpec, scenario: Scenario) -> Pricing:
        r, sp = scenario.retrieve, cell.robot
        settle = sp.track_settle_s if r.tracking else 0.0
        belt = cell.conveyors["horizontal"]
        return cls(model, r.robot_speed_pct,
                   2 * sp.command_overhead_s + settle + sp.grip_s + sp.release_s,
                   settle + sp.grip_s,
                   {n: (p.place.x, p.place.y) for n, p in scenario.parts.items()},
                   {n: (p.tool_offset[0], p.tool_offset[1]) for n, p in scenario.parts.items()},
                   min(r.too_far_mm, belt.length_mm), belt.length_mm)


def mean_bound(pricing: Pricing, picks: list[tuple[float, float, float, str]]
               ) -> tuple[float, float] | None:
    """(mean cycle s, parts/min) over the run's real pick points; None without picks."""
    if not picks:
        return None
    cycles = []
    for ptype in sorted({p[3] for p in picks}):
        xs = np.array([p[1] for p in picks if p[3] == ptype])
        ys = np.array([p[2] for p in picks if p[3] == ptype])
        place = pricing.places.get(ptype)
        if place is None:
            continue
        there = pricing.model.arch_times_from(place, xs, ys, pricing.speed_pct)
        cycles.append(2.0 * there + pricing.fixed_s)     # a move's time is symmetric
    if not cycles:
        return None
    mean = float(np.concatenate(cycles).mean())
    return mean, 60.0 / mean


def selection_bound(pricing: Pricing, log, start: tuple[float, float], t_end: float,
                    kit: KitTracker | None = None, placed_leave: bool = False) -> int:
    """Parts a nearest-first robot places from the run's passes by ``t_end`` (see the
    module); ``log`` is the world's ``PassLog``. With ``kit`` (a fresh ``KitTracker``) the
    robot takes only the types the kit wants next, as the retrieve tree does, and the
    tracker counts the kits it completes. ``placed_leave``: placed parts leave the cell
    (``World.ship_placed``), so a part the replay placed never comes to it again."""
    bt = np.asarray(log.belt_t)
    bp = np.maximum.accumulate(np.asarray(log.belt_pos))   # a reversal never un-passes
    t_on = np.asarray(log.t_on)
    n = len(t_on)
    if n == 0 or len(bt) == 0:
        return 0
    x0 = np.asarray(log.x0)
    pid = np.asarray(log.pid)
    gone: set[int] = set()         # parts the replay placed that never come back
    types = log.types
    ox = np.array([pricing.offsets.get(tp, (0.0, 0.0))[0] for tp in types])
    oy = np.array([pricing.offsets.get(tp, (0.0, 0.0))[1] for tp in types])
    y = np.asarray(log.y) + oy
    usable = np.asarray(log.usable, dtype=bool)
    place_x = np.array([pricing.places.get(tp, start)[0] for tp in types])
    place_y = np.array([pricing.places.get(tp, start)[1] for tp in types])
    spec = pricing.model.spec
    bx, by = spec.base_mm
    dy = np.abs(y - by)
    x_enter = np.where(dy < spec.reach_mm,
                       bx - np.sqrt(np.maximum(spec.reach_mm ** 2 - dy ** 2, 0.0)), np.inf)
    order = np.argsort(t_on, kind="stable")

    def pos(t: np.ndarray | float) -> np.ndarray:
        return np.interp(t, bt, bp)

    def time_at(p: np.ndarray) -> np.ndarray:
        """When the belt first reaches position ``p`` (inf: never in the record)."""
        i = np.searchsorted(bp, p, side="left")
        out = np.full(np.shape(p), np.inf)
        ok = i < len(bp)
        out[ok] = bt[np.minimum(i[ok], len(bt) - 1)]
        return out

    t = float(bt[0])
    here = start
    done = 0
    nxt = 0                        # next pass (in order of landing) not yet on the belt
    active = np.zeros(0, dtype=int)
    while t < t_end:
        while nxt < n and t_on[order[nxt]] <= t:
            if usable[order[nxt]] and int(pid[order[nxt]]) not in gone:
                active = np.append(active, order[nxt])
            nxt += 1
        if active.size:
            p_now = float(pos(t))
            x_now = x0[active] + p_now + ox[active]
            alive = (x_now - ox[active] < pricing.belt_end) & (x_now <= pricing.x_hi)
            active, x_now = active[alive], x_now[alive]
        if active.size:
            ya = y[active]
            x_arr = x_now
            move = np.zeros(active.size)
            for _ in range(3):                      # intercept the moving part
                move = pricing.model.arch_times_from(here, x_arr, ya, pricing.speed_pct)
                x_arr = x_now + (pos(t + move) - p_now)
            x_grip = x_now + (pos(t + move + pricing.hold_s) - p_now)
            ok = (pricing.model.reachable_mask(x_arr, ya)
                  & pricing.model.reachable_mask(x_grip, ya) & (x_grip <= pricing.x_hi))
            if kit is not None:
                wanted = kit.wanted()
                ok &= np.fromiter((types[i] in wanted for i in active.tolist()), bool,
                                  active.size)
            if ok.any():
                idx = np.flatnonzero(ok)
                sel = active[idx]
                back = _moves_to_places(pricing, x_grip[idx], ya[idx], place_x[sel],
                                        place_y[sel])
                cycle = move[idx] + back + pricing.fixed_s
                j = int(np.argmin(cycle))
                t += float(cycle[j])
                if t <= t_end:
                    done += 1
                    if kit is not None:
                        kit.placed(types[sel[j]])
                here = (float(place_x[sel[j]]), float(place_y[sel[j]]))
                taken = int(pid[sel[j]])
                active = np.delete(active, idx[j])
                if placed_leave:           # it never comes again, nor does a pass under way
                    gone.add(taken)
                    active = active[pid[active] != taken]
                continue
        # nothing to take now: wait for the next landing or a part coming into reach
        waits = [t_on[order[nxt]]] if nxt < n else []
        if active.size:
            upstream = active[x_now < x_enter[active]]
            if upstream.size:
                waits.append(float(time_at(x_enter[upstream] - x0[upstream]
                                           - ox[upstream]).min()))
        t_next = min(waits) if waits else math.inf
        if not math.isfinite(t_next) and not active.size:
            break
        t = max(t + 0.005, t_next if math.isfinite(t_next) else t + 0.05)
    return done


def _moves_to_places(pricing: Pricing, x: np.ndarray, y: np.ndarray, px: np.ndarray,
                     py: np.ndarray) -> np.ndarray:
    """Each grip point's move to its own type's place pose."""
    out = np.empty(x.size)
    for p in set(zip(px.tolist(), py.tolist(), strict=True)):
        m = (px == p[0]) & (py == p[1])
        out[m] = pricing.model.arch_times_from(p, x[m], y[m], pricing.speed_pct)
    return out
