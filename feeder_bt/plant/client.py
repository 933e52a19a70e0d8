"""The reference robot client of the part server (docs/part-server.md).

A robot program in Python (or a PC beside a robot controller) uses ``PartClient``::

    with PartClient.connect("127.0.0.1", 7600) as parts:
        offer = parts.part("lens", wait=5.0)       # None: nothing within the wait
        if offer is not None:
            ...                                    # pick at offer.x, offer.y (+ tracking)
            parts.picked(offer.id)
            ...                                    # place
            parts.placed(offer.id)

Every call sends one line and reads one reply. For a program that must never block (the
simulated robot, which runs on the cell's tick thread), ``submit`` sends and ``poll``
returns the next reply when it has come. A ``Link`` carries the lines: ``TcpLink`` over a
socket, ``LoopLink`` straight into a desk in the same process (lock-step with virtual
time, for deterministic tests and ``--fast`` runs).
"""

from __future__ import annotations

import select
import socket
from collections import deque
from collections.abc import Hashable
from typing import Protocol

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import FeederError
from feeder_bt.core.part_protocol import (
    MAX_LINE,
    Offer,
    ProtocolError,
    parse_offer,
    parse_reply,
    parse_status,
    prove,
    secret_key,
)


class PartServerError(FeederError):
    """The part server refused a request (``ERR ...``), or the link failed."""


class Link(Protocol):
    def send(self, line: str) -> None: ...

    def receive(self, timeout: float | None = 0.0) -> str | None:
        """The next reply line; None if none within ``timeout`` (0: do not wait)."""

    def close(self) -> None: ...


class TcpLink:
    """Lines over a TCP connection."""

    def __init__(self, host: str, port: int, timeout: float = 10.0) -> None:
        try:
            self.sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as e:
            raise PartServerError(f"cannot connect to the part server at {host}:{port}: "
                                  f"{e.strerror or e}") from None
        self.buf = b""
        self.closed = False

    def send(self, line: str) -> None:
        if "\n" in line or len(line) > MAX_LINE:
            raise PartServerError(f"not one request line: {line[:40]!r}")
        try:
            self.sock.sendall(line.encode("ascii") + b"\n")
        except OSError as e:
            raise PartServerError(f"part server link lost: {e}") from None

    def receive(self, timeout: float | None = 0.0) -> str | None:
        while b"\n" not in self.buf:
            poller = select.poll()           # not select(): a descriptor may be > 1023
            poller.register(self.sock, select.POLLIN)
            ready = poller.poll(None if timeout is None else max(0, int(timeout * 1000)))
            if not ready:
                return None
            try:
                chunk = self.sock.recv(4096)
            except OSError as e:
                raise PartServerError(f"part server link lost: {e}") from None
            if not chunk:
                raise PartServerError("the part server closed the connection")
            self.buf += chunk
        line, _, self.buf = self.buf.partition(b"\n")
        return line.decode("ascii", errors="replace").rstrip("\r")

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            try:
                self.sock.close()
            except OSError:
                pass


class LoopLink:
    """Lines handed straight to a desk in this process; the desk answers on the next tick.

    ``conn`` names the robot in the desk's records. Each line sent hints the clock so that
    a fast run does not skip the tick that answers it."""

    def __init__(self, desk, clock: Clock, conn: Hashable = "sim-robot") -> None:
        self.desk, self.clock, self.conn = desk, clock, conn
        self.replies: deque[str] = deque()
        self.sent: dict[int, object] = {}       # requests not answered yet
        self.closed = False

    def send(self, line: str) -> None:
        if self.closed:
            raise PartServerError("link closed")
        from feeder_bt.behaviours.desk import Pending

        def answer(text: str) -> None:
            self.sent.pop(id(item), None)
            self.replies.append(text)

        item = Pending(self.conn, line, answer)
        self.sent[id(item)] = item
        self.desk.inbox.put(item)
        self.clock.wake_at(self.clock.now() + 1e-6)

    def receive(self, timeout: float | None = 0.0) -> str | None:
        if self.replies:
            return self.replies.popleft()
        if timeout:
            raise PartServerError("a loop link is answered by the tick thread: poll it "
                                  "between ticks instead of waiting")
        return None

    def close(self) -> None:
        """Like a killed robot program: whatever it asked and did not get is dropped."""
        self.closed = True
        for item in self.sent.values():
            item.cancelled = True  # type: ignore[attr-defined]
        self.sent.clear()


