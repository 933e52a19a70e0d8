"""The Adept controller as the HAL sees it: robot, robot position and I/O over the four
V+ server sockets of ``vplus/`` (motion, position, I/O, I/O notify; ``vplus/PROTOCOL.md``).
"""

from __future__ import annotations

from collections.abc import Iterable

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import CommsLost, HalError
from feeder_bt.core.model import AdeptSpec, RobotSpec
from feeder_bt.hal.adept import protocol
from feeder_bt.hal.adept.client import LineSocket, ServerClient
from feeder_bt.hal.adept.robot import AdeptIO, AdeptRobot, AdeptRobotPosition

HEARTBEAT_S = 1.0      # the motion socket's keep-alive; the V+ server drops a client
                       # silent for link.idle (5 s, vplus/a_server.v2)


class AdeptController:
    """Connect to the V+ servers, check each is the server it should be, and start the
    position poller and the notify listener. ``.robot``, ``.position``, ``.io``.

    ``inputs``: the cell description's Adept input bits, read once at start-up (inputs the
    notify socket reports are learned anyway). Raises ``CommsLost`` if a server does not
    answer within ``spec.timeout_s``.

    ``robot``: the cell description's robot, whose base pose (``base_mm``, ``base_deg``) and
    safe pose go to the motion server as FRAME and DEFSAFE on every (re)connection of the
    motion socket, before any motion (vplus/PROTOCOL.md, "Frames"); without them V+
    answers every motion -9008. ``estop``: the e-stop's V+ input, negative when active low
    (``protocol.estop_signal``), sent as ESTOP; None leaves the V+ default (input 1001).
    ``counts_per_mm``: the belt encoder's counts per mm, sent (signed by
    ``spec.belt_direction``) as BELTSCALE; None leaves the V+ program's ``belt.scale``.
    ``window``: the belt window (upstream, downstream, pick limit; belt-frame x, mm;
    ``core.model.belt_window``), sent as WINDOW; None leaves the V+ program's.
    """

    def __init__(self, spec: AdeptSpec, clock: Clock, inputs: Iterable[int] = (),
                 robot: RobotSpec | None = None, estop: int | None = None,
                 counts_per_mm: float | None = None,
                 window: tuple[float, float, float] | None = None) -> None:
        self.spec, self.clock = spec, clock
        self.robot_spec, self.estop, self.counts_per_mm = robot, estop, counts_per_mm
        self.window = window
        host, t = spec.host, spec.timeout_s
        self.clients = {
            "motion": ServerClient("motion", host, spec.motion_port, t),
            "position": ServerClient("position", host, spec.position_port, t),
            "io": ServerClient("io", host, spec.io_port, t),
        }
        self.notify_link = LineSocket("notify", host, spec.notify_port, t)
        sign = -1 if spec.belt_direction == "reverse" else 1
        self.robot = AdeptRobot(self.clients["motion"], clock, spec.motion_timeout_s, t,
                                stopper=self.clients["position"],
                                recover_power_on=spec.recover_power_on, belt_sign=sign)
        self.position = AdeptRobotPosition(self.clients["position"], 1.0 / spec.poll_hz,
                                           belt_sign=sign)
        self.io = AdeptIO(self.clients["io"], self.notify_link, clock, inputs)
        self.clients["motion"].link.on_connect = self._set_up_motion
        try:
            for name, client in self.clients.items():
                self._hello(name, client)
            self.robot.refresh_holding()
            self.position.read_once()
            self.io.read_inputs()
        except BaseException:
            self.close()
            raise
        self.position.start()
        self.io.start()
        # the motion socket is idle between picks: a heartbeat finds a dead link in seconds
        self.clients["motion"].keep_alive("HOLDING", HEARTBEAT_S)

    def _hello(self, name: str, client: ServerClient, timeout: float | None = None) -> None:
        version, server = protocol.decode_hello(client.call("HELLO", timeout=timeout))
        if server != name:
            raise CommsLost(f"{client.link.where}: answers as the {server!r} server: "
                            "check the ports in the cell description")
        if version != protocol.PROTOCOL_VERSION:
            raise HalError(f"{client.link.where}: protocol version {version}, this driver "
                           f"speaks {protocol.PROTOCOL_VERSION}: load the matching vplus/ programs")

    def _set_up_motion(self) -> None:
        """Every new motion connection: check the server, then FRAME, DEFSAFE, BELTSCALE,
        WINDOW and ESTOP,
        before any motion (the V+ program may have restarted and forgotten them)."""
        client = self.clients["motion"]
        t = self.spec.motion_timeout_s      # a motion whose link was cut runs on: the
        self._hello("motion", client, t)    # server answers once it has ended
        if self.robot_spec is not None:
            r = self.robot_spec
            client.call("FRAME", *protocol.frame_args(r.base_mm, r.base_deg), timeout=t)
            client.call("DEFSAFE", float(r.safe_mm[0]), float(r.safe_mm[1]), 0.0, 0.0,
                        timeout=t)
        if self.counts_per_mm:
            sign = -1.0 if self.spec.belt_direction == "reverse" else 1.0
            client.call("BELTSCALE", sign / self.counts_per_mm, timeout=t)
        if self.window is not None:
            client.call("WINDOW", *(round(float(v), 3) for v in self.window), timeout=t)
        if self.estop is not None:
            client.call("ESTOP", int(self.estop), timeout=t)

    def close(self) -> None:
        """Stop the poller and listener, close every socket and worker."""
        for client in self.clients.values():     # first: wakes any blocked request
            client.close()
        self.notify_link.close()
        self.position.stop()
        self.io.stop()
