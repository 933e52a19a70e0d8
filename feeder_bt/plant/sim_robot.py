"""A robot program for the simulated robot, written against the reference client.

It is what a robot integrator would write on a robot controller (docs/part-server.md):
ask for a part, pick it with belt tracking, report it picked, place it, report it placed;
report a miss and ask again. The motions go to the simulated cell's robot (the HAL's
``Robot``), so the world still judges every grip against the truth and keeps every part
accounted for by identity — the part server only ever hears what the robot reports.

It never blocks: ``step()`` runs between ticks (run.py's after-tick hook), polls the
client and the robot's jobs, and sends what comes next.
"""

from __future__ import annotations

from collections import deque

from feeder_bt.core.clock import EPS, Clock
from feeder_bt.core.errors import HalError
from feeder_bt.core.jobs import Job, JobState
from feeder_bt.core.model import Scenario
from feeder_bt.core.part_protocol import Offer, parse_offer
from feeder_bt.hal.interfaces import PickTarget, Pose, Robot
from feeder_bt.plant.client import PartClient, PartServerError

WAIT_S = 5.0            # PART ... WAIT: the server holds the request this long


class SimRobotProgram:
    """Pick-and-place loop of one simulated robot, driven through a ``PartClient``."""

    def __init__(self, client: PartClient, robot: Robot, scenario: Scenario, clock: Clock,
                 speed_pct: float | None = None, part_type: str | None = None) -> None:
        self.client, self.robot, self.scenario, self.clock = client, robot, scenario, clock
        self.again: tuple[float, str] | None = None   # ask the controller again at t
        self.part_type = part_type
        self.expect: deque[str] = deque()         # the command of each reply still to come
        self.job: Job | None = None
        self.doing: str | None = None             # "pick" | "place" | "recover" | "safe"
        self.offer: Offer | None = None
        self.asking = False
        self.dead = False
        self.error: str | None = None
        self.tries = 0
        self.counts = {"offers": 0, "picked": 0, "placed": 0, "missed": 0, "refused": 0}
        self.robot.set_speed(speed_pct if speed_pct is not None
                             else scenario.retrieve.robot_speed_pct)
        self._start("safe", self.robot.move_safe())

    # ------------------------------------------------------------------ the loop
    def step(self) -> None:
        """Between ticks: read replies, follow the robot's job, send the next request."""
        if self.dead:
            return
        try:
            self._replies()
            self._motion()
            if self.again is not None and self.clock.now() >= self.again[0] - EPS:
                doing, self.again = self.again[1], None
                self._start(doing, self.robot.held())
            if self.job is None and self.again is None and self.offer is None \
                    and not self.asking:
                words = "PART" + (f" {self.part_type}" if self.part_type else "")
                self._send(f"{words} WAIT {WAIT_S:g}")
                self.asking = True
        except PartServerError as e:          # the link failed: the program stops
            self.error = str(e)
            self.kill()

    def _send(self, line: str) -> None:
        self.client.submit(line)
        self.expect.append(line.split()[0])

    def _replies(self) -> None:
        while self.expect:
            got = self.client.poll()
            if got is None:
                return
            kind, fields = got
            cmd = self.expect.popleft()
            if kind == "ERR":
                self.counts["refused"] += 1
                self.error = fields[0]
            if cmd != "PART":
                continue
            self.asking = False
            if kind == "PART":
                self.offer = parse_offer(fields)
                self.counts["offers"] += 1
                self._pick(self.offer)

    def _pick(self, offer: Offer) -> None:
        tracking = self.scenario.retrieve.tracking
        self._start("pick", self.robot.pick(PickTarget(
            part_id=offer.id, x_mm=offer.x, y_mm=offer.y, angle_deg=offer.rz,
            latch=offer.latch, tracking=tracking)))

    def _start(self, doing: str, job: Job) -> None:
        self.doing, self.job = doing, job

    def _motion(self) -> None:
        job = self.job
        if job is None or job.poll() is JobState.RUNNING:
            return
        doing, self.job, self.doing = self.doing, None, None
        offer = self.offer
        err = None if job.ok else (job.error or HalError(f"{doing} failed"))
        if doing == "recover":
            self._start("safe", self.robot.move_safe())
        elif offer is None:
            return
        elif doing == "pick" and err is None:
            self._picked(offer)
        elif doing == "pick" and err.kind == "comms_lost":
            self._start("held after pick", self.robot.held())    # gripped before the cut?
        elif doing == "pick":
            self._missed(offer, "unreachable" if err.kind == "envelope" else err.kind)
            if err.kind == "servo_timeout":
                self._start("recover", self.robot.recover())
        elif doing.startswith("held") and err is not None:
            self._ask_again(doing)              # the link is still down: back off
        elif doing == "held after pick":
            held, self.tries = job.result, 0
            if held is not None and held.part_id == offer.id:
                self._picked(offer)
            else:
                self._missed(offer, "comms_lost")
        elif doing == "place" and err is None:
            self._placed(offer)
        elif doing == "place" and err.kind == "comms_lost":
            self._start("held after place", self.robot.held())
        elif doing == "place":                  # a servo fault: still held, place again
            self._start("recover then place", self.robot.recover())
        elif doing == "recover then place":
            self._place(offer)
        elif doing == "held after place":
            held, self.tries = job.result, 0
            if held is not None and held.part_id == offer.id:
                self._place(offer)
            elif held is not None and held.last_placed == offer.id:
                self._placed(offer)
            else:
                self._missed(offer, "dropped")

    def _ask_again(self, doing: str) -> None:
        """Ask the controller again after a back-off (0.5 s, doubling, at most 8 s)."""
        self.tries += 1
        wait = min(8.0, 0.5 * 2 ** (self.tries - 1))
        self.again = (self.clock.now() + wait, doing)
        self.clock.wake_at(self.again[0])

    def _picked(self, offer: Offer) -> None:
        self.counts["picked"] += 1
        self._send(f"PICKED {offer.id}")
        self._place(offer)

    def _place(self, offer: Offer) -> None:
        spec = self.scenario.parts[offer.type].place
        rz = -offer.rz if spec.orient else 0.0
        self._start("place", self.robot.place(Pose(spec.x, spec.y, spec.z, rz)))

    def _placed(self, offer: Offer) -> None:
        self.counts["placed"] += 1
        self._send(f"PLACED {offer.id}")
        self.offer = None

    def _missed(self, offer: Offer, why: str) -> None:
        self.counts["missed"] += 1
        self._send(f"MISSED {offer.id} {why}")
        self.offer = None

    def kill(self) -> None:
        """The robot program is aborted: the motion stops where it is (a pick not yet
        gripped leaves the part on the belt) and the connection drops without a word."""
        if self.dead:
            return
        self.dead = True
        if self.job is not None and not self.job.done:
            self.job.cancel()
        self.job = None
        self.client.close()
