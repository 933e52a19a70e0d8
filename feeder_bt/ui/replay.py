"""``feeder replay FILE.db --ui``: the dashboard's tree view over a past run, with its
timeline, served read-only from the event log until Ctrl-C.

No cell and no commands, but the blackboard and every node of a run are the cell's
business: a viewer signs in with the dashboard's users file (``replay_login``).
Like the operator UI it listens on 127.0.0.1 by default, answers only to the Host names of
the address it is bound to (a DNS-rebinding page cannot read the log), with the same
security headers and connection limits. uvicorn runs on the main thread's loop, which is
also the only thread that reads the database.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import FileResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from feeder_bt.control.access import Gate, Settings, allowed_hosts
from feeder_bt.control.conns import ConnGate, ConnLimits, quiet_logger
from feeder_bt.core.errors import FeederError
from feeder_bt.records.eventlog import open_readonly
from feeder_bt.records.treelog import TraceView, read_trace
from feeder_bt.ui import parse_bind
from feeder_bt.ui.listener import _bind, is_loopback, make_notice, uvicorn_config
from feeder_bt.ui.replay_login import ReplayLogin
from feeder_bt.ui.responses import SecurityHeaders
from feeder_bt.ui.treedata import tree_routes

STATIC = Path(__file__).parent / "static"


def replay_app(view: TraceView, host: str, login: ReplayLogin,
               extra_hosts: tuple[str, ...] = ()) -> Starlette:
    """The read-only app over one run's recorded trees, for signed-in users; it answers to
    the bound address's names and the users file's ``hosts``."""
    hosts = allowed_hosts(host, extra_hosts)

    async def page(request: Request) -> Response:
        name = "replay.html" if login.session(request) is not None else "replay_login.html"
        return FileResponse(STATIC / name, headers={"cache-control": "no-store"})

    def refused(ip: str, why: str) -> None:
        print(f"feeder replay: refused a request from {ip}: {why}", file=sys.stderr)

    return Starlette(routes=[
        Route("/", page),
        *login.routes,
        *tree_routes(lambda: view, login.may_read, live=False),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ], middleware=[Middleware(SecurityHeaders),
                   Middleware(Gate, hosts=lambda: hosts, proxies=lambda: (),
                              refused=refused)])


def serve_replay(db: str | Path, run_id: int, bind: str,
                 users_path: str | Path | None = None) -> int:
    """Serve until Ctrl-C; the line ``replay UI: URL`` on standard error says where."""
    import uvicorn

    from feeder_bt.ui.app import check_users
    try:
        host, port = parse_bind(bind)
    except argparse.ArgumentTypeError as e:
        raise FeederError(f"--ui: {e}") from None
    users = check_users(users_path)          # somebody must be able to sign in
    sock = _bind(host, port)
    port = sock.getsockname()[1]
    print(protection_notice(host, users.path), file=sys.stderr)
    notice = make_notice(host, "the replay UI")
    if notice:
        print(notice, file=sys.stderr)
    conn = open_readonly(db)
    view = read_trace(conn, run_id)
    gate = ConnGate("replay UI", ConnLimits(total=256, per_address=32))
    login = ReplayLogin(users)
    extra = Settings.of(users.section("settings")).hosts
    server = uvicorn.Server(uvicorn_config(replay_app(view, host, login, extra), gate))

    async def serve() -> None:
        gate.loop_errors(asyncio.get_running_loop())
        unquiet = quiet_logger("uvicorn.error", gate)
        try:
            await server.serve(sockets=[sock])
        finally:
            unquiet()

    shown = f"[{host}]" if ":" in host else host
    print(f"replay UI: http://{shown}:{port}/ (run {run_id}; Ctrl-C to stop)",
          file=sys.stderr, flush=True)
    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
        conn.close()
    return 0


def protection_notice(host: str, users: Path) -> str:
    """What protects this replay server, said at start-up."""
    where = "this machine only" if is_loopback(host) else f"the network ({host})"
    return (f"feeder replay: reachable from {where}; every page but the login needs a "
            f"session from the users file {users}; Host names are checked, connections "
            "capped per address and in all")
