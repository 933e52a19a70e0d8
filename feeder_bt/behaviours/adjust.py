"""Auto-adjustment: every ``period_s`` the scenario's adjuster reads the statistics and
writes new speeds to the blackboard; the present and retrieve trees follow them."""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, Leaf
from feeder_bt.behaviours.keys import FAULTS, SPEEDS
from feeder_bt.core.encoder import DriftWatch
from feeder_bt.policy.adjusters import AdjustInputs

SPEED_KEYS = SPEEDS.ALL
GOLDEN = 0.6180339887498949    # the golden ratio's fraction: evenly spread, never repeating


class Adjust(Leaf):
    """Run the scenario's adjuster on the statistics; write the speeds it returns."""

    READS = SPEEDS.ALL
    WRITES = SPEEDS.ALL

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


class CheckDrift(Leaf):
    """Re-checks during the run that the Galil's and the robot's belt counts still agree:
    commissioning checks it once, but a counter that loses pulses
    later moves every pick by the difference. Reads only cached counts, so it never
    blocks; samples every ``encoder.drift_check_s``. Past ``drift_warn_mm`` it records an
    ``encoder_drift`` event; held past ``drift_limit_mm`` (``DriftWatch.held_past``) it asks
    the cell to go to FAULT (the operator's reset re-anchors the sync with the belt at
    rest)."""

    READS = (FAULTS.ESCALATE,)
    WRITES = (FAULTS.ESCALATE,)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        enc = ctx.cell.encoder
        self.spec = enc
        self.watch = DriftWatch(ctx.encoder, enc.counts_per_mm,
                                robot_sample_s=enc.robot_sample_s)
        self._next = 0.0
        self._k = 0
        self._warned = False

    def update(self) -> Status:
        now = self.ctx.now()
        if self.spec.drift_check_s <= 0 or now < self._next:
            return Status.SUCCESS
        # irregular spacing (0.75..1.25 of the period, a golden-ratio sequence): reads
        # spaced by a multiple of the robot's sampling period would all catch its held
        # sample at the same age, and the median would not average the age out (aliasing)
        self._k += 1
        self._next = now + self.spec.drift_check_s * (0.75 + 0.5 * ((self._k * GOLDEN) % 1.0))
        conv = self.ctx.hal.conveyors["horizontal"]
        pos = self.ctx.hal.robot_position
        conv_age = getattr(conv, "position_age", lambda: None)()
        robot_age = getattr(pos, "age", lambda: None)()
        doubt = (getattr(conv, "position_rtt", lambda: 0.0)()
                 + getattr(pos, "rtt", 0.0)) / 2.0
        drift = self.watch.sample(now, conv.position(), conv_age, pos.belt_encoder(),
                                  robot_age, doubt_s=doubt)
        stats = self.ctx.stats
        stats.drift = {"last_mm": drift, "max_abs_mm": round(self.watch.max_abs_mm, 2),
                       "samples": self.watch.taken, "doubtful": self.watch.doubtful}
        if drift is None:
            return Status.SUCCESS
        self.feedback_message = f"encoder drift {drift:+.2f} mm"
        if self.watch.held_past(drift, self.spec.drift_limit_mm):
            if self.bb.get(FAULTS.ESCALATE) is None:
                stats.emit(now, "encoder_drift", mm=round(drift, 2), level="fault")
                stats.faults["encoder_drift"] += 1
                self.bb.set(FAULTS.ESCALATE,
                            f"belt encoders disagree by {drift:+.1f} mm (limit "
                            f"{self.spec.drift_limit_mm:g} mm): the Galil's and the robot's "
                            "counts of the belt drifted apart; check the encoder cable and "
                            "its shield, then reset (the reset re-syncs at rest)")
        elif abs(drift) > self.spec.drift_warn_mm and not self._warned:
            self._warned = True
            stats.emit(now, "encoder_drift", mm=round(drift, 2), level="warning")
        return Status.SUCCESS
