"""The Adept robot controller over the V+ server programs of ``vplus/`` (TCP, line protocol
documented in ``vplus/PROTOCOL.md``)."""

from .controller import AdeptController
from .protocol import ProtocolError, VplusError
from .robot import AdeptIO, AdeptRobot, AdeptRobotPosition

__all__ = ["AdeptController", "AdeptIO", "AdeptRobot", "AdeptRobotPosition", "ProtocolError",
           "VplusError"]
