"""A client that hangs up mid-request is no bug of ours: the dashboard logs nothing for
it, while a real bug still gets its one line and a 500."""

from __future__ import annotations

import asyncio

from starlette.requests import ClientDisconnect

from feeder_bt.ui.responses import SecurityHeaders


def _call(exc: Exception, capsys) -> tuple[list[dict], str]:
    async def app(scope, receive, send):
        raise exc

    sent: list[dict] = []

    async def receive():
        return {"type": "http.disconnect"}

    async def send(message):
        sent.append(message)

    scope = {"type": "http", "method": "POST", "path": "/api/stop", "headers": []}
    asyncio.run(SecurityHeaders(app)(scope, receive, send))
    return sent, capsys.readouterr().err


def test_a_client_that_hangs_up_is_not_logged_as_an_internal_error(capsys):
    sent, err = _call(ClientDisconnect(), capsys)
    assert err == "" and sent == []


def test_a_bug_still_gets_one_line_and_a_500(capsys):
    sent, err = _call(ValueError("boom"), capsys)
    assert err.count("\n") == 1 and "internal error: ValueError" in err
    assert sent[0]["type"] == "http.response.start" and sent[0]["status"] == 500
