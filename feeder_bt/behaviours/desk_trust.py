"""The part server's distrust of robots (issue 28; docs/part-server.md, "Robots must be
trusted"), as rules of the ``Desk`` (behaviours/serve.py), tick thread only:

- a robot is named by its connection (``NAME#N@HOST:PORT`` once it said who it is: one
  robot across its connections; else the connection alone, ``robot_of``);
- a robot whose parts expire unreported ``max_outstanding`` times in a row is cut off for
  ``cut_off_s``, with a ``robot_cut_off`` fault for the operator;
- on the simulated cell a ``PLACED`` the world did not see is a mismatch, not a part
  retrieved (``verify_placed``, set by plant/adapters.py).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Hashable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from feeder_bt.behaviours.desk import Handed

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
