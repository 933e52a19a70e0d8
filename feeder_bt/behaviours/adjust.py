"""Auto-adjustment: every ``period_s`` the scenario's adjuster reads the statistics and
writes new speeds to the blackboard; the present and retrieve trees follow them."""

from __future__ import annotations

from py_trees.common import Status

from ..adjusters import AdjustInputs
from .common import Ctx, Leaf, client

SPEED_KEYS = ("/speeds/horizontal_mm_s", "/speeds/incline_pct", "/speeds/robot_speed_pct")


class Adjust(Leaf):
    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.bb = client(self, read=SPEED_KEYS, write=SPEED_KEYS)

    def update(self) -> Status:
        s = self.ctx.stats
        h, i, r = (float(self.bb.get(k)) for k in SPEED_KEYS)
        inp = AdjustInputs(t=self.ctx.now(), queue_len=len(self.ctx.queue), horizontal_mm_s=h,
                           incline_pct=i, robot_speed_pct=r, retrieved=s.total_retrieved,
                           located=s.counts["located"], recirculated=s.counts["too_far"],
                           missed=s.counts["missed"])
        out = self.ctx.adjuster.update(inp)
        new = (out.horizontal_mm_s, out.incline_pct, out.robot_speed_pct)
        for key, old, val in zip(SPEED_KEYS, (h, i, r), new, strict=True):
            if abs(val - old) > 1e-9:
                self.bb.set(key, val)
        s.timeline.append({"t": inp.t, "queue": inp.queue_len, "horizontal_mm_s": new[0],
                           "incline_pct": new[1], "robot_speed_pct": new[2],
                           "retrieved": inp.retrieved})
        self.feedback_message = f"horizontal {new[0]:.0f} mm/s, queue {inp.queue_len}"
        return Status.SUCCESS
