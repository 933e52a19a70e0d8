"""HTTP pieces of the operator UI that know nothing of its state: the security headers
(and the last-resort answer to a bug), the same-origin check, and JSON answers."""

from __future__ import annotations

import sys
from typing import Any

from starlette.requests import ClientDisconnect, HTTPConnection, Request
from starlette.responses import JSONResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

SECURITY_HEADERS = [
    (b"content-security-policy",
     b"default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
     b"connect-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
]


class SecurityHeaders:
    """Adds ``SECURITY_HEADERS`` to every HTTP response, and answers a bug with one line
    (500, no traceback, one line on standard error) instead of Starlette's error page."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def send_with_headers(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message = {**message, "headers": [*message.get("headers", []),
                                                  *SECURITY_HEADERS]}
            await send(message)

        try:
            await self.app(scope, receive, send_with_headers)
        except ClientDisconnect:               # the client hung up mid-request: no bug,
            return                             # and nobody is left to answer
        except Exception as e:                 # a bug: one line, never a traceback
            print(f"feeder: operator UI: {str(scope.get('method'))[:16]} "
                  f"{short_path(scope.get('path'))}: internal error: {type(e).__name__}",
                  file=sys.stderr)
            if not started:
                await refuse("internal error; nothing was changed", 500)(
                    scope, receive, send_with_headers)


def short_path(path: object, limit: int = 80) -> str:
    """A request path as it may be logged: at most ``limit`` characters and its length
    (a path of megabytes must not become megabytes of log)."""
    text = str(path)
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}... ({len(text)} chars)"


def same_origin(conn: HTTPConnection) -> bool:
    """A browser always sends ``Origin`` on POSTs and websockets; it must be this server,
    scheme included. (A client without one, such as curl, is not a browser that a third
    site can drive.)"""
    origin = conn.headers.get("origin")
    if origin is None:
        return True
    scheme = "https" if conn.url.scheme in ("https", "wss") else "http"
    return origin.lower() == f"{scheme}://{conn.headers.get('host', '').lower()}"


def json_response(data: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return JSONResponse(data, status_code=status,
                        headers={"cache-control": "no-store", **(headers or {})})


def refuse(message: str, status: int, headers: dict[str, str] | None = None) -> Response:
    return json_response({"ok": False, "error": message}, status, headers)


def client_ip(conn: HTTPConnection) -> str:
    return conn.client.host if conn.client else "?"


async def json_body(request: Request, max_bytes: int) -> dict[str, Any] | Response:
    """The JSON object of a state-changing request, or the refusal to send back: another
    site's Origin, not JSON, over ``max_bytes``, or not one JSON object. One reader for the
    dashboard and the replay's login."""
    from feeder_bt.control.access import BadBody, parse_body
    if not same_origin(request):
        return refuse("refused: request from another site", 403)
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        return refuse("expected a JSON body (Content-Type: application/json)", 415)
    raw = b""
    async for chunk in request.stream():
        raw += chunk
        if len(raw) > max_bytes:
            return refuse("request too large", 413)
    try:
        return parse_body(raw)
    except BadBody as e:
        return refuse(str(e), 400)
