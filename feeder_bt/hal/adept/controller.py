"""The Adept controller as the HAL sees it: robot, robot position and I/O over the four
V+ server sockets of ``vplus/`` (motion, position, I/O, I/O notify; ``vplus/PROTOCOL.md``).
"""

from __future__ import annotations

from collections.abc import Iterable

from ...clock import Clock
from ...errors import CommsLost, HalError
from ...scenario.model import AdeptSpec
from . import protocol
from .client import LineSocket, ServerClient
from .robot import AdeptIO, AdeptRobot, AdeptRobotPosition


class AdeptController:
    """Connect to the V+ servers, check each is the server it should be, and start the
    position poller and the notify listener. ``.robot``, ``.position``, ``.io``.

    ``inputs``: the cell description's Adept input bits, read once at start-up (inputs the
    notify socket reports are learned anyway). Raises ``CommsLost`` if a server does not
    answer within ``spec.timeout_s``.
    """

    def __init__(self, spec: AdeptSpec, clock: Clock, inputs: Iterable[int] = ()) -> None:
        self.spec, self.clock = spec, clock
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

    def _hello(self, name: str, client: ServerClient) -> None:
        version, server = protocol.decode_hello(client.call("HELLO"))
        if server != name:
            raise CommsLost(f"{client.link.where}: answers as the {server!r} server: "
                            "check the ports in the cell description")
        if version != protocol.PROTOCOL_VERSION:
            raise HalError(f"{client.link.where}: protocol version {version}, this driver "
                           f"speaks {protocol.PROTOCOL_VERSION}: load the matching vplus/ programs")

    def close(self) -> None:
        """Stop the poller and listener, close every socket and worker."""
        for client in self.clients.values():     # first: wakes any blocked request
            client.close()
        self.notify_link.close()
        self.position.stop()
        self.io.stop()
