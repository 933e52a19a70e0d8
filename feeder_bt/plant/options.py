"""What ``feeder run`` was asked to open to the plant floor (the part server, OPC UA, an
outside robot): one record every adapter reads."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class PlantOptions:
    part_server: str | None = None      # "[HOST:]PORT"
    sim_robot: bool = True              # on the simulated cell: drive its robot through
                                        # the reference client
    pick_grace_s: float = 5.0
    robots: str | None = None           # the robots file: who may take parts (robots.py)
    sim_robot_port: str | None = None   # "[HOST:]PORT": an outside program moves the
                                        # simulated robot (robot_port.py)
    opcua: str | None = None            # "[HOST:]PORT"
    opcua_users: str | None = None
    opcua_insecure: bool = False        # an unsecured endpoint too (loopback only)
    opcua_pki: str | None = None
