"""Operator access that cannot be turned against the cell — lock-outs that spare
the rightful user, control that cannot get stuck, sessions that end, the Host allow-list and
forwarded headers, the users file. (Bodies, the fuzz and the event log: test_bodies.py.)

The UI's ASGI app is driven in-process (no socket, no browser), on a fake clock: every
lock-out, lifetime and grace period is stepped, never slept."""

from __future__ import annotations

import asyncio
import json
import os
from typing import Any

import pytest

from feeder_bt.cli.main import main
from feeder_bt.control.access import Settings, allowed_hosts, host_name
from feeder_bt.control.sessions import Sessions
from feeder_bt.control.users import UsersError, UsersFile, check_password
from feeder_bt.ui.app import check_users
from feeder_bt.ui.server import UiApp
from tests.support.uiutil import PASSWORDS, Browser, Recorder, make_ui, write_users

# ---------------------------------------------------------------------------- lock-outs


def test_guesses_from_elsewhere_do_not_keep_the_rightful_user_out(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    alice = Browser(ui, "10.0.0.5")
    assert alice.login("alice")[0] == 200                  # her usual browser and address
    assert alice.call("POST", "/api/logout", {})[0] == 200

    answers = []
    for i in range(40):                                     # guesses from two other addresses
        mallory = Browser(ui, f"10.0.0.{66 + i % 2}")
        answers.append(mallory.login("alice", f"guess-{i}")[0])
        clock.t += 1.0
    assert answers.count(401) < 20 and 429 in answers      # the attacker is slowed...
    assert rec.kinds("login_locked")                        # ...and that is on record

    assert alice.login("alice")[0] == 200                  # ...but alice is not kept out
    new_browser = Browser(ui, "10.0.0.5")                   # her address, a new browser
    assert new_browser.login("alice")[0] == 200
    elsewhere = Browser(ui, "10.0.0.9")                     # a new browser and address:
    code, body = elsewhere.login("alice")                   # at most a short, fixed wait
    if code == 429:
        assert int(dict(elsewhere.last_headers)["retry-after"]) <= 5
        clock.t += 5.0
        code, body = elsewhere.login("alice")
    assert code == 200, body

    failed = rec.kinds("login_failed")                      # every failure is recorded
    assert len(failed) == answers.count(401)
    assert {d["ip"] for _, d in failed} == {"10.0.0.66", "10.0.0.67"}
    assert {u for u, _ in failed} == {"alice"}
    refused = rec.kinds("login_refused")
    assert len(refused) == answers.count(429)
    assert {d["by"] for _, d in rec.kinds("login_locked")} >= {"name and address", "name"}


def test_the_same_address_as_the_attacker_is_told_apart_by_the_browser(tmp_path):
    """Everyone on the controller's machine shares 127.0.0.1: only alice's browser, which
    logged in as her before, tells her apart from a local guesser."""
    ui, rec, clock = make_ui(tmp_path)
    alice, local = Browser(ui), Browser(ui)
    assert alice.login("alice")[0] == 200
    codes = [local.login("alice", f"guess-{i}")[0] for i in range(12)]
    assert codes.count(401) == 3 and codes[3:] == [429] * 9   # locked after three
    assert alice.login("alice")[0] == 200                      # not alice's browser
    code, body = local.login("alice")                          # the guesser's stays locked
    assert code == 429 and "try again in" in body["error"]


def test_case_does_not_let_one_name_lock_another(tmp_path):
    """Names are compared exactly: guesses at ALICE count against ALICE (nobody), never
    against alice; `feeder users add` refuses a second name that differs only in case."""
    ui, rec, clock = make_ui(tmp_path)
    alice = Browser(ui, "10.0.0.5")
    assert alice.login("alice")[0] == 200
    alice.cookies.clear()                                   # not even her known cookie
    for i in range(20):
        Browser(ui, "10.0.0.66").login("ALICE", f"guess-{i}")
        clock.t += 1.0
    assert alice.login("alice")[0] == 200
    assert {u for u, _ in rec.kinds("login_failed")} == {"(unknown name)"}   # not echoed
    with pytest.raises(UsersError, match="differ only in case"):
        ui.users.add("ALICE", "another-secret-9")


def test_a_known_browser_is_locked_only_by_its_own_mistakes(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    alice = Browser(ui)
    assert alice.login("alice")[0] == 200
    codes = [alice.login("alice", "typo-typo")[0] for _ in range(6)]
    assert codes[:5] == [401] * 5 and codes[5] == 429         # five free, then a lock
    assert any(d["by"] == "browser" for _, d in rec.kinds("login_locked"))
    clock.t += 1.0
    assert alice.login("alice")[0] == 200


# ---------------------------------------------------------------------------- sessions, control


WAIT_S = 60.0       # a net against a hung loop only: nothing here is judged by the clock


async def settle(turns: int = 50) -> None:
    """Let every ready task run to its next wait: loop turns, not seconds."""
    for _ in range(turns):
        await asyncio.sleep(0)


def connect(ui: UiApp, browser: Browser) -> tuple[asyncio.Task, asyncio.Queue]:
    """Open the page's websocket (on the running loop); put a disconnect on the queue to
    close it."""
    incoming: asyncio.Queue = asyncio.Queue()
    incoming.put_nowait({"type": "websocket.connect"})
    scope = {"type": "websocket", "asgi": {"version": "3.0"}, "scheme": "ws", "path": "/ws",
             "raw_path": b"/ws", "query_string": b"", "root_path": "",
             "client": (browser.ip, 50001), "server": ("127.0.0.1", 8080), "subprotocols": [],
             "headers": [(b"host", browser.host.encode()),
                         (b"cookie", browser._cookie_header("/ws").encode())]}

    async def send(message: dict[str, Any]) -> None:
        if message["type"] == "websocket.close":          # as the server would: closed
            incoming.put_nowait({"type": "websocket.disconnect", "code": message["code"]})

    return asyncio.ensure_future(ui.app(scope, incoming.get, send)), incoming


def test_control_held_by_a_closed_browser_is_free_after_the_grace_time(tmp_path):
    ui, rec, clock = make_ui(tmp_path, settings=Settings(control_grace_s=60))
    alice, bob = Browser(ui), Browser(ui)
    assert alice.login("alice")[0] == 200 and bob.login("bob")[0] == 200

    async def scenario() -> list[dict[str, Any]]:
        seen = []
        task, incoming = connect(ui, alice)
        await settle()
        assert ui.sessions.all()[0].conns == 1
        ok, _ = ui.control.take(ui.sessions.all()[0])
        assert ok
        clock.t += 3600.0                                  # her page stays open: hers
        ui.wake_all()
        seen.append(ui.control.state_for(ui.sessions.all()[1]))
        await incoming.put({"type": "websocket.disconnect", "code": 1001})  # tab closed
        await asyncio.wait_for(task, WAIT_S)
        seen.append(ui.control.state_for(ui.sessions.all()[1]))
        clock.t += 59.5
        ui.wake_all()
        seen.append(ui.control.state_for(ui.sessions.all()[1]))
        clock.t += 1.0
        ui.wake_all()
        seen.append(ui.control.state_for(ui.sessions.all()[1]))
        return seen

    assert [s["state"] for s in asyncio.run(scenario())] == ["other"] * 3 + ["available"]
    code, body = bob.me()
    assert body["control"] == {"state": "available", "holder": None}
    (user, data), = rec.kinds("control_released")
    assert user == "alice" and "no page open for 60 s" in data["why"]


def test_control_count_down_is_shown_to_the_others(tmp_path):
    ui, rec, clock = make_ui(tmp_path, settings=Settings(control_grace_s=60))
    alice, bob = Browser(ui), Browser(ui)
    alice.login("alice")
    bob.login("bob")
    assert alice.call("POST", "/api/control", {"action": "take"})[0] == 200
    clock.t += 45.0                                         # a script: no page, no request
    assert bob.me()[1]["control"] == {"state": "other", "holder": "alice", "free_in": 15}
    assert alice.me()[1]["control"]["state"] == "you"      # a request: she is here again
    assert bob.me()[1]["control"]["free_in"] == 60


def test_pushes_do_not_keep_a_session_alive_and_sessions_have_a_lifetime(tmp_path):
    ui, rec, clock = make_ui(tmp_path, settings=Settings(session_idle_s=100,
                                                         session_lifetime_s=300))
    alice, bob = Browser(ui), Browser(ui)
    alice.login("alice")

    async def pushes() -> None:
        task, incoming = connect(ui, alice)
        for _ in range(15):                                 # 150 s of updates, no request
            clock.t += 10.0
            ui.wake_all()
            await settle()
        await asyncio.wait_for(task, WAIT_S)                   # told to log out, and closed

    bob_seen = []
    asyncio.run(pushes())
    assert alice.me()[0] == 401
    bob.login("bob")
    t0 = clock.t
    while clock.t < t0 + 360:                               # bob keeps busy...
        bob_seen.append(bob.me()[0])
        clock.t += 50.0
    assert bob_seen[:6] == [200] * 6 and bob_seen[-1] == 401     # ...until the lifetime
    assert {d["why"] for _, d in rec.kinds("session_ended")} == {"expired"}


def test_removing_a_user_or_changing_the_password_ends_sessions_and_control_at_once(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    alice, bob, old_bob = Browser(ui), Browser(ui), Browser(ui)
    alice.login("alice")
    bob.login("bob")
    old_bob.login("bob")
    assert alice.call("POST", "/api/control", {"action": "take"})[0] == 200

    ui.users.remove("alice")                                # `feeder users remove alice`
    ui.wake_all()                                           # the next publish, 0.2 s later
    assert ui.control.holder is None
    assert [s.user for s in ui.sessions.all()] == ["bob", "bob"]
    assert rec.kinds("control_released")[0][0] == "alice"
    write = UsersFile(ui.users.path)
    write.add("alice", PASSWORDS["alice"])                  # the same password, again
    assert alice.me()[0] == 401                             # the old token stays dead

    write.add("bob", "bob-new-secret-5", replace=True)      # `feeder users add bob --replace`
    ui.wake_all()
    assert ui.sessions.all() == []
    assert old_bob.me()[0] == 401
    whys = [d["why"] for _, d in rec.kinds("session_ended")]
    assert whys == ["user removed", "password changed", "password changed"]


def test_an_administrator_forces_control_free(tmp_path, capsys):
    ui, rec, clock = make_ui(tmp_path, roles={"carol": "admin"})
    alice, bob, carol = Browser(ui), Browser(ui), Browser(ui)
    for b, name in ((alice, "alice"), (bob, "bob"), (carol, "carol")):
        b.login(name)
    assert alice.call("POST", "/api/control", {"action": "take"})[0] == 200
    code, body = bob.call("POST", "/api/control", {"action": "force-release"})
    assert code == 403 and ui.control.holder is not None    # only an admin may
    assert carol.me()[1]["admin"] and not bob.me()[1]["admin"]
    code, body = carol.call("POST", "/api/control", {"action": "force-release"})
    assert code == 200 and body["message"] == "control taken from alice"
    assert ui.control.holder is None

    assert alice.call("POST", "/api/control", {"action": "take"})[0] == 200
    assert main(["users", "release-control", "--users", str(ui.users.path)]) == 0
    ui.wake_all()
    assert ui.control.holder is None
    released = rec.kinds("control_released")
    assert [u for u, _ in released] == ["alice", "alice"]
    assert released[0][1]["why"] == "forced by admin carol"
    assert "release-control" in released[1][1]["why"]
    assert rec.kinds("command_refused")[0][1]["command"] == "force-release"


# ---------------------------------------------------------------------------- hosts, proxies


def test_a_foreign_host_is_refused_before_anything_else(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    rebinding = Browser(ui, host="evil.example:8080")       # a DNS-rebinding page's Host
    code, body = rebinding.login("alice")
    assert code == 400 and body["error"] == "refused: this server does not answer to that Host"
    assert not rebinding.cookies and len(ui.sessions) == 0
    assert Browser(ui, host="").me()[0] == 400              # no Host at all
    assert Browser(ui, host="localhost:8080").login("alice")[0] == 200
    assert Browser(ui, host="[::1]:8080").me()[0] == 401    # loopback names: ours
    assert rec.kinds("request_refused")[0][1]["why"] == "unknown Host 'evil.example:8080'"

    ok = Browser(ui)
    ok.login("bob")
    code, _ = ok.call("POST", "/api/control", {"action": "take"},
                      headers={"origin": "https://127.0.0.1:8080"})   # the scheme counts
    assert code == 403
    assert ok.call("POST", "/api/control", {"action": "take"},
                   headers={"origin": "http://127.0.0.1:8080"})[0] == 200


def test_host_allow_list():
    assert host_name("Feeder.Example:8080") == "feeder.example"
    assert host_name("[::1]:80") == "::1" and host_name("127.0.0.1") == "127.0.0.1"
    assert host_name("a b") is None and host_name("x:y") is None and host_name(None) is None
    assert allowed_hosts("127.0.0.1") == {"localhost", "127.0.0.1", "::1"}
    assert allowed_hosts("0.0.0.0", ["cell7"]) == {"localhost", "127.0.0.1", "::1", "cell7"}
    assert allowed_hosts("10.1.2.3") == {"10.1.2.3"}


def test_forwarded_headers_count_only_from_a_named_proxy(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    forged = {"x-forwarded-for": "10.9.9.9", "x-forwarded-proto": "https"}
    b = Browser(ui)
    b.call("POST", "/api/login", {"user": "alice", "password": "wrong-wrong"}, headers=forged)
    assert rec.kinds("login_failed")[-1][1]["ip"] == "127.0.0.1"    # not the forged one

    (tmp_path / "proxied").mkdir()
    ui2, rec2, _ = make_ui(tmp_path / "proxied", settings=Settings(proxies=("127.0.0.1",)))
    p = Browser(ui2)
    p.call("POST", "/api/login", {"user": "alice", "password": "wrong-wrong"},
           headers={"x-forwarded-for": "192.0.2.1, 10.9.9.9"})
    assert rec2.kinds("login_failed")[-1][1]["ip"] == "10.9.9.9"    # the proxy's word
    code, _ = p.call("POST", "/api/login", {"user": "bob", "password": PASSWORDS["bob"]},
                     headers={**forged, "origin": "https://127.0.0.1:8080"})
    assert code == 200
    cookie = next(v for k, v in p.last_headers if k == "set-cookie")
    assert "Secure" in cookie


def test_the_sessions_default_is_not_fooled_by_an_empty_sessions(tmp_path):
    users = write_users(tmp_path / "users.json")
    mine = Sessions(idle_s=3)
    assert len(mine) == 0 and not mine                      # empty: falsy
    assert UiApp(Recorder(), users, sessions=mine).sessions is mine


# ---------------------------------------------------------------------------- users file


def test_weak_passwords_are_refused():
    for weak in ("password", "PASSWORD", " " * 8, "aaaaaaaaaa", "12345678", "qwerty123"):
        with pytest.raises(UsersError, match="refused"):
            check_password(weak)
    with pytest.raises(UsersError, match="refused"):
        check_password("alice-alice", "Alice-Alice")
    assert check_password("alice-secret-1", "alice") == "alice-secret-1"


def test_a_users_file_others_may_read_is_warned_of_or_refused(tmp_path, capsys):
    users = write_users(tmp_path / "users.json")
    os.chmod(users.path, 0o644)
    check_users(users.path)
    assert "may be read by other users" in capsys.readouterr().err
    assert main(["users", "set", "readable_users_file", "refuse", "--users",
                 str(users.path)]) == 0
    os.chmod(users.path, 0o644)
    with pytest.raises(UsersError, match="refused: .* chmod 600"):
        check_users(users.path)
    os.chmod(users.path, 0o600)
    check_users(users.path)
    assert main(["users", "set", "session_idle_s", "-5", "--users", str(users.path)]) == 2
    assert "between 1 and one year" in capsys.readouterr().err
    assert main(["users", "set", "hosts", "cell7.example", "10.0.0.5", "--users",
                 str(users.path)]) == 0
    assert Settings.of(UsersFile(users.path).section("settings")).hosts == (
        "cell7.example", "10.0.0.5")
    assert UsersFile(users.path).names() == sorted(PASSWORDS)   # users kept


def test_password_checks_at_once_are_bounded(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    ui._checking = 4                                        # four scrypt checks running
    code, body = Browser(ui).login("alice")
    assert code == 429 and "busy checking other logins" in body["error"]
    ui._checking = 0
    assert Browser(ui).login("alice")[0] == 200


def test_feeder_users_roles_and_settings(tmp_path, capsys):
    path = str(write_users(tmp_path / "users.json").path)
    assert main(["users", "role", "carol", "admin", "--users", path]) == 0
    assert main(["users", "role", "nobody", "admin", "--users", path]) == 2
    capsys.readouterr()
    assert main(["users", "list", "--users", path]) == 0
    assert capsys.readouterr().out.splitlines() == ["alice", "bob", "carol (admin)"]
    assert main(["users", "set", "control_grace_s", "90", "--users", path]) == 0
    assert main(["users", "set", "proxies", "not-an-address", "--users", path]) == 2
    capsys.readouterr()
    assert main(["users", "settings", "--users", path]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["control_grace_s"] == 90.0 and shown["proxies"] == []
    assert main(["users", "set", "control_grace_s", "--users", path]) == 0   # reset
    assert Settings.of(UsersFile(path).section("settings")).control_grace_s == 60.0
    monkey = UsersFile(path)
    monkey.add("alice", "alice-new-secret-7", replace=True)
    assert monkey.role("carol") == "admin"                  # roles survive other changes
