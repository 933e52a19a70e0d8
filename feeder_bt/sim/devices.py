"""The HAL over the simulated world: what the trees talk to on the simulated cell.

Each device turns a call into a ``Job`` that the world completes at the right virtual
time. Rendering runs on the camera's own worker thread; the virtual clock waits for it
(``FutureJob`` gating), so a fast run gives the same results on any machine.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import HalError
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.hal.interfaces import Frame, Hal, IoChange, PickResult, PickTarget, Pose
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.imperfect import true_calibration
from feeder_bt.sim.render import Renderer
from feeder_bt.sim.world import World
from feeder_bt.vision.pixels import Calibration
from feeder_bt.vision.worker import DeferredFuture


class TimedJob(Job):
    """A job the world finishes at a scheduled virtual time; cancel unschedules it."""

    def __init__(self, name: str, world: World) -> None:
        super().__init__(name)
        self.world = world
        self.seq: int | None = None
        self.on_cancel = None

    def at(self, t: float, fn) -> TimedJob:
        self.seq = self.world.schedule(t, fn)
        return self

    def _on_cancel(self) -> None:
        if self.seq is not None:
            self.world.unschedule(self.seq)
        if self.on_cancel is not None:
            self.on_cancel()


class SimConveyor:
    def __init__(self, name: str, axis: Axis, world: World) -> None:
        self.name, self.axis, self.world = name, axis, world

    def _ends_at(self, name: str, t_end: float) -> Job:
        job = TimedJob(name, self.world)
        return job.at(t_end, lambda t: job.succeed(t))

    def _refused(self, what: str, mm_s: float) -> Job | None:
        """A speed above the cell's ``max_mm_s`` fails the job: the simulated belt never
        clamps silently, so every setting runs under the same limits."""
        from feeder_bt.hal.interfaces import speed_refused
        return speed_refused(self.name, what, mm_s, self.axis.max_speed, self.world.cell.path)

    def set_speed(self, mm_s: float) -> Job:
        refused = self._refused("set_speed", mm_s)
        if refused is not None:
            return refused
        return self._ends_at(f"{self.name}.set_speed", self.axis.jog(self.world.now(), mm_s))

    def move(self, distance_mm: float, mm_s: float) -> Job:
        refused = self._refused("move", mm_s)
        if refused is not None:
            return refused
        return self._ends_at(f"{self.name}.move", self.axis.move(self.world.now(), distance_mm, mm_s))

    def stop(self) -> Job:
        return self._ends_at(f"{self.name}.stop", self.axis.jog(self.world.now(), 0.0))

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        """Back-and-forth moves, then back to the speed it had."""
        before = self.axis.commanded
        t = self.axis.jog(self.world.now(), 0.0)
        for _ in range(max(1, cycles)):
            t = self.axis.move(t, amplitude_mm, self.axis.max_speed)
            t = self.axis.move(t, -amplitude_mm, self.axis.max_speed)
        if before:
            t = self.axis.jog(t, before)
        return self._ends_at(f"{self.name}.shake", t)

    def speed(self) -> float:
        return self.axis.commanded

    def position(self) -> int:
        return self.world.galil_count()

    def position_age(self) -> float | None:
        return 0.0                      # read now, from the world

    def fault(self) -> HalError | None:
        return None

    def servo(self, on: bool) -> Job:
        return DoneJob(f"{self.name}.servo")

    def travelled(self, distance_mm: float) -> Job:
        job = Job(f"{self.name}.travelled({distance_mm:g})")
        self.world.notify_travel(self.axis, distance_mm, job)
        return job


class SimCamera:
    def __init__(self, world: World, cell: CellSpec, seed: int) -> None:
        self.world, self.cell, self.seed = world, cell, seed
        # the world's true mapping (a calibration residual): the renderer's, never the locator's
        self.renderer = Renderer(cell.camera, truth=true_calibration(cell))
        self.calibration = Calibration(cell.camera.calibration)
        cam = cell.camera
        corners = self.calibration.px_to_mm(np.array(
            [[0, 0], [cam.width_px, 0], [0, cam.height_px], [cam.width_px, cam.height_px]],
            dtype=float))
        self.x_range = (float(corners[:, 0].min()), float(corners[:, 0].max()))
        self.worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-camera")
        self.frames = 0
        self.exposure_ms = cam.exposure_ms
        self.front_lit = cam.render.lighting == "frontlit"

    def snapshot(self, t: float, index: int):
        """What the camera sees at ``t`` (read under the world's time), and a function that
        renders it — slow, so it runs off the tick on a worker."""
        # a front-lit camera's lamp is always on: the backlight output does not light it
        lit = self.front_lit or self.world.io.get("backlight", True)
        outlines = self.world.visible_outlines(t, self.x_range) if lit else []
        rng = np.random.default_rng([self.seed, index])

        def render() -> np.ndarray:
            img = self.renderer.render(outlines, rng)
            return img if lit else (img * 0.08).astype(np.uint8)

        return render

    def grab(self) -> Job:
        w = self.world
        t = w.now()
        self.frames += 1
        index = self.frames
        latch = w.galil_count(t)
        render = self.snapshot(t, index)

        def frame() -> Frame:
            return Frame(image=render(), latch=latch, t=t, index=index)

        # on a virtual clock the frame is rendered when the clock first waits for it, in
        # the waiting thread: the same image (its own rng, the outlines read now) without
        # handing it to the worker thread and back, which cost as much as the render
        future = DeferredFuture(frame) if w.clock.virtual else self.worker.submit(frame)
        return FutureJob("camera.grab", future, w.clock, eta=t + self.cell.camera.grab_s)

    def set_exposure(self, ms: float) -> Job:
        self.exposure_ms = ms
        return DoneJob("camera.set_exposure")

    def close(self) -> None:
        self.worker.shutdown(wait=True, cancel_futures=True)


class SimRobot:
    def __init__(self, world: World) -> None:
        self.world = world

    def _busy_check(self, name: str) -> HalError | None:
        busy = self.world.robot_busy
        if busy is not None and not busy.done:
            return HalError(f"robot busy with {busy.name}; {name} refused")
        return None

    def _run(self, name: str, duration: float, finish) -> Job:
        err = self._busy_check(name)
        if err:
            return DoneJob(name, error=err)
        job = TimedJob(name, self.world)
        self.world.robot_busy = job

        def done(t: float) -> None:
            try:
                job.succeed(finish(t))
            except HalError as e:
                job.fail(e)

        return job.at(self.world.now() + duration, done)

    def pick(self, target: PickTarget) -> Job:
        w = self.world
        err = self._busy_check("pick")
        if err:
            return DoneJob("robot.pick", error=err)
        try:
            _, t_grip = w.plan_pick(target, w.now() + w.cell.robot.command_overhead_s,
                                    scale=w.imperfect.time_factor())
        except HalError as e:
            return DoneJob("robot.pick", error=e)
        wait = w.planned_wait_s

        def grip(t: float) -> PickResult:
            result = w.grip(target, t)
            w.pick_waited_s += wait       # the truth beside the report's robot_time
            return result

        return self._run("robot.pick", t_grip - w.now(), grip)

    def place(self, pose: Pose) -> Job:
        w = self.world
        here = (w.robot_pose.x, w.robot_pose.y)
        duration = (w.cell.robot.command_overhead_s + w.cell.robot.release_s
                    + w.imperfect.time_factor() * w.robot_model.move_time(
                        here, (pose.x, pose.y), w.robot_speed_pct))
        job = self._run("robot.place", duration, lambda t: w.release(pose, t))
        if isinstance(job, TimedJob):     # a place is never abandoned: the part is let go
            job.on_cancel = lambda: job.succeed(w.release(pose, w.now()))
        return job

    def move_to(self, pose: Pose) -> Job:
        w = self.world
        here = (w.robot_pose.x, w.robot_pose.y)

        def arrive(t: float) -> Pose:
            w.robot_pose = pose
            return pose

        return self._run("robot.move", w.imperfect.time_factor()
                         * w.robot_model.move_time(here, (pose.x, pose.y), w.robot_speed_pct),
                         arrive)

    def move_safe(self) -> Job:
        return self.move_to(Pose(*self.world.cell.robot.safe_mm))

    def set_speed(self, pct: float) -> Job:
        self.world.robot_speed_pct = float(pct)
        return DoneJob("robot.set_speed")

    def recover(self) -> Job:
        return self._run("robot.recover", 2.0, lambda t: None)

    def holding(self) -> bool:
        return self.world.gripper is not None

    def held(self) -> Job:
        """The controller's record of its gripper; a motion still running (its reply was
        lost) finishes first, as the motion server answers one request at a time."""
        w = self.world
        busy = w.robot_busy
        if busy is None or busy.done:
            return DoneJob("robot.held", w.held_now())
        job = Job("robot.held")
        busy.add_done_callback(lambda _: job.succeed(w.held_now()))
        return job


class SimRobotPosition:
    def __init__(self, world: World) -> None:
        self.world = world

    def belt_encoder(self) -> int:
        return self.world.robot_count()

    def age(self) -> float | None:
        return 0.0

    def pose(self) -> Pose:
        return self.world.robot_pose


class SimIO:
    def __init__(self, world: World) -> None:
        self.world = world
        self._changes: list[IoChange] = []

    def get(self, signal: str) -> bool:
        return self.world.io.get(signal, False)

    def set(self, signal: str, value: bool) -> Job:
        if signal not in self.world.io:
            return DoneJob(f"io.set({signal})", error=HalError(f"unknown signal {signal!r}"))
        self.world.io[signal] = bool(value)
        return DoneJob(f"io.set({signal})")

    def changes(self) -> list[IoChange]:
        out, self._changes = self._changes, []
        return out


class SimHal(Hal):
    """The simulated cell behind the HAL interfaces."""

    world: World

    @property
    def truth(self) -> World:               # type: ignore[override]
        """The world itself: its truth is what the report accounts against."""
        return self.world

    @truth.setter
    def truth(self, value: object) -> None:
        """The dataclass's default (None) is set at construction; the world stands in."""

    def step(self, now: float) -> None:
        self.world.step(now)

    def changeover(self, scenario: Scenario) -> None:
        fresh = make_sim_hal(scenario, self.world.cell, self.world.clock, self.world.seed)
        # the operator swaps the parts; what the old world found wrong is still a finding
        fresh.world.listeners = self.world.listeners
        fresh.world.problems = self.world.problems
        self.camera.close()
        self.__dict__.update(fresh.__dict__)

    def close(self) -> None:
        self.camera.close()


def make_sim_hal(scenario: Scenario, cell: CellSpec, clock: SimClock, seed: int) -> SimHal:
    world = World(scenario, cell, clock, seed)   # its arm: a SCARA (world.robot_model)
    hal = SimHal(
        conveyors={"horizontal": SimConveyor("horizontal", world.horizontal, world),
                   "incline": SimConveyor("incline", world.incline, world)},
        robot=SimRobot(world),
        robot_position=SimRobotPosition(world),
        camera=SimCamera(world, cell, seed),
        io=SimIO(world),
        kind="sim",
    )
    hal.world = world
    return hal
