"""``feeder replay FILE.db --ui``: the dashboard's tree view over a past run, with its
timeline, served read-only from the event log until Ctrl-C.

No cell and no commands, so no login: like the operator UI it listens on 127.0.0.1 by
default and answers only to the Host names of the address it is bound to (a DNS-rebinding
page cannot read the log), with the same security headers. uvicorn runs on the main
thread's loop, which is also the only thread that reads the database.
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

from ..errors import FeederError
from ..eventlog import open_readonly
from ..treelog import TraceView, read_trace
from . import parse_bind
from .access import Gate, allowed_hosts
from .conns import ConnGate, ConnLimits, quiet_logger
from .responses import SecurityHeaders
from .serve import _bind, make_notice, uvicorn_config
from .treedata import tree_routes

STATIC = Path(__file__).parent / "static"


def replay_app(view: TraceView, host: str) -> Starlette:
    """The read-only app over one run's recorded trees."""
    hosts = allowed_hosts(host)

    async def page(request: Request) -> Response:
        return FileResponse(STATIC / "replay.html", headers={"cache-control": "no-store"})

    def refused(ip: str, why: str) -> None:
        print(f"feeder replay: refused a request from {ip}: {why}", file=sys.stderr)

    return Starlette(routes=[
        Route("/", page),
        *tree_routes(lambda: view, lambda request: None, live=False),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ], middleware=[Middleware(SecurityHeaders),
                   Middleware(Gate, hosts=lambda: hosts, proxies=lambda: (),
                              refused=refused)])


def serve_replay(db: str | Path, run_id: int, bind: str) -> int:
    """Serve until Ctrl-C; the line ``replay UI: URL`` on standard error says where."""
    import uvicorn
    try:
        host, port = parse_bind(bind)
    except argparse.ArgumentTypeError as e:
        raise FeederError(f"--ui: {e}") from None
    sock = _bind(host, port)
    port = sock.getsockname()[1]
    notice = make_notice(host)
    if notice:
        print(notice, file=sys.stderr)
    conn = open_readonly(db)
    view = read_trace(conn, run_id)
    gate = ConnGate("replay UI", ConnLimits(total=256, per_address=32))
    server = uvicorn.Server(uvicorn_config(replay_app(view, host), gate))

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
