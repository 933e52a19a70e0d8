"""The dashboard over HTTP and a websocket, against a real `feeder run --ui` on loopback (the
simulated cell in real time): logins, the rate limit, cookies, who may command, live
updates. The rigs (``FeederUi``, ``Client``, ``make_users``) are in uiutil.py."""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.request

import pytest

from tests.support.uiutil import Client, FeederUi, feeder_cli, make_users

PASSWORDS = {"alice": "alice-secret-1", "bob": "bob-secret-22", "carol": "carol-secret-3"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ui_http")
    users = make_users(tmp / "users.json", PASSWORDS)
    ui = FeederUi(tmp, users)
    ui.users = users
    yield ui
    ui.kill()


def test_users_file_holds_no_password(server):
    text = server.users.read_text()
    for name, password in PASSWORDS.items():
        assert password not in text
        assert re.search(rf'"{name}": {{\s*"hash": "scrypt\$', text)


def test_not_logged_in_sees_and_does_nothing(server):
    anon = Client(server.url)
    assert anon.call("api/status")[0] == 401
    assert anon.call("api/me")[0] == 401
    assert anon.command("start")[0] == 401
    assert anon.call("api/control", {"action": "take"})[0] == 401
    code, body, _ = anon.call("api/login", {"user": "alice"})
    assert code == 400
    page = urllib.request.urlopen(server.url, timeout=10).read().decode()
    assert "<title>feeder_bt operator</title>" in page      # the page itself is public


def test_session_cookie_is_http_only_and_same_site(server):
    c = Client(server.url)
    code, body, headers = c.login("carol", PASSWORDS["carol"])
    assert code == 200 and body["user"] == "carol"
    cookie = headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
    assert "content-security-policy" in {k.lower() for k in headers}
    assert c.call("api/me")[1]["user"] == "carol"
    assert c.call("api/logout", {})[0] == 200
    assert c.call("api/me")[0] == 401


def test_requests_from_another_site_are_refused(server):
    c = Client(server.url)
    assert c.login("carol", PASSWORDS["carol"])[0] == 200
    code, body, _ = c.call("api/control", {"action": "take"},
                           headers={"Origin": "http://evil.example"})
    assert code == 403 and "another site" in body["error"]
    code, body, _ = c.call("api/control", raw=b'{"action": "take"}',
                           headers={"Content-Type": "text/plain"})
    assert code == 415
    code, body, _ = c.call("api/control", raw=b'{"action": "' + b"x" * 70000 + b'"}')
    assert code == 413
    code, body, _ = c.call("api/control", {"action": "take"},      # DNS rebinding
                           headers={"Host": "evil.example:8080"})
    assert code == 400 and body["error"] == "refused: this server does not answer to that Host"
    code, body, _ = c.call("api/control", raw=b"[" * 20000 + b"]" * 20000)
    assert code == 400 and body["error"] == "the body is nested too deeply"
    assert c.call("api/me")[1]["control"]["state"] == "available"


def test_only_the_holder_commands_the_cell(server):
    alice, bob = Client(server.url), Client(server.url)
    assert alice.login("alice", PASSWORDS["alice"])[0] == 200
    assert bob.login("bob", PASSWORDS["bob"])[0] == 200
    code, body = bob.command("start")
    assert code == 403 and body["error"] == "refused: take control first (nobody has it)"
    code, body, _ = alice.call("api/control", {"action": "take"})
    assert code == 200 and body["control"] == {"state": "you", "holder": "alice",
                                               "free_in": 60}   # a script: no page open
    code, body, _ = bob.call("api/control", {"action": "take"})
    assert code == 409 and "alice has control" in body["error"]
    control = bob.call("api/me")[1]["control"]
    assert (control["state"], control["holder"]) == ("other", "alice")
    assert 0 < control["free_in"] <= 60          # free unless alice keeps making requests
    for name, args in [("start", {}), ("stop", {}), ("speeds", {"horizontal_mm_s": 250}),
                       ("load", {"scenario": "squares"}), ("adjust", {"engaged": False})]:
        code, body = bob.command(name, **args)
        assert (code, body["error"]) == (403, "refused: alice has control"), name
    st = alice.status()
    assert st["state"] == "STOPPED" and st["scenario"] == "lenses" and st["auto_adjust"]
    assert st["hal"]["horizontal_mm_s"] == 0.0
    code, body = alice.command("speeds", horizontal_mm_s=9999)
    assert code == 409 and "start it first" in body["error"]
    code, body = alice.command("load", scenario="squares")
    assert code == 200 and alice.status()["scenario"] == "squares"
    code, body = alice.command("load", scenario="lenses")
    assert code == 200 and alice.status()["scenario"] == "lenses"
    assert bob.call("api/control", {"action": "release"})[0] == 409
    assert alice.call("api/control", {"action": "release"})[0] == 200
    assert bob.call("api/me")[1]["control"]["state"] == "available"


def test_live_updates_over_the_websocket(server):
    from websockets.sync.client import connect

    c = Client(server.url)
    assert c.login("carol", PASSWORDS["carol"])[0] == 200
    ws_url = server.url.replace("http://", "ws://") + "ws"
    with connect(ws_url, additional_headers={"Cookie": c.cookie}, open_timeout=10) as ws:
        first = json.loads(ws.recv(timeout=10))
        second = json.loads(ws.recv(timeout=10))
    assert first["type"] == "update" and first["session"]["user"] == "carol"
    assert first["status"]["scenario"] == "lenses" and "limits" in first["status"]
    assert second["status"]["seq"] > first["status"]["seq"]
    assert second["status"]["up_time_s"] >= first["status"]["up_time_s"]
    with pytest.raises(Exception, match="403"):       # no session cookie: no updates
        connect(ws_url, open_timeout=10).close()


def test_removed_user_is_logged_out(server):
    c = Client(server.url)
    assert c.login("carol", PASSWORDS["carol"])[0] == 200
    res = feeder_cli("users", "remove", "carol", "--users", str(server.users))
    assert res.returncode == 0, res.stderr
    assert c.call("api/me")[0] == 401
    assert c.login("carol", PASSWORDS["carol"])[0] == 401


def test_wrong_passwords_are_refused_and_slowed(server):
    """A guesser on this machine shares 127.0.0.1 with everybody: it is locked out, but
    alice's browser, which has logged in as her before, is not."""
    alice = Client(server.url)
    assert alice.login("alice", PASSWORDS["alice"])[0] == 200     # her browser is known now
    guesser = Client(server.url)
    for _ in range(2):
        code, body, _ = guesser.login("alice", "not-her-password")
        assert (code, body["error"]) == (401, "wrong user name or password")
    code, body, _ = guesser.login("alice", "still-not-it")
    assert (code, body["error"]) == (401, "wrong user name or password; next attempt in 1 s")
    code, body, headers = guesser.login("alice", PASSWORDS["alice"])   # locked: not checked
    assert code == 429 and body["error"] == "too many failed logins: try again in 1 s"
    assert headers["retry-after"] == "1"
    code, body, _ = alice.login("alice", PASSWORDS["alice"])      # the rightful user: at once
    assert code == 200 and body["user"] == "alice"
    code, body, _ = guesser.login("mallory", "whatever-it-is")   # unknown: the same answer
    assert (code, body["error"]) == (401, "wrong user name or password")


def test_ctrl_c_stops_in_order_and_reports_what_operators_did(server):
    report = server.stop()
    assert report["state"] == "STOPPED" and report["interrupted"] and report["fault"] is None
    assert report["feed_seconds"] == 0.0                # nobody started the cell
    done = [(c["user"], c["action"]) for c in report["operator"]["commands"]]
    assert ("alice", "took control") in done and ("alice", "load") in done
    assert {a for u, a in done if u == "bob"} <= {"logged in"}   # bob changed nothing
    assert server.url == report["operator"]["url"]
    access = report["operator"]["access"]                  # refusals on record
    assert access["login_failed"] >= 4 and access["login_locked"] >= 1
    assert access["command_refused"] >= 6 and access["request_refused"] >= 1
    err = server.err.read_text()
    assert "login_locked alice" in err and "Traceback" not in err
