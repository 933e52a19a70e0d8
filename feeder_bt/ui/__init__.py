"""The operator UI (thesis chapter 4): a web dashboard served by ``feeder run --ui``.

Many logged-in users watch; one at a time holds control and operates the cell. The pieces:

- ``users``: the users file (salted scrypt hashes, roles, access settings) behind
  ``feeder users``;
- ``control``: sessions, the control token and the failed-login limiter (web thread only);
- ``guard``: judging login attempts so that guessing never locks the rightful user out;
- ``access``: what every operator surface shares: settings, defensive body parsing, the
  Host allow-list and forwarded headers, and the record of refusals;
- ``bridge``: the only way between the web thread and the cell: commands queued to the tick
  thread, immutable status snapshots published back;
- ``operate`` and ``status``: what the tick thread does with a command, and what it puts
  in a snapshot;
- ``server``: the Starlette app (``responses``: its stateless HTTP pieces), ``serve``: the
  uvicorn thread; ``static/``: the page;
- ``treedata``: the tree view's data (the trees' history, ``feeder_bt.records.treelog``) for
  ``static/tree.js``; ``replay``: that view alone over a past run (``feeder replay --ui``);
- ``app``: all of it put together for ``feeder run --ui`` (run.py).

This module stays import-light (no web framework) so that the command line can parse
``--ui HOST:PORT`` without loading the server.
"""

from __future__ import annotations

import argparse

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_BIND = f"{DEFAULT_HOST}:{DEFAULT_PORT}"


def parse_bind(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:8080`` for IPv6, ``:8080`` for loopback) to (host, port).

    Port 0 lets the system choose a free port (the URL is printed when the UI starts).
    """
    text = text.strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, e.g. {DEFAULT_BIND}, got {text!r}")
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port must be a number, got {port_text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 0..65535, got {port}")
    return host, port
