"""The mock HAL: calls recorded in order as ``(device, method, args)``; jobs left RUNNING."""

from __future__ import annotations

from typing import Any

from feeder_bt.core.jobs import DoneJob, Job
from feeder_bt.hal.interfaces import Hal, Held, IoChange, Pose


class MockJob(Job):
    """A job the test completes by hand."""

    def __init__(self, name: str, args: tuple) -> None:
        super().__init__(name)
        self.args = args
        self.cancelled = False

    def _on_cancel(self) -> None:
        self.cancelled = True


class _Device:
    def __init__(self, hal: MockHal, name: str) -> None:
        self._hal, self._name = hal, name

    def _job(self, method: str, *args: Any) -> MockJob:
        job = MockJob(f"{self._name}.{method}", args)
        self._hal.calls.append((self._name, method, args))
        self._hal.jobs.append(job)
        return job


class MockConveyor(_Device):
    def __init__(self, hal: MockHal, name: str) -> None:
        super().__init__(hal, name)
        self.name = name
        self.count = 0
        self.commanded = 0.0
        self.jam = None

    def set_speed(self, mm_s: float) -> Job:
        self.commanded, self.jam = mm_s, None
        return self._job("set_speed", mm_s)

    def move(self, distance_mm: float, mm_s: float) -> Job:
        self.jam = None
        return self._job("move", distance_mm, mm_s)

    def stop(self) -> Job:
        self.commanded, self.jam = 0.0, None
        return self._job("stop")

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        self.jam = None
        return self._job("shake", amplitude_mm, cycles)

    def speed(self) -> float:
        return self.commanded

    def position(self) -> int:
        return self.count

    def position_age(self) -> float | None:
        return 0.0

    def travelled(self, distance_mm: float) -> Job:
        return self._job("travelled", distance_mm)

    def servo(self, on: bool) -> Job:
        return self._job("servo", on)

    def fault(self):
        """The test sets ``jam`` to a ``ConveyorFault``; a motion command clears it."""
        return self.jam


class MockCamera(_Device):
    def grab(self) -> Job:
        return self._job("grab")

    def set_exposure(self, ms: float) -> Job:
        return self._job("set_exposure", ms)


class MockRobot(_Device):
    """Keeps a controller's record of its gripper: a pick the test finishes grips the
    commanded part, a place the test finishes releases it; the test may also set
    ``gripping`` and ``held_id`` by hand (a part put in the gripper, a lost reply)."""

    def __init__(self, hal: MockHal, name: str) -> None:
        super().__init__(hal, name)
        self.gripping = False
        self.held_id: int | None = None
        self.last_placed: int | None = None
        self.speed_pct = 100.0

    def grip(self, part_id: int | None) -> None:
        self.gripping, self.held_id = True, part_id

    def pick(self, target) -> Job:
        job = self._job("pick", target)
        job.add_done_callback(lambda j: j.ok and self.grip(target.part_id))
        return job

    def place(self, pose: Pose) -> Job:
        job = self._job("place", pose)
        job.add_done_callback(lambda j: j.ok and self._released())
        return job

    def _released(self) -> None:
        if self.gripping:
            self.last_placed = self.held_id
        self.gripping, self.held_id = False, None

    def held(self) -> Job:
        self._hal.calls.append((self._name, "held", ()))
        if not self.gripping:
            h = Held(None, False, self.last_placed)
        else:
            h = Held(self.held_id, self.held_id is None, self.last_placed)
        return DoneJob("robot.held", h)

    def move_to(self, pose: Pose) -> Job:
        return self._job("move_to", pose)

    def move_safe(self) -> Job:
        return self._job("move_safe")

    def set_speed(self, pct: float) -> Job:
        self.speed_pct = pct
        job = self._job("set_speed", pct)
        job.succeed(None)
        return job

    def recover(self) -> Job:
        return self._job("recover")

    def holding(self) -> bool:
        return self.gripping


class MockRobotPosition:
    def __init__(self) -> None:
        self.encoder = 0
        self.at = Pose(0.0, 0.0)

    def belt_encoder(self) -> int:
        return self.encoder

    def age(self) -> float | None:
        return 0.0

    def pose(self) -> Pose:
        return self.at


class MockIO(_Device):
    def __init__(self, hal: MockHal, name: str) -> None:
        super().__init__(hal, name)
        self.values: dict[str, bool] = {}
        self.pending: list[IoChange] = []

    def get(self, signal: str) -> bool:
        return self.values.get(signal, False)

    def set(self, signal: str, value: bool) -> Job:
        self.values[signal] = value
        return self._job("set", signal, value)

    def changes(self) -> list[IoChange]:
        out, self.pending = self.pending, []
        return out


class MockHal(Hal):
    def __init__(self) -> None:
        self.calls: list[tuple[str, str, tuple]] = []
        self.jobs: list[MockJob] = []
        super().__init__(
            conveyors={"horizontal": MockConveyor(self, "horizontal"),
                       "incline": MockConveyor(self, "incline")},
            robot=MockRobot(self, "robot"), robot_position=MockRobotPosition(),
            camera=MockCamera(self, "camera"), io=MockIO(self, "io"), kind="mock")

    def pending(self, device: str | None = None, method: str | None = None) -> list[MockJob]:
        """Jobs still RUNNING, optionally only those of one device/method, oldest first."""
        return [j for j in self.jobs if not j.done
                and (device is None or j.name.split(".")[0] == device)
                and (method is None or j.name.split(".", 1)[1] == method)]

    def last(self, device: str, method: str) -> MockJob:
        for j in reversed(self.jobs):
            if j.name == f"{device}.{method}":
                return j
        raise AssertionError(f"no {device}.{method} call; calls were {self.calls}")

    def methods(self) -> list[str]:
        """Calls as ``device.method`` strings, in order."""
        return [f"{d}.{m}" for d, m, _ in self.calls]