class PartClient:
    """One robot's conversation with the part server: one request, one reply, in order."""

    def __init__(self, link: Link, timeout: float = 10.0) -> None:
        self.link, self.timeout = link, timeout
        self.outstanding = 0

    @classmethod
    def connect(cls, host: str = "127.0.0.1", port: int = 7600,
                timeout: float = 10.0) -> PartClient:
        return cls(TcpLink(host, port, timeout), timeout)

    def __enter__(self) -> PartClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ non-blocking
    def submit(self, line: str) -> None:
        """Send a request; its reply comes from ``poll`` (replies come in request order)."""
        self.link.send(line)
        self.outstanding += 1

    def poll(self, timeout: float | None = 0.0) -> tuple[str, list[str]] | None:
        """The next reply as (kind, fields) — kind ``ERR`` for a refusal — or None."""
        line = self.link.receive(timeout)
        if line is None:
            return None
        self.outstanding -= 1
        try:
            return parse_reply(line)
        except ProtocolError as e:
            raise PartServerError(str(e)) from None

    # ------------------------------------------------------------------ blocking
    def request(self, line: str, wait: float = 0.0) -> tuple[str, list[str]]:
        """Send and wait for the reply; ``ERR`` raises ``PartServerError``."""
        if self.outstanding:
            raise PartServerError("replies still outstanding: poll them first")
        self.submit(line)
        got = self.poll(self.timeout + wait)
        if got is None:
            raise PartServerError(f"no reply to {line.split()[0]} within "
                                  f"{self.timeout + wait:g} s")
        kind, fields = got
        if kind == "ERR":
            raise PartServerError(fields[0])
        return kind, fields

    def hello(self, name: str, secret: str, plain: bool = False) -> None:
        """Prove which robot this is (a part server with a robots file asks it first):
        ``HELLO NAME``, then the challenge's HMAC, so the secret never crosses the
        network. ``plain``: the old ``HELLO NAME SECRET``, replayable, for a server whose
        robots file allows it for this robot (trusted networks only)."""
        if plain:
            self.request(f"HELLO {name} {secret}")
            return
        kind, fields = self.request(f"HELLO {name}")
        if kind != "CHALLENGE" or len(fields) != 1:
            raise PartServerError(f"unexpected reply to HELLO: {kind}")
        self.request(f"PROOF {prove(secret_key(secret), fields[0])}")

    def part(self, type: str | None = None, within: float | None = None,
             wait: float = 0.0) -> Offer | None:
        """Ask for a part; None if there is none (within ``wait`` seconds)."""
        words = ["PART"] + ([type] if type else [])
        if within is not None:
            words += ["WITHIN", f"{within:g}"]
        if wait:
            words += ["WAIT", f"{wait:g}"]
        kind, fields = self.request(" ".join(words), wait)
        if kind == "NONE":
            return None
        if kind != "PART":
            raise PartServerError(f"unexpected reply to PART: {kind}")
        return parse_offer(fields)

    def picked(self, part_id: int) -> None:
        self.request(f"PICKED {part_id}")

    def placed(self, part_id: int) -> int:
        """Report a part placed; returns the cell's total retrieved."""
        _, fields = self.request(f"PLACED {part_id}")
        return int(fields[1]) if len(fields) > 1 else 0

    def missed(self, part_id: int, why: str = "") -> None:
        self.request(f"MISSED {part_id} {why}".rstrip())

    def release(self, part_id: int) -> bool:
        """Give a part back; True if it went back into the queue."""
        _, fields = self.request(f"RELEASE {part_id}")
        return fields[-1] == "queued"

    def prepare(self, n: int = 1, type: str | None = None) -> int:
        """Tell the cell how many parts are wanted next; returns how many are ready now."""
        _, fields = self.request(f"PREPARE {n}" + (f" {type}" if type else ""))
        return int(fields[0])

    def status(self) -> dict[str, str]:
        _, fields = self.request("STATUS")
        return parse_status(fields)

    def help(self, topic: str | None = None) -> str:
        kind, fields = self.request("HELP" + (f" {topic}" if topic else ""))
        return " ".join(fields)

    def close(self) -> None:
        self.link.close()


def main(argv: list[str] | None = None) -> int:
    """``python -m feeder_bt.plant.client [HOST:]PORT [REQUEST ...]``: send each request (or
    each line of standard input) and print each reply — a robot's side, by hand."""
    import sys

    from feeder_bt.core.addresses import parse_hostport
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print(main.__doc__)
        return 0 if args else 2
    try:
        host, port = parse_hostport(args[0], 7600, "part server")
        with PartClient.connect(host, port) as client:
            lines = args[1:] or (line.strip() for line in sys.stdin)
            for line in lines:
                if not line:
                    continue
                wait = 0.0
                words = line.split()
                if words[0].upper() == "PART" and "WAIT" in (w.upper() for w in words):
                    i = [w.upper() for w in words].index("WAIT")
                    wait = float(words[i + 1]) if i + 1 < len(words) else 0.0
                client.submit(line)
                got = client.poll(client.timeout + wait)
                if got is None:
                    raise PartServerError(f"no reply to {words[0]}")
                kind, fields = got
                print("ERR " + fields[0] if kind == "ERR" else " ".join(["OK", kind, *fields]),
                      flush=True)
                if kind == "BYE":
                    break
    except (FeederError, ValueError) as e:
        print(f"feeder part client: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
