"""Accounting by identity: every simulated part is always in exactly one place.

Each part carries its own record (``SimPart.where``); every move between places checks that
record against the place it leaves and keeps a tally of the records by place. Every step
compares the tally with the containers' sizes (eight integers), and a full audit matches
each part's record against the containers one by one whenever they disagree, every
``AUDIT_EVERY`` steps and at every census. A part found nowhere is *lost*, one found in two
places *duplicated*: each is named with its id and last known place (``problems``),
counted, and told to the ``listeners`` — the run then ends with its own exit code
(docs/faults.md).

``PartAccounting`` is a part of ``World`` (``world.py``), kept here by concept; it reads the
world's containers and keeps its own tally.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

PLACES = ("hopper", "incline", "horizontal", "return", "gripper", "placed", "shipped",
          "scrapped")
AUDIT_EVERY = 32                # steps between full audits when the tallies agree


@dataclass
class SimPart:
    """One simulated part: its own record of where it is (``where``, one of ``PLACES``),
    and its pose and contacts while on the belt."""

    id: int
    type: str
    pose: str = ""
    pickable: bool = False
    where: str = "hopper"
    outline: np.ndarray | None = None
    radius: float = 0.0
    p_release: float = 0.0      # incline position at release
    x0: float = 0.0             # belt-frame x minus horizontal belt position at landing
    y: float = 0.0
    angle: float = 0.0
    touching: set[int] = field(default_factory=set)
    held_error_deg: float = 0.0
    # settling after a landing (imperfect.py): the rest pose is (x0, y); until settle_end
    # the part is still sliding towards it, short of it by slide * (1 - s)^2
    slide: tuple[float, float] = (0.0, 0.0)
    settle_t0: float = 0.0
    settle_end: float = -math.inf
    passes: int = 0             # times it has fallen off the belt's end (wear)
    slip_v: float = 0.0         # sliding on the belt: its speed less the belt's (slip.py)

    @property
    def singulated(self) -> bool:
        return not self.touching


class PartAccounting:
    """The world's census and audit of its parts by identity (a part of ``World``)."""

    # the world's containers, which it reads (``World.__init__`` makes them)
    parts: dict[int, SimPart]
    hopper: deque[int]
    on_incline: deque[int]
    on_horizontal: dict[int, SimPart]
    returning: list[tuple[float, int]]
    placed: list[tuple[float, int]]
    gripper: int | None
    shipped: list[int]
    scrapped: list[int]
    total: int
    t: float

    def _start_accounting(self) -> None:
        """Every part starts in the hopper; no problem reported yet."""
        self.tally: Counter[str] = Counter({"hopper": self.total})
        self.problems: list[dict] = []          # every part lost or duplicated, named
        self.reported: set[tuple[str, int]] = set()
        self.listeners: list[Callable[[dict], None]] = []
        self._steps = 0
        self._audit_due = False

    def _relocate(self, part: SimPart, src: str, dst: str) -> None:
        """Move a part's own record from ``src`` to ``dst``. A record that does not say
        ``src`` means the containers and the records disagree: audit at once."""
        if part.where != src:
            self._report([{"kind": "misrecorded", "id": part.id, "type": part.type,
                           "last_place": part.where, "places": [src]}])
            self._audit_due = True
        self.tally[part.where] -= 1
        self.tally[dst] += 1
        part.where = dst

    def _sizes(self) -> dict[str, int]:
        return {
            "hopper": len(self.hopper),
            "incline": len(self.on_incline),
            "horizontal": len(self.on_horizontal),
            "return": len(self.returning),
            "gripper": 0 if self.gripper is None else 1,
            "placed": len(self.placed),
            "shipped": len(self.shipped),
            "scrapped": len(self.scrapped),
        }

    def census(self) -> dict[str, int]:
        self.audit()
        return self._sizes()

    def check_accounting(self) -> None:
        """Every step: the records' tally against the containers' sizes (cheap); a full
        audit, part by part, when they disagree and every ``AUDIT_EVERY`` steps."""
        self._steps += 1
        t = self.tally
        if (self._audit_due or self._steps % AUDIT_EVERY == 0
                or len(self.hopper) != t["hopper"] or len(self.on_incline) != t["incline"]
                or len(self.on_horizontal) != t["horizontal"]
                or len(self.returning) != t["return"] or len(self.placed) != t["placed"]
                or len(self.shipped) != t["shipped"] or len(self.scrapped) != t["scrapped"]
                or (self.gripper is not None) != t["gripper"]):
            self.audit()

    def _containers(self) -> Iterator[tuple[str, Iterable[int]]]:
        yield "hopper", self.hopper
        yield "incline", self.on_incline
        yield "horizontal", self.on_horizontal.keys()
        yield "return", (pid for _, pid in self.returning)
        yield "gripper", () if self.gripper is None else (self.gripper,)
        yield "placed", (pid for _, pid in self.placed)
        yield "shipped", self.shipped
        yield "scrapped", self.scrapped

    def audit(self) -> list[dict]:
        """Match every part against the containers by identity; name each part that is
        in no place (lost) or in more than one (duplicated, or an id nobody made). Returns
        the problems found for the first time; the tallies are then taken from the
        containers so that one problem is reported once."""
        self._audit_due = False
        found: dict[int, list[str]] = {}
        for place, ids in self._containers():
            for pid in ids:
                found.setdefault(pid, []).append(place)
        new: list[dict] = []
        for pid, part in self.parts.items():
            places = found.get(pid)
            if not places:
                new.append({"kind": "lost", "id": pid, "type": part.type,
                            "last_place": part.where})
            elif len(places) > 1:
                new.append({"kind": "duplicated", "id": pid, "type": part.type,
                            "places": places})
            elif places[0] != part.where:       # one place, but its record says another
                new.append({"kind": "misrecorded", "id": pid, "type": part.type,
                            "last_place": part.where, "places": places})
                part.where = places[0]
        for pid in found.keys() - self.parts.keys():
            new.append({"kind": "duplicated", "id": pid, "type": None, "places": found[pid]})
        new = self._report(new)
        if new or self._tally_off():
            self.tally = Counter(self._sizes())
        return new

    def _report(self, problems: list[dict]) -> list[dict]:
        """Record and tell each problem not reported before; returns those."""
        new = [p for p in problems if (p["kind"], p["id"]) not in self.reported]
        for p in new:
            p["t"] = round(self.t, 3)
            self.reported.add((p["kind"], p["id"]))
            self.problems.append(p)
            for fn in self.listeners:
                fn(p)
        return new

    def _tally_off(self) -> bool:
        sizes = self._sizes()
        return any(self.tally[k] != v for k, v in sizes.items())

    def lost(self) -> int:
        return sum(1 for p in self.problems if p["kind"] == "lost")

    def duplicated(self) -> int:
        return sum(1 for p in self.problems if p["kind"] == "duplicated")

    @property
    def broken(self) -> bool:
        """A part was lost or duplicated: the world can no longer be trusted."""
        return bool(self.problems)
