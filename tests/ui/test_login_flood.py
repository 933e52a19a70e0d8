"""A flood of strangers' logins cannot keep the rightful user out. A known
browser (its ``known`` cookie) or the address the user logged in from before is served
before strangers when password checks are scarce, and the limiter's memory stays bounded
without a sort on the event loop."""

from __future__ import annotations

import http.client
import json
import secrets
import threading
import time

from feeder_bt.control import guard as guard_mod
from feeder_bt.control.guard import Attempt, LoginGuard
from feeder_bt.control.sessions import LoginLimiter
from tests.support.uiutil import Browser, Client, FeederUi, make_ui, make_users


def test_strangers_may_hold_only_part_of_the_password_checks(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    alice = Browser(ui, ip="10.0.0.7")
    assert alice.login("alice")[0] == 200          # her browser and address are known now
    ui._checking = ui._strangers = 2               # strangers hold their share
    code, body = Browser(ui, ip="10.9.9.9").login("mallory", "guess-guess")
    assert code == 429 and "busy checking other logins" in body["error"]
    assert alice.login("alice")[0] == 200          # her known cookie
    assert Browser(ui, ip="10.0.0.7").login("alice")[0] == 200     # her known address
    code, _ = Browser(ui, ip="10.0.0.8").login("alice")            # elsewhere, no cookie
    assert code == 429
    ui._checking = ui._strangers = 0


def test_the_limiters_memory_is_bounded_oldest_first(monkeypatch):
    lim = LoginLimiter(free=3, max_keys=100, clock=lambda: 5.0)
    for i in range(250):
        lim.failure([f"ip:10.0.{i // 250}.{i}"])
    assert len(lim._records) == 100
    assert "ip:10.0.0.249" in lim._records and "ip:10.0.0.0" not in lim._records
    monkeypatch.setattr(guard_mod, "MAX_KEYS", 50)
    g = LoginGuard(lambda name: None, clock=lambda: 5.0)
    for i in range(120):
        g.failure(Attempt(f"name{i}", "10.1.1.1"), False)
    assert len(g._names) == 50 and "name119" in g._names and "name0" not in g._names


def _flood(port: int, stop: threading.Event, k: int, tries: list[int]) -> None:
    """One attacker thread: random names from its own loopback addresses, as fast as the
    server answers."""
    n = 0
    while not stop.is_set():
        src = f"127.4.{k}.{n % 200 + 1}"
        n += 1
        try:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30,
                                              source_address=(src, 0))
            body = json.dumps({"user": "u" + secrets.token_hex(4), "password": "x" * 10})
            conn.request("POST", "/api/login", body, {"Content-Type": "application/json"})
            conn.getresponse().read()
            conn.close()
            tries[k] += 1
        except OSError:
            pass


def test_a_login_flood_from_many_addresses_does_not_keep_alice_out(tmp_path):
    users = make_users(tmp_path / "users.json", {"alice": "alice-secret-1"})
    ui = FeederUi(tmp_path, users)
    stop = threading.Event()
    tries = [0] * 12
    threads = [threading.Thread(target=_flood, args=(int(ui.url.rsplit(":", 1)[1].strip("/")),
                                                     stop, k, tries)) for k in range(12)]
    try:
        alice = Client(ui.url)
        assert alice.login("alice", "alice-secret-1")[0] == 200     # her browser is known
        for t in threads:
            t.start()
        end = time.monotonic() + 60
        while sum(tries) < 24 and time.monotonic() < end:            # the flood is on
            time.sleep(0.05)
        got = [alice.login("alice", "alice-secret-1")[0] for _ in range(20)]
        assert got.count(200) >= 18, got
        assert sum(tries) >= 24
    finally:
        stop.set()
        for t in threads:
            if t.is_alive() or t.ident:
                t.join(60)
        ui.kill()
    assert "Traceback" not in (tmp_path / "stderr.txt").read_text()
