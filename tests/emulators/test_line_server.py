"""The small emulators' serving loop (``emulators.line_server``): lines cut out of whatever
chunks the client sends, one client at a time, and a client that goes while it is being
answered ends only its own session."""

from __future__ import annotations

import socket

from feeder_bt.emulators.line_server import LineServer


class Echo(LineServer):
    terminator = b"\r"

    def __init__(self) -> None:
        super().__init__()
        self.lines: list[bytes] = []

    def on_line(self, conn: socket.socket, line: bytes) -> None:
        self.lines.append(line)
        if line == b"gone":
            raise BrokenPipeError("the client went")      # as sendall to a closed peer
        conn.sendall(line.upper() + b"\r")


def read_until(f, n: int) -> bytes:
    out = b""
    while out.count(b"\r") < n:
        chunk = f.recv(4096)
        assert chunk, out
        out += chunk
    return out


def test_lines_across_chunks_and_a_client_that_goes_ends_only_its_session():
    srv = Echo().start()
    try:
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as c:
            c.sendall(b"ab")
            c.sendall(b"c\rde")
            c.sendall(b"f\r\r")
            assert read_until(c, 3) == b"ABC\rDEF\r\r"
            c.sendall(b"gone\rnever\r")
            assert c.recv(4096) == b""                     # the session ended there
        assert srv.lines == [b"abc", b"def", b"", b"gone"]
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as c:
            c.sendall(b"again\r")
            assert read_until(c, 1) == b"AGAIN\r"          # the next client is served
    finally:
        srv.stop()
