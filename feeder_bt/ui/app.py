"""``feeder run --ui``: the operator UI put together for one run.

run.py creates an ``OperatorUi`` on the main thread, calls ``pump()`` after every tick
(commands run there, snapshots are published there) and ``close()`` at the end; the web
server's thread sees only the bridge.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from feeder_bt.control.access import Settings
from feeder_bt.control.bridge import Bridge, Snapshot
from feeder_bt.control.cell import Cell
from feeder_bt.control.operate import CellOps
from feeder_bt.control.status import CellPanel
from feeder_bt.control.users import UsersError, UsersFile, group_or_world_readable
from feeder_bt.ui.belt import BeltPanel
from feeder_bt.ui.camera import CameraFeed
from feeder_bt.ui.listener import UiServer, make_notice
from feeder_bt.ui.server import UiApp
from feeder_bt.vision.latest import LatestLook
from feeder_bt.vision.pixels import Calibration

_WARNED: set[Path] = set()


def check_users(path: str | Path | None) -> UsersFile:
    """The users file for ``--ui``: it must exist, name somebody who can log in, hold
    valid settings, and (if the settings say so) be private to its owner."""
    users = UsersFile(path)
    if not users.names():               # a damaged file is a one-line UsersError here
        hint = f" --users {path}" if path else ""
        raise UsersError(f"no users in {users.path}: nobody could log in; add one with "
                         f"`feeder users add NAME{hint}`")
    settings = Settings.of(users.section("settings"), f"{users.path}: settings")
    if group_or_world_readable(users.path):
        what = (f"{users.path} may be read by other users of this machine (its password "
                f"hashes can be guessed offline): chmod 600 {users.path}")
        if settings.readable_users_file == "refuse":
            raise UsersError(f"refused: {what}")
        if users.path not in _WARNED:          # run.py checks first, then the UI again
            _WARNED.add(users.path)
            print(f"feeder: warning: {what}", file=sys.stderr)
    return users


class OperatorUi:
    """The bridge, the cell's panel and commands, and the web server of one run."""

    def __init__(self, cell: Cell, scenario_path: str | Path, cell_file: str | Path,
                 host: str, port: int, users_path: str | Path | None = None,
                 t0: float | None = None, trace: Any = None) -> None:
        users = check_users(users_path)
        self.ops = CellOps(cell, Path(scenario_path).resolve().parent, Path(cell_file))
        self.panel = CellPanel(cell, self.ops.limits, lambda: sorted(self.ops.scenarios), t0)
        self.cell, self.belt = cell, BeltPanel(cell)
        self.camera = CameraFeed(LatestLook(), Calibration(cell.cell.camera.calibration))
        self.bridge = Bridge(self.ops.execute, self._snapshot)
        self.web = UiApp(self.bridge, users, host=host, camera=self.camera)
        self.trace = trace              # treelog.TreeTrace: the tree view and its timeline
        if trace is not None:
            self.web.trace_view = lambda: trace.published
        self.server = UiServer(self.web, host, port)
        self.url = ""

    def start(self) -> str:
        """Publish a first snapshot, then serve; returns the URL (port 0 resolved)."""
        self.bridge.publish()
        self.url = self.server.start()
        notice = make_notice(self.server.host)
        if notice:
            print(notice, file=sys.stderr)
        return self.url

    def pump(self) -> None:
        """After each tick, on the tick thread."""
        self.bridge.pump()
        self.camera.install(self.cell.ctx)       # a start makes a new context

    def _snapshot(self) -> Snapshot:
        status, history, messages = self.panel.snapshot()
        return {**status, "belt": self.belt.snapshot()}, history, messages

    def closing(self) -> None:
        """The run is ending: refuse commands from now on; keep showing the clean-up."""
        self.bridge.close()

    def close(self) -> None:
        """Publish the final state, then stop the server (its thread ends)."""
        self.bridge.close()
        self.bridge.pump(force=True)
        self.server.close()

    def report(self) -> dict[str, Any]:
        return {"url": self.url, **self.ops.report()}
