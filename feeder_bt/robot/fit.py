"""A robot model fitted online from the robot's measured move times.

The pick policies price every pick with a robot model. The cell description's model is
nominal: the arm in front of the cell may be slower (a payload, a controller's speed
limit, wear) or faster than it says, and a policy pricing with the wrong model trades
moves against belt waits at the wrong rate. So the retrieve tree times every successful
pick and place on the cell's clock, takes off the fixed parts the cell description knows
(command overhead, settle, grip, release), and fits what is left — the arm's move — by
recursive least squares:

    move time = k * nominal arch time(d, speed %) + c

``k`` is a time scale (1/k the arm's speed over the described one: effective v_max / k,
a_max / k²) and ``c`` a constant per move (controller latency, the tick at which the cell
sees a job end). The fit starts from the nominal model (k = 1, c = 0) as a prior, forgets
slowly (a robot slowed by an operator is followed), and is bounded and robust:

- only successful jobs are timed (a time-out or fault fails the job: no sample);
- a pick is timed only if its part was inside the reach when the pick was commanded, so
  the arm never waited for the part to come into reach (a tracking wait is not a move);
- a time no bounded model could explain is rejected and counted; the rest is weighted
  by Huber's rule, so one slow move moves the fit only a little;
- the estimates stay within ``K_BOUNDS`` and ``C_BOUNDS``.

The fitted model lives in ``ctx.extras["robot_fit"]`` (``robot_fit(ctx)``); the pick
policies read ``pricing_model(ctx)``, and the run report shows it as ``robot_model``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from feeder_bt.core.model import RobotSpec
from feeder_bt.robot.model import RobotModel, with_speed_factor

K_BOUNDS = (0.4, 2.5)          # the arm 2.5 times faster to 2.5 times slower than described
C_BOUNDS = (-0.05, 0.25)       # s per move
PRIOR_SD = (0.25, 0.02)        # how far the prior (the cell description) is trusted
FORGET = 0.998                 # memory of about 500 moves
HUBER = 3.0                    # residuals beyond this many scales are down-weighted
MIN_SCALE_S = 0.004            # floor of the residual scale: the tick is 5 ms at 200 Hz
NOISE_S = 0.01                 # a measured move's expected error (tick, timing jitter)


class FittedRobotModel(RobotModel):
    """The nominal model with every arch time mapped through the fit: ``k t + c``."""

    def __init__(self, spec: RobotSpec, fit: RobotFit) -> None:
        super().__init__(spec)
        self.fit = fit

    def arch_time(self, d_xy: float, speed_pct: float) -> float:
        return self.fit.k * super().arch_time(d_xy, speed_pct) + self.fit.c

    def arch_times(self, d_xy: np.ndarray, speed_pct: float) -> np.ndarray:
        return self.fit.k * super().arch_times(d_xy, speed_pct) + self.fit.c


@dataclass
class Timing:
    """A pick or place as it was commanded: what the fit needs when it ends."""

    kind: str                          # "pick" | "place"
    t0: float
    start: tuple[float, float]         # the arm's pose when commanded
    speed_pct: float
    usable: bool = True                # pick: the part was in reach (no wait possible)
    end: tuple[float, float] | None = None     # place: where it goes
    belt_mm_s: float = 0.0
    tracking: bool = True
    tool_y: float = 0.0


class RobotFit:
    """Recursive least squares of ``(k, c)`` from timed moves; see the module's doc."""

    def __init__(self, spec: RobotSpec, learning: bool = True) -> None:
        self.spec = spec
        self.learning = learning
        self.nominal = RobotModel(spec)
        self.model = FittedRobotModel(spec, self)
        self.theta = np.array([1.0, 0.0])
        self.P0 = np.diag(np.square(PRIOR_SD))
        self.P = self.P0.copy()
        self.scale = 0.05              # robust residual scale, s (generous at first)
        self.mean_sq = 0.0
        self.samples: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.busy_s = 0.0              # commanded to the end of every pick and place that ended
        # where the arm's time went (the report's robot_time): of busy_s, the picks' waits at
        # the reach for a part still upstream; beside it, picks that gripped nothing
        self.waited_s = 0.0
        self.missed_s = 0.0
        self.first_pick_t: float | None = None
        # the fit's one-step prediction residual (predicted before each update against the
        # measured move): how well the controller's Cartesian form fits the arm
        self.res_n = 0
        self.res_sq = 0.0
        self.res_max = 0.0
        self.res_moves_s = 0.0

    @property
    def k(self) -> float:
        return float(self.theta[0])

    @property
    def c(self) -> float:
        return float(self.theta[1])

    # ---------------------------------------------------------------- the fit
    def observe(self, kind: str, d_xy: float, speed_pct: float, move_s: float) -> bool:
        """One measured move of ``d_xy`` mm at ``speed_pct``: update the fit; False if
        the time was rejected as one no bounded model could explain."""
        t_nom = self.nominal.arch_time(d_xy, speed_pct)
        lo = K_BOUNDS[0] * t_nom + C_BOUNDS[0]
        hi = K_BOUNDS[1] * t_nom + C_BOUNDS[1]
        if not (math.isfinite(move_s) and lo <= move_s <= hi):
            self.rejected["implausible"] += 1
            return False
        phi = np.array([t_nom, 1.0])
        r = move_s - float(phi @ self.theta)
        self.res_n += 1
        self.res_sq += r * r
        self.res_max = max(self.res_max, abs(r))
        self.res_moves_s += move_s
        s = max(self.scale, MIN_SCALE_S)
        w = 1.0 if abs(r) <= HUBER * s else HUBER * s / abs(r)
        p_phi = self.P @ phi
        gain = p_phi / (NOISE_S ** 2 / w + float(phi @ p_phi))
        self.theta = self.theta + gain * r
        self.P = (self.P - np.outer(gain, p_phi)) / FORGET
        self.P = 0.5 * (self.P + self.P.T)
        if np.trace(self.P) > np.trace(self.P0):     # no wind-up while nothing is learnt
            self.P *= np.trace(self.P0) / np.trace(self.P)
        self.theta = self._bounded(self.theta)
        self.scale = 0.97 * self.scale + 0.03 * 1.25 * min(abs(r), 5 * s)
        self.mean_sq = 0.97 * self.mean_sq + 0.03 * r * r
        self.samples[kind] += 1
        return True

    def _bounded(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` moved inside the bounds along the fit's own uncertainty: an estimate
        held at one bound moves the other as the data correlate them (clipping each alone
        leaves a pair that fits nothing: with a world whose offset wants to be below
        ``C_BOUNDS``, the fit ran 0.2 s above every move)."""
        k, c = float(theta[0]), float(theta[1])
        P = self.P
        cb = min(max(c, C_BOUNDS[0]), C_BOUNDS[1])
        if cb != c:
            k += P[0, 1] / P[1, 1] * (cb - c)
            c = cb
        kb = min(max(k, K_BOUNDS[0]), K_BOUNDS[1])
        if kb != k:
            c = min(max(c + P[0, 1] / P[0, 0] * (kb - k), C_BOUNDS[0]), C_BOUNDS[1])
            k = kb
        return np.array([k, c])

    # ---------------------------------------------------------------- timing jobs
    def pick_done(self, timing: Timing, t_end: float, grip_x: float) -> None:
        """A pick that gripped at ``grip_x`` (the tool point along the belt) ended at
        ``t_end``: its move ran from ``timing.start`` to where the part was at arrival."""
        self.busy_s += t_end - timing.t0          # a wait for the part is the arm's time too
        sp = self.spec
        hold = (sp.track_settle_s if timing.tracking else 0.0) + sp.grip_s
        arrive_x = grip_x - (timing.belt_mm_s * hold if timing.tracking else 0.0)
        d = math.dist(timing.start, (arrive_x, timing.tool_y))
        measured = t_end - timing.t0 - sp.command_overhead_s - hold
        if not timing.usable:
            # commanded before the part was in reach: the arm waited at the reach's edge
            # for as long as the move took less than the whole pick (priced by the fit)
            self.rejected["may_have_waited"] += 1
            wait = measured - self.model.arch_time(d, timing.speed_pct)
            self.waited_s += min(max(wait, 0.0), t_end - timing.t0)
            return
        self.observe("pick", d, timing.speed_pct, measured)

    def pick_missed(self, timing: Timing, t_end: float) -> None:
        """A pick that ended with nothing gripped: the arm's time, but no part's."""
        self.missed_s += t_end - timing.t0

    def pick_commanded(self, timing: Timing) -> None:
        """A pick left for the arm (the first one ends the start-up's idle)."""
        if self.first_pick_t is None:
            self.first_pick_t = timing.t0

    def place_done(self, timing: Timing, t_end: float) -> None:
        sp = self.spec
        self.busy_s += t_end - timing.t0
        assert timing.end is not None
        self.observe("place", math.dist(timing.start, timing.end), timing.speed_pct,
                     t_end - timing.t0 - sp.command_overhead_s - sp.release_s)

    # ---------------------------------------------------------------- the report
    def summary(self) -> dict[str, Any]:
        """The report's ``robot_model``: nominal against fitted, and what it was fitted on."""
        sp = self.spec
        eff = with_speed_factor(sp, 1.0 / self.k)
        return {
            "learning": self.learning,
            "samples": sum(self.samples.values()),
            "picks": self.samples["pick"], "places": self.samples["place"],
            "rejected": dict(self.rejected),
            "nominal": {"v_max_mm_s": sp.v_max_mm_s, "a_max_mm_s2": sp.a_max_mm_s2,
                        "time_scale": 1.0, "offset_s": 0.0,
                        "standard_cycle_s": round(self.nominal.standard_cycle(), 4)},
            "fitted": {"v_max_mm_s": round(eff.v_max_mm_s, 1),
                       "a_max_mm_s2": round(eff.a_max_mm_s2, 1),
                       "time_scale": round(self.k, 4), "offset_s": round(self.c, 4),
                       "standard_cycle_s": round(self.model.standard_cycle(), 4),
                       "rms_residual_s": round(math.sqrt(self.mean_sq), 4),
                       "residual": self.residual()},
        }

    def time_split(self, feed_seconds: float, started_at: float | None) -> dict[str, Any]:
        """The report's ``robot_time``: the arm's share of feeding on pick-and-place cycles
        (moving, gripping, releasing), waiting at the reach for a part still upstream, on
        picks that gripped nothing, and idle (no pick or place under way: nothing the
        policy would take, a decision, a recovery); and when it first picked."""
        if feed_seconds <= 0:
            return {}

        def pct(s: float) -> float:
            return round(100.0 * s / feed_seconds, 1)

        idle = max(feed_seconds - self.busy_s - self.missed_s, 0.0)
        first = (round(self.first_pick_t - started_at, 2)
                 if self.first_pick_t is not None and started_at is not None else None)
        return {"cycles_pct": pct(self.busy_s - self.waited_s), "waiting_pct": pct(self.waited_s),
                "missed_pct": pct(self.missed_s), "idle_pct": pct(idle),
                "first_pick_s": first}

    def residual(self) -> dict[str, Any]:
        """The fit's prediction error over the run: every accepted move's time predicted
        before the fit saw it, against the measured time (rms and max in ms, rms as a %
        of the mean measured move)."""
        if self.res_n == 0:
            return {"moves": 0, "rms_ms": None, "max_ms": None, "rms_pct": None}
        rms = math.sqrt(self.res_sq / self.res_n)
        mean = self.res_moves_s / self.res_n
        return {"moves": self.res_n, "rms_ms": round(1000.0 * rms, 2),
                "max_ms": round(1000.0 * self.res_max, 2),
                "rms_pct": round(100.0 * rms / mean, 2) if mean > 0 else None}


def robot_fit(ctx: Any) -> RobotFit:
    """The run's fit (one per scenario), created on first use."""
    fit = ctx.extras.get("robot_fit")
    if fit is None:
        fit = ctx.extras["robot_fit"] = RobotFit(ctx.cell.robot,
                                                 ctx.scenario.retrieve.learn_robot)
    return fit


def pricing_model(ctx: Any) -> RobotModel:
    """The model a pick policy prices with: the fitted one, or the nominal one if the
    scenario says ``retrieve.learn_robot: false``."""
    fit = robot_fit(ctx)
    return fit.model if fit.learning else fit.nominal
