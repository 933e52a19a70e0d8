"""The Adept robot controller over the V+ server programs of ``vplus/`` (TCP, line protocol
documented in ``vplus/PROTOCOL.md``)."""

from feeder_bt.hal.adept.controller import AdeptController
from feeder_bt.hal.adept.protocol import ProtocolError, VplusError
from feeder_bt.hal.adept.robot import AdeptIO, AdeptRobot, AdeptRobotPosition

__all__ = ["AdeptController", "AdeptIO", "AdeptRobot", "AdeptRobotPosition", "ProtocolError",
           "VplusError"]
