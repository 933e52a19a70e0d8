"""The plant adapters of one run (``feeder run --part-server`` / ``--opcua``), put together.

run.py opens them after the scenario is loaded, calls ``pump()`` after every tick (on the
tick thread: the desk answers robots while the cell is not feeding, the simulated robot
program takes its next step, the OPC UA server's commands run and its variables are
published) and ``close()`` at the end.
"""

from __future__ import annotations

import sys
from typing import Any

from feeder_bt.behaviours.desk import Desk
from feeder_bt.control.cell import Cell
from feeder_bt.core.addresses import parse_hostport
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import FeederError
from feeder_bt.plant.options import PlantOptions


def _world_check(world: Any) -> Any:
    """On the simulated cell: a PLACED is believed only if the world placed one more part
    of that type than the PLACED reports already believed (the world's ids are not the
    cell's: it counts by type). Not a leak of truth to vision: it judges robots' reports,
    as the report's accounting does."""
    from collections import Counter
    believed: Counter[str] = Counter()

    def check(part: Any) -> bool:
        if believed[part.type] >= world.placed_by_type[part.type]:
            return False
        believed[part.type] += 1
        return True

    return check


class PlantAdapters:
    """Whatever of the part server, the simulated robot and OPC UA this run serves."""

    def __init__(self, cell: Cell, opts: PlantOptions, scenario_path: str | None = None,
                 cell_path: str | None = None, fast: bool = False) -> None:
        self.cell, self.opts, self.fast = cell, opts, fast
        self.desk: Desk | None = None
        self.server = None
        self.program = None
        self.opcua = None
        self.scenario_path, self.cell_path = scenario_path, cell_path

    def open(self) -> None:
        cell, opts = self.cell, self.opts
        if opts.part_server:
            from feeder_bt.plant.part_server import DEFAULT_PORT, PartServer, install
            host, port = parse_hostport(opts.part_server, DEFAULT_PORT, "--part-server")
            from feeder_bt.plant.robots import RobotTrust
            trust = RobotTrust.load(opts.robots)
            self.desk = Desk(cell.clock, pick_grace_s=opts.pick_grace_s)
            install(cell, self.desk)
            world = cell.hal.truth
            if world is not None:
                self.desk.verify_placed = _world_check(world)
            self.trust = trust
            try:
                self.server = PartServer(self.desk, host, port, trust)
                where = self.server.start()
            except OSError as e:
                raise FeederError(f"--part-server {opts.part_server}: {e.strerror or e}") \
                    from None
            print(f"part server: {where}", file=sys.stderr, flush=True)
            if opts.sim_robot and cell.hal.truth is not None:
                self.program = self._sim_robot(where)
            if opts.sim_robot_port:
                self._robot_port(opts.sim_robot_port)
        if opts.opcua:
            from feeder_bt.plant.opcua import CellUaServer
            self.opcua = CellUaServer(cell, opts, self.scenario_path, self.cell_path)
            url = self.opcua.start()
            print(f"OPC UA: {url}", file=sys.stderr, flush=True)

    def _sim_robot(self, where: str):
        """The simulated robot's program: over TCP in real time, lock-step in a fast run
        (a socket's timing would make a virtual-time run depend on the machine)."""
        from feeder_bt.plant.client import LoopLink, PartClient, TcpLink
        from feeder_bt.plant.sim_robot import SimRobotProgram
        cell = self.cell
        assert self.desk is not None and cell.scenario is not None
        if isinstance(cell.clock, SimClock) and self.fast:
            link = LoopLink(self.desk, cell.clock)
        else:
            host, _, port = where.rpartition(":")
            link = TcpLink(host, int(port))
            client = PartClient(link)
            if self.trust.robots:            # it proves who it is, like any robot
                try:
                    client.hello("sim-robot", self.trust.add_runtime("sim-robot"))
                except FeederError as e:
                    raise FeederError(f"the simulated robot was refused: {e}") from None
            return SimRobotProgram(client, cell.hal.robot, cell.scenario, cell.clock)
        return SimRobotProgram(PartClient(link), cell.hal.robot, cell.scenario, cell.clock)

    trust = None
    robot_port = None

    def _robot_port(self, text: str) -> None:
        """The simulated robot's port for an outside program (--sim-robot-port)."""
        from feeder_bt.plant.robot_port import RobotPort
        cell, opts = self.cell, self.opts
        if opts.sim_robot or cell.hal.truth is None:
            raise FeederError("--sim-robot-port: with --no-sim-robot on the simulated cell "
                              "(the built-in program would move the same robot)")
        host, port = parse_hostport(text, 7601, "--sim-robot-port")
        self.robot_port = RobotPort(cell.hal.robot, cell.scenario, host, port)
        try:
            where = self.robot_port.start()
        except OSError as e:
            raise FeederError(f"--sim-robot-port {text}: {e.strerror or e}") from None
        print(f"simulated robot port: {where}", file=sys.stderr, flush=True)

    def pump(self) -> None:
        """After each tick, on the tick thread."""
        if self.program is not None:
            self.program.step()
        if self.robot_port is not None:
            self.robot_port.pump()
        if self.desk is not None:
            self.desk.serve_idle()
        if self.opcua is not None:
            self.opcua.pump()

    def closing(self) -> None:
        if self.opcua is not None:
            self.opcua.closing()

    def close(self) -> None:
        if self.program is not None:
            self.program.kill()
        if self.robot_port is not None:
            self.robot_port.close()
        if self.server is not None:
            self.server.close()
        if self.opcua is not None:
            self.opcua.close()

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.server is not None:
            out["part_server"] = self.server.report()
            if self.program is not None:
                out["part_server"]["sim_robot"] = dict(self.program.counts)
            if self.robot_port is not None:
                out["part_server"]["sim_robot_port"] = dict(self.robot_port.counts)
        if self.opcua is not None:
            out["opcua"] = self.opcua.report()
        return out
