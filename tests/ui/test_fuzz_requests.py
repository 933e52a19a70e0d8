"""No malformed unauthenticated request gets a 5xx, and none fills the log. A real
`feeder run --ui` on loopback is sent, over raw sockets, long numbers in every route
parameter and query, long and many headers, cut and broken bodies."""

from __future__ import annotations

import socket

import pytest

from tests.support.uiutil import FeederUi, make_users

NINES = "9" * 4301


def _exchange(port: int, raw: bytes, half_close: bool = False) -> int | None:
    """Send ``raw``; the status code of the answer, or None if the server just closed."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(raw)
        if half_close:
            s.shutdown(socket.SHUT_WR)
        data = b""
        while b"\r\n" not in data:
            try:
                chunk = s.recv(4096)
            except ConnectionResetError:
                return None
            if not chunk:
                return None
            data += chunk
    return int(data.split(b" ", 2)[1])


def _get(path: str, headers: str = "") -> bytes:
    return (f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n{headers}"
            "Connection: close\r\n\r\n").encode()


def _post(path: str, body: bytes, length: int | None = None) -> bytes:
    n = len(body) if length is None else length
    return (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            f"Content-Length: {n}\r\nConnection: close\r\n\r\n").encode() + body


CASES = [
    ("camera frame of 4301 digits", _get(f"/api/camera/{NINES}.jpg"), False),
    ("camera frame, negative", _get("/api/camera/-1.jpg"), False),
    ("camera frame, Arabic digits", _get("/api/camera/%D9%A1%D9%A2.jpg"), False),
    ("camera frame, no extension", _get(f"/api/camera/{NINES}"), False),
    ("camera, long path", _get("/api/camera/" + "a/" * 3000), False),
    ("tree at 4301 digits", _get(f"/api/tree/at?t={NINES}"), False),
    ("tree at 1e999", _get("/api/tree/at?t=1e999"), False),
    ("tree at NaN", _get("/api/tree/at?t=nan"), False),
    ("tree nodes with a tail", _get(f"/api/tree/nodes/{NINES}"), False),
    ("static, long name", _get("/static/" + "x" * 5000), False),
    ("static, escape", _get("/static/../../../../etc/passwd"), False),
    ("static, NUL", _get("/static/a%00b.js"), False),
    ("the websocket by GET", _get("/ws"), False),
    ("a header of 20 kB", _get("/api/me", "X-Long: " + "a" * 20000 + "\r\n"), False),
    ("500 headers", _get("/api/me", "".join(f"X-{i}: {i}\r\n" for i in range(500))), False),
    ("a cookie of 4301 digits", _get("/api/me", f"Cookie: feeder_session={NINES}\r\n"), False),
    ("a login cut short", _post("/api/login", b'{"user": "al', 100), True),
    ("a login of broken JSON", _post("/api/login", b'{"user": "alice", "pass'), False),
    ("a login of a long number", _post("/api/login", b'{"user": ' + NINES.encode() + b"}"),
     False),
    ("a command of a long number",
     _post("/api/command", b'{"command": "speeds", "robot_speed_pct": ' + NINES.encode() +
           b"}"), False),
    ("a body longer than said", _post("/api/control", b'{"action": "take"}' * 10, 5), False),
    ("a chunked body cut", b"POST /api/login HTTP/1.1\r\nHost: 127.0.0.1\r\n"
     b"Transfer-Encoding: chunked\r\nContent-Type: application/json\r\n\r\nfff\r\n{", True),
    ("a request line of garbage", b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" * 40, True),
    ("no Host", b"GET /api/me HTTP/1.1\r\nConnection: close\r\n\r\n", False),
]


@pytest.fixture(scope="module")
def ui(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    server = FeederUi(tmp, make_users(tmp / "users.json", {"alice": "alice-secret-1"}))
    server.port = int(server.url.rsplit(":", 1)[1].strip("/"))
    yield server
    server.kill()


@pytest.mark.parametrize("raw,half", [(c[1], c[2]) for c in CASES], ids=[c[0] for c in CASES])
def test_no_malformed_request_gets_a_5xx(ui, raw, half):
    status = _exchange(ui.port, raw, half)
    assert status is None or 400 <= status < 500, status


def test_the_log_stays_small_after_the_fuzzing(ui):
    for _, raw, half in CASES:
        _exchange(ui.port, raw, half)
    err = ui.err.read_text()
    assert "Traceback" not in err and NINES not in err
    assert all(len(line) < 400 for line in err.splitlines()), err[-2000:]
