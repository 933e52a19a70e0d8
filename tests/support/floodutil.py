"""Playing the attacker on loopback: many idle TCP connections from many
loopback addresses (127.0.N.x: every 127/8 address is this machine on Linux), opened
without blocking and held until closed. Shared by tests/ui/test_conn_limits.py and
benchmarks/flood.py."""

from __future__ import annotations

import errno
import resource
import selectors
import socket
import time


def raise_fd_limit(need: int) -> int:
    """Raise this process's soft limit on open files to at least ``need`` if the hard
    limit allows; returns the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < need:
        target = need if hard == resource.RLIM_INFINITY else min(need, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        soft = target
    return soft


class IdleFlood:
    """``n`` connections to ``(host, port)`` that never send a byte, spread over
    ``addresses`` source addresses 127.<net>.0.1, 127.<net>.0.2, ..."""

    def __init__(self, port: int, n: int, addresses: int = 50, net: int = 1,
                 host: str = "127.0.0.1") -> None:
        raise_fd_limit(2 * n + 512)
        self.socks: list[socket.socket] = []
        self.sel = selectors.DefaultSelector()
        for i in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setblocking(False)
            s.bind((f"127.{net}.{i % addresses // 250}.{i % addresses % 250 + 1}", 0))
            err = s.connect_ex((host, port))
            if err not in (0, errno.EINPROGRESS):
                s.close()
                continue
            self.socks.append(s)
            self.sel.register(s, selectors.EVENT_WRITE)

    def settle(self, timeout_s: float = 60.0) -> int:
        """Wait until every connect has finished (made, refused or reset) or ``timeout_s``
        passed; returns how many finished."""
        done = 0
        end = time.monotonic() + timeout_s
        while done < len(self.socks) and time.monotonic() < end:
            for key, _ in self.sel.select(timeout=0.5):
                self.sel.unregister(key.fileobj)
                done += 1
        return done

    def still_open(self) -> int:
        """Connections the server has not closed (a peek reads nothing and no EOF)."""
        n = 0
        for s in self.socks:
            try:
                if s.recv(1, socket.MSG_PEEK) == b"":
                    continue
            except BlockingIOError:
                n += 1
            except OSError:
                continue
        return n

    def close(self) -> None:
        self.sel.close()
        for s in self.socks:
            s.close()
        self.socks.clear()
