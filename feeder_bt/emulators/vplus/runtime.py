"""The V+ controller: memory, tasks, signals, the arm and the TCP LUNs over the plant.

``Runtime.statement`` and ``Runtime.func`` carry out the statements and functions of the
V+ subset the programs use (``program.py`` parses them); every robot fact is the arm's
(``arm.py``), every socket fact the LUN's (``devices.py``).

Signals (V+ Language Reference Guide, SIGNAL and SIG): outputs 1-999, inputs 1001-1999,
soft signals 2001-2999; ``SIGNAL -n`` turns n off; ``SIG(-n)`` is true while n is off
(NOT CONFIRMED through the search tool: the complement; commissioning checks it with the
e-stop). The cell description names the Adept's wired bits; an input the description
marks ``active_low`` reads 0 while its signal is active. The vacuum switch (the
programs' ``grip.sense``, input ``grip_sense``) reads whether the plant's gripper holds
a part; turning the ``vacuum`` output on makes the plant judge a grip where the arm
truly is, turning it off releases the part there.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from feeder_bt.core.errors import HalError
from feeder_bt.core.model import RobotSpec
from feeder_bt.emulators.vplus.arm import Arm
from feeder_bt.emulators.vplus.devices import TcpLun
from feeder_bt.emulators.vplus.funcs import PURE
from feeder_bt.emulators.vplus.program import Program
from feeder_bt.emulators.vplus.task import Cell, Killed, Task, VError
from feeder_bt.emulators.vplus.trans import Belt, BeltLoc, Trans
from feeder_bt.hal.interfaces import PickTarget, Pose

GRIP_Z_MM = 10.0          # the cup reaches a part only this close to the belt
MAJOR_CYCLE_S = 0.016     # V+ WAIT with no condition: until the next major cycle
SERVO_S = 0.004           # how often the servo loop looks at the arm


class Runtime:
    def __init__(self, programs: dict[str, Program], plant: Any, true_base: Trans,
                 listeners: dict[int, tuple[str, Any]], faults: Any = None,
                 belt_direction: int = 1, grip_sense: int = 1003,
                 log: Callable[[str], None] | None = None) -> None:
        self.programs, self.plant, self.faults = programs, plant, faults
        self.listeners = listeners
        self.belt_direction, self.grip_sense = belt_direction, grip_sense
        self.globals: dict[str, Any] = {}
        self.tasks: dict[int, Task] = {}
        self.luns: dict[int, TcpLun] = {}
        self.soft: dict[int, bool] = {}
        self.outputs: dict[int, bool] = {}
        self.belt_switch = False
        self.killed = False
        self._kill = threading.Event()
        self.lock = threading.RLock()           # the arm and the memory it shares
        self.typed: deque[str] = deque(maxlen=500)
        self.requests: deque[tuple[str, str]] = deque(maxlen=1000)
        self.connections: Counter[str] = Counter()
        self.conns: set[Any] = set()
        self._log = log
        with plant.lock:
            p = plant.world.robot_pose
        start = true_base.inverse() @ Trans.make(p.x, p.y, p.z, 0.0, 180.0, p.rz)
        self.arm = Arm(self, true_base, start)
        self._servo: threading.Thread | None = None

    # ------------------------------------------------------------ life
    def start(self, program: str = "a_server") -> None:
        task = self.tasks[0] = Task(self, 0)
        self.arm.owner = task
        self._servo = threading.Thread(target=self._servo_loop, name="vplus-servo",
                                       daemon=True)
        self._servo.start()
        task.start(program, [])

    def stop(self) -> None:
        self.killed = True
        self._kill.set()
        for lun in list(self.luns.values()):
            lun.close_client()
        for task in list(self.tasks.values()):
            if task.thread is not None:
                task.thread.join(timeout=3.0)
        if self._servo is not None:
            self._servo.join(timeout=2.0)

    def wake(self) -> None:
        pass                                     # waits poll; nothing to notify

    def sleep(self, s: float) -> None:
        if self._kill.wait(max(0.0, s)):
            raise Killed()

    def log(self, text: str) -> None:
        self.typed.append(text)
        if self._log is not None:
            self._log(text)

    def accepted(self, server: str, conn: Any) -> None:
        self.connections[server] += 1
        self.conns.add(conn)

    def forget(self, conn: Any) -> None:
        self.conns.discard(conn)

    def _servo_loop(self) -> None:
        n = 0
        while not self._kill.wait(SERVO_S):
            try:
                estop = self.estop()
                with self.lock:
                    self.arm.poll(estop)
                n += 1
                if n % 5 == 0:
                    x, y, z, r = self.arm.cell_pose()
                    with self.plant.lock:
                        self.plant.world.robot_pose = Pose(x, y, z, r)
            except Exception as e:               # noqa: BLE001 - kept, reported by the log
                self.log(f"servo loop: {e!r}")

    # ------------------------------------------------------------ plant facts
    def now(self) -> float:
        return self.plant.now()

    def robot_spec(self) -> RobotSpec:
        return self.plant.world.robot_model.spec

    def robot_count(self, t: float | None = None) -> int:
        """The belt channel as BELT() reads it: the sample of the current cycle, held."""
        with self.plant.lock:
            count = self.plant.world.robot_count(t)
        return self._directed(count)

    def track_count(self, t: float | None = None) -> int:
        """The belt count the arm's tracking follows (the held sample carried forward by
        the averaged belt speed: the world's ``robot_track_count``)."""
        with self.plant.lock:
            world = self.plant.world
            count = world.robot_track_count(world.now() if t is None else t)
        return self._directed(count)

    def _directed(self, count: int) -> int:
        d = self.belt_direction
        return ((count * d + (1 << 23)) % (1 << 24)) - (1 << 23)

    def estop(self) -> bool:
        return self.plant.signal("estop")

    # ------------------------------------------------------------ signals
    def _io_name(self, bit: int, is_input: bool) -> str | None:
        for name, sig in self.plant.cell.io.items():
            if sig.controller == "adept" and (sig.dir == "in") == is_input and sig.bit == bit:
                return name
        return None

    def sig(self, n: int) -> bool:
        if n < 0:
            return not self.sig(-n)
        if n > 2000:
            return self.soft.get(n, False)
        if n > 1000:
            name = self._io_name(n - 1000, True)
            if name is not None:
                return self.plant.signal(name) != bool(self.plant.cell.io[name].active_low)
            if n == self.grip_sense:
                with self.plant.lock:
                    return self.plant.world.gripper is not None
            return False
        name = self._io_name(n, False)
        return self.plant.signal(name) if name is not None else self.outputs.get(n, False)

    def signal(self, n: int) -> None:
        on, n = n > 0, abs(n)
        if 1000 < n < 2000:
            raise VError(-412, "an input cannot be set")   # NOT CONFIRMED: number
        if n > 2000:
            self.soft[n] = on
            return
        name = self._io_name(n, False)
        if name is None:
            self.outputs[n] = on
            return
        was = self.plant.signal(name)
        self.plant.set_signal(name, on)
        if name == "vacuum" and on != was:
            self._vacuum(on)

    def _vacuum(self, on: bool) -> None:
        """The cup where the arm truly is: a grip judged by the plant, or a release."""
        with self.lock:
            x, y, z, r = self.arm.cell_pose()
        world = self.plant.world
        with self.plant.lock:
            t = world.now()
            world.robot_pose = Pose(x, y, z, r)
            if on:
                if z > GRIP_Z_MM:
                    world.counts["grip_empty"] += 1
                    return
                # the tool stands at the part's angle plus the PICK's grip turn
                # (motion_server.v2 ``pick.grip``): the world judges the footprint at
                # the tool's turn and the held part's angle from the part's (as the
                # simulated robot's PickTarget has them)
                cell = self.globals.get("pick.grip")
                grip = float(cell.v) if cell is not None and cell.v is not None else 0.0
                try:
                    world.grip(PickTarget(part_id=0, x_mm=x, y_mm=y, angle_deg=r - grip,
                                          latch=0, tracking=False, grip_deg=grip), t)
                except HalError as e:
                    self.log(f"vacuum: {e}")
            elif world.gripper is not None:
                world.release(Pose(x, y, z, r), t)

    # ------------------------------------------------------------ locations
    def compose(self, a: Any, b: Any) -> Any:
        if isinstance(a, Belt):
            return BeltLoc(a, b)
        if isinstance(a, Trans) and isinstance(b, Trans):
            return a @ b
        raise VError(-401, "':' needs two transformations")

    def fixed(self, v: Any) -> Trans:
        if isinstance(v, BeltLoc):
            return v.at(self.track_count())
        if not isinstance(v, Trans):
            raise VError(-401, "not a transformation")
        return v

    def decompose(self, v: Any) -> tuple[float, ...]:
        return self.fixed(v).decompose()

    # ------------------------------------------------------------ functions
    def func(self, task: Task, name: str, args: list[Any]) -> Any:
        f = PURE.get(name)
        if f is not None:
            return f(args)
        if name == "here":
            with self.lock:
                return self.arm.here()
        if name == "trans":
            return Trans.make(*[float(a) for a in args])
        if name == "inverse":
            return self.fixed(args[0]).inverse()
        if name in ("dx", "dy", "dz"):
            return self.fixed(args[0]).xyz["xyz".index(name[1])]
        if name == "inrange":
            return 0.0 if self.arm.in_reach(self.fixed(args[0])) else 1.0
        if name == "window":
            return self._window(args[0], float(args[1]) if len(args) > 1 else 0.0)
        if name == "belt":
            return float(self.robot_count())
        if name == "sig":
            return -1.0 if all(self.sig(int(a)) for a in args) else 0.0
        if name == "switch":
            if args[0] == "power":
                return -1.0 if self.arm.power and not self.estop() else 0.0
            return -1.0 if self.belt_switch else 0.0
        if name == "timer":
            return self.now()
        if name == "error":
            return float(task.last_error)
        if name == "iostat":
            lun = self.luns.get(int(args[0]))
            return float(lun.status if lun is not None else -527)
        raise VError(-401, f"function {name.upper()} is not in the interpreted subset")

    def _window(self, loc: Any, lead: float) -> float:
        """WINDOW(%belt:loc, time): how far inside the belt's window the location is
        ``time`` s from now (negative: outside; NOT CONFIRMED: V+'s exact value)."""
        if not isinstance(loc, BeltLoc) or loc.belt.window is None:
            return 1.0
        x = loc.belt_x(self.track_count(self.now() + lead))
        up, down = loc.belt.window
        return min(x - up, down - x)

    # ------------------------------------------------------------ statements
    def statement(self, task: Task, kw: str, args: Any) -> None:
        getattr(self, "_s_" + kw)(task, args)

    def _s_type(self, task: Task, args: Any) -> None:
        parts = [a if isinstance(a, str) else f"{a:g}" for a in (f(task) for f in args[0])]
        self.log(f"task {task.number}: " + "".join(parts))

    def _s_signal(self, task: Task, args: Any) -> None:
        for f in args[0]:
            self.signal(int(f(task)))

    def _s_enable(self, task: Task, what: str) -> None:
        if what == "power":
            if not self.estop():
                self.arm.power = True
        else:
            self.belt_switch = True

    def _s_disable(self, task: Task, what: str) -> None:
        if what == "power":
            with self.lock:
                self.arm.power = False
                self.arm.brake()
        else:
            self.belt_switch = False

    def _s_speed(self, task: Task, args: Any) -> None:
        self.arm.speed = float(args[0][0](task))

    def _s_reacte(self, task: Task, name: str) -> None:
        task.trap = name

    def _s_execute(self, task: Task, args: Any) -> None:
        number, name, fargs = args
        n = int(number(task))
        t = self.tasks[n] = Task(self, n)
        t.start(name, [f(task) for f in fargs])

    def _wait_free(self, task: Task) -> None:
        """Until the arm has ended its motion (or the arm reports an error)."""
        while True:
            with self.lock:
                m = self.arm.motion
                left = (m.t1 - self.now()) if m is not None else 0.0
            if left <= 0 or task.pending:
                return
            self.sleep(min(left, 0.005))

    def _s_break(self, task: Task, args: Any) -> None:
        self._wait_free(task)

    def _s_wait(self, task: Task, args: Any) -> None:
        if not args[0]:
            self.sleep(MAJOR_CYCLE_S)
            return
        while not args[0][0](task):
            self.sleep(MAJOR_CYCLE_S)

    def _s_brake(self, task: Task, args: Any) -> None:
        with self.lock:
            self.arm.brake()

    def _motion(self, task: Task, kind: str, target: Any) -> None:
        with self.lock:
            blend = self.arm.busy()              # reached while the arm still moves
        self._wait_free(task)
        if task.pending:
            return                               # the error comes in at the next step
        with self.lock:
            self.arm.start(kind, target, blend=blend)

    def _s_delay(self, task: Task, args: Any) -> None:
        self._motion(task, "delay", float(args[0][0](task)))

    def _s_move(self, task: Task, args: Any) -> None:
        self._motion(task, "move", args[0][0](task))

    def _s_moves(self, task: Task, args: Any) -> None:
        self._motion(task, "moves", args[0][0](task))

    def _appro(self, task: Task, args: Any, kind: str) -> None:
        loc, d = args[0][0](task), float(args[0][1](task))
        self._motion(task, kind, loc.shifted_tool_z(-d))

    def _s_appro(self, task: Task, args: Any) -> None:
        self._appro(task, args, "appro")

    def _s_appros(self, task: Task, args: Any) -> None:
        self._appro(task, args, "appros")

    def _depart(self, task: Task, args: Any, kind: str) -> None:
        d = float(args[0][0](task))
        self._wait_free(task)
        with self.lock:
            loc = self.arm.loc
        self._motion(task, kind, loc.shifted_tool_z(-d))

    def _s_depart(self, task: Task, args: Any) -> None:
        self._depart(task, args, "depart")

    def _s_departs(self, task: Task, args: Any) -> None:
        self._depart(task, args, "departs")

    def _belt(self, name: str) -> Belt:
        cell = self.globals.get(name)
        if cell is None or not isinstance(cell.v, Belt):
            cell = self.globals[name] = Cell(Belt(name))
        return cell.v

    def _s_defbelt(self, task: Task, args: Any) -> None:
        name, fs = args
        belt = self._belt(name)
        vals = [f(task) for f in fs]
        belt.nominal = self.fixed(vals[0])
        belt.encoder, belt.vavg, belt.scale = int(vals[1]), float(vals[2]), float(vals[3])

    def _s_setbelt(self, task: Task, args: Any) -> None:
        name, fs = args
        self._belt(name).latch = int(fs[0](task))

    def _s_window(self, task: Task, args: Any) -> None:
        name, (up, down, program, _mode) = args
        belt = self._belt(name)
        belt.window = (self.fixed(up(task)).xyz[0], self.fixed(down(task)).xyz[0])
        belt.window_program = program

    # ------------------------------------------------------------ TCP LUNs
    def _lun(self, task: Task, f: Callable[[Any], Any]) -> TcpLun:
        n = int(f(task))
        lun = self.luns.get(n)
        if lun is None:
            raise VError(-513, f"LUN {n} not attached")     # NOT CONFIRMED: number
        return lun

    def _s_attach(self, task: Task, args: Any) -> None:
        n = int(args[0][0](task))
        if n not in self.luns:
            self.luns[n] = TcpLun(self, n)

    def _s_fopen(self, task: Task, args: Any) -> None:
        self._lun(task, args[0][0]).fopen(args[1](task))

    def _s_fcmnd(self, task: Task, args: Any) -> None:
        lun = self._lun(task, args[0][0])
        if int(args[0][1](task)) == 640:
            lun.close_client()

    def _s_fclose(self, task: Task, args: Any) -> None:
        lun = self._lun(task, args[0][0])
        lun.close_client()
        lun.listener = None

    def _s_detach(self, task: Task, args: Any) -> None:
        self.luns.pop(int(args[0][0](task)), None)

    def _s_read(self, task: Task, args: Any) -> None:
        (lun_f, handle_ref, mode_f), var_ref = args
        lun = self._lun(task, lun_f)
        status, handle, line = lun.read(int(mode_f(task)) if mode_f else 0)
        handle_ref(task).v = float(handle)
        if status == 1:
            var_ref(task).v = line

    def _s_write(self, task: Task, args: Any) -> None:
        lun = self._lun(task, args[0][0])
        handle = int(args[0][1](task)) if len(args[0]) > 1 else 0
        lun.write(handle, args[1](task) if args[1] is not None else "")
