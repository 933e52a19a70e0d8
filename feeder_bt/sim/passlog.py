"""What the selection-aware robot bounds need from a simulated run: the belt's
motion, every pass of a part along the horizontal belt, and where the robot picked.

A pass starts when a part lands on the horizontal belt (off the incline, or dropped by the
robot): its belt-frame x (``x0``: the cell x is ``x0`` plus the belt's position), its y, its
type, and whether the robot could take it (lying pickable and touching nothing when it
came to rest; a part the run's robot did pick is marked so too, whatever it was at
landing). The belt's position is sampled at the world's steps, at most one in
``SAMPLE_S`` of virtual time; a fast run that skips idle ticks steps more seldom (lenses:
about one sample in 0.18 s), and the replay interpolates linearly: up to about 13 mm off in
the middle of a 0.27 s speed ramp, exact at constant speed. The report replays picking over
this record (``feeder_bt.analysis.robot_bounds``); nothing here is seen by the controller.
"""

from __future__ import annotations

from array import array

SAMPLE_S = 0.02


class PassLog:
    """The record; ``World`` fills it (``world.passlog``)."""

    def __init__(self, t0: float, pos0: float) -> None:
        self.belt_t = array("d", [t0])
        self.belt_pos = array("d", [pos0])
        self.next_t = t0 + SAMPLE_S
        self.t_on = array("d")
        self.pid = array("q")                    # the part's id: its passes share it
        self.x0 = array("d")
        self.y = array("d")
        self.types: list[str] = []
        self.usable: list[bool] = []
        self._current: dict[int, int] = {}       # part id -> its pass now under way
        self.picks: list[tuple[float, float, float, str]] = []   # t, x, y, type

    def sample(self, t: float, pos: float) -> None:
        """The belt's position at ``t`` (the world calls it once ``next_t`` is due)."""
        self.belt_t.append(t)
        self.belt_pos.append(pos)
        self.next_t = t + SAMPLE_S

    def landed(self, pid: int, t: float, x0: float, y: float, ptype: str,
               usable: bool) -> None:
        """A part came to rest on the horizontal belt: a pass begins."""
        self._current[pid] = len(self.t_on)
        self.t_on.append(t)
        self.pid.append(pid)
        self.x0.append(x0)
        self.y.append(y)
        self.types.append(ptype)
        self.usable.append(usable)

    def picked(self, pid: int, t: float, x: float, y: float, ptype: str) -> None:
        """The robot gripped part ``pid`` at (x, y): its pass was one the robot could take."""
        i = self._current.pop(pid, None)
        if i is not None:
            self.usable[i] = True
        self.picks.append((t, x, y, ptype))
