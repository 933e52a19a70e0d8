"""Who may log in and who may command. The users
file and `feeder users`, sessions, the control token, the failed-login limiter.

Time is stepped (fake clocks) wherever the code lets it be."""

from __future__ import annotations

import io
import json
import os
import stat
from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from feeder_bt.control.sessions import Control, LoginLimiter, Sessions
from feeder_bt.control.users import UsersError, UsersFile, hash_password, verify_password
from tests.support.uiutil import FakeClock

# ----------------------------------------------------------------------- users


def test_hashes_are_salted_scrypt_and_verify():
    a, b = hash_password("correct horse"), hash_password("correct horse")
    assert a != b                                   # a fresh salt each time
    assert a.startswith("scrypt$16384$8$1$") and "correct" not in a
    assert verify_password("correct horse", a) and verify_password("correct horse", b)
    assert not verify_password("correct hors", a)
    assert not verify_password("correct horse", "plain:correct horse")
    assert not verify_password("correct horse", "scrypt$2$1$1$AAAA$AAAA")   # too weak: refused


def test_users_file_keeps_no_password_and_is_private(tmp_path):
    f = UsersFile(tmp_path / "cfg" / "users.json")
    f.add("alice", "alice-secret-1")
    f.add("bob", "alice-secret-1")                  # same password, different hash
    text = f.path.read_text()
    assert "alice-secret-1" not in text
    doc = json.loads(text)
    assert doc["users"]["alice"]["hash"] != doc["users"]["bob"]["hash"]
    assert stat.S_IMODE(os.stat(f.path).st_mode) == 0o600
    assert f.names() == ["alice", "bob"]
    assert f.verify("alice", "alice-secret-1") and not f.verify("alice", "wrong-password")
    assert not f.verify("nobody", "alice-secret-1")
    f.remove("bob")
    assert f.names() == ["alice"]


@pytest.mark.parametrize("call,needle", [
    (lambda f: f.add("alice", "another-pass"), "already exists"),
    (lambda f: f.add("bad name", "long-enough"), "bad user name"),
    (lambda f: f.add("carol", "short"), "too short"),
    (lambda f: f.remove("nobody"), "no user 'nobody'"),
])
def test_users_file_mistakes_are_one_line(tmp_path, call, needle):
    f = UsersFile(tmp_path / "users.json")
    f.add("alice", "alice-secret-1")
    with pytest.raises(UsersError) as e:
        call(f)
    assert needle in str(e.value) and "\n" not in str(e.value) and e.value.exit_code == 2


def test_damaged_users_file_fails_closed(tmp_path, capsys):
    p = tmp_path / "users.json"
    p.write_text('{"format": "feeder_bt users 1", "users": {"alice": ')
    with pytest.raises(UsersError, match=r"users.json:1: not a feeder users file"):
        UsersFile(p).names()
    p.write_text('{"users": {}}')
    with pytest.raises(UsersError, match="not a feeder users file"):
        UsersFile(p).names()
    f = UsersFile(p)
    assert f.load_or_empty() == {} and f.load_or_empty() == {}
    assert capsys.readouterr().err.count("nobody can log in") == 1    # warned once


def test_users_file_is_reread_when_it_changes(tmp_path):
    server_view, cli = UsersFile(tmp_path / "u.json"), UsersFile(tmp_path / "u.json")
    assert not server_view.exists("alice")
    cli.add("alice", "alice-secret-1")
    assert server_view.exists("alice")
    cli.remove("alice")
    assert not server_view.exists("alice")


def test_feeder_users_command(tmp_path, monkeypatch, capsys):
    users = str(tmp_path / "users.json")
    monkeypatch.setattr("sys.stdin", io.StringIO("alice-secret-1\n"))
    assert main(["users", "add", "alice", "--password-stdin", "--users", users]) == 0
    assert "alice-secret-1" not in Path(users).read_text()
    monkeypatch.setattr("sys.stdin", io.StringIO("another-secret\n"))
    assert main(["users", "add", "alice", "--password-stdin", "--users", users]) == 2
    assert "already exists" in capsys.readouterr().err
    monkeypatch.setattr("sys.stdin", io.StringIO("another-secret\n"))
    assert main(["users", "add", "alice", "--replace", "--password-stdin",
                 "--users", users]) == 0
    assert UsersFile(users).verify("alice", "another-secret")
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert main(["users", "add", "bob", "--password-stdin", "--users", users]) == 2
    monkeypatch.setattr("sys.stdin", io.StringIO(""))       # not a terminal, no flag
    assert main(["users", "add", "bob", "--users", users]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "too short" in err[0] and "--password-stdin" in err[1]
    capsys.readouterr()
    assert main(["users", "list", "--users", users]) == 0
    assert capsys.readouterr().out.split() == ["alice"]
    assert main(["users", "remove", "alice", "--users", users]) == 0
    assert main(["users", "remove", "alice", "--users", users]) == 2
    assert main(["users", "list", "--users", users]) == 0
    assert "no users in" in capsys.readouterr().err


# --------------------------------------------------------------------- control


def test_sessions_expire_when_idle():
    clock = FakeClock()
    s = Sessions(idle_s=60, clock=clock)
    a, b = s.create("alice"), s.create("alice")
    assert a.token != b.token and len(a.token) >= 40
    assert s.users() == ["alice"] and len(s) == 2
    clock.t += 50
    assert s.get(a.token) is a                      # seen: stays alive
    clock.t += 50
    assert s.get(a.token) is a and s.get(b.token) is None
    assert s.get("forged") is None and s.get(None) is None
    assert s.end(a.token) is a and s.users() == []


def test_one_holder_of_control_at_a_time():
    s, c = Sessions(), Control()
    alice, bob, alice2 = s.create("alice"), s.create("bob"), s.create("alice")
    alice.conns = bob.conns = 1                     # their pages are open
    assert c.state_for(bob) == {"state": "available", "holder": None}
    assert c.refusal(bob) == "refused: take control first (nobody has it)"
    assert c.take(alice) == (True, "you have control")
    assert c.take(alice)[0]                         # taking it again is harmless
    ok, msg = c.take(bob)
    assert not ok and "alice has control" in msg and c.holder is alice
    assert c.release(bob) == (False, "refused: you do not have control")
    assert c.state_for(alice) == {"state": "you", "holder": "alice"}
    assert c.state_for(bob) == {"state": "other", "holder": "alice"}
    assert c.refusal(bob) == "refused: alice has control"
    assert not c.is_holder(alice2) and "another session" in c.refusal(alice2)
    # her other session is told it is hers, not "someone else" (the banner says so)
    assert c.state_for(alice2) == {"state": "other", "holder": "alice", "same_user": True}
    assert c.release(alice)[0] and c.holder is None
    assert c.take(bob)[0]
    assert not c.drop(alice.token) and c.drop(bob.token) and c.holder is None


def test_failed_logins_are_slowed_more_and_more():
    clock = FakeClock()
    lim = LoginLimiter(free=3, base_s=1.0, max_s=8.0, forget_s=600, clock=clock)
    keys = ("user:alice", "ip:10.0.0.9")
    assert lim.failure(keys) == 0 and lim.failure(keys) == 0    # two free mistakes
    assert lim.locked_for(keys) == 0
    assert lim.failure(keys) == 1.0                 # the third locks for 1 s
    assert lim.locked_for(keys) == 1.0 and lim.locked_for(["user:alice"]) == 1.0
    assert lim.locked_for(["user:bob"]) == 0        # others are not affected
    clock.t += 1.0
    assert lim.locked_for(keys) == 0
    assert lim.failure(keys) == 2.0                 # then 2 s, 4 s, 8 s, capped at 8 s
    clock.t += 2.0
    assert lim.failure(keys) == 4.0
    clock.t += 4.0
    assert lim.failure(keys) == 8.0
    clock.t += 8.0
    assert lim.failure(keys) == 8.0
    clock.t += 8.0
    lim.success(keys)                               # a good password clears the count
    assert lim.failure(keys) == 0
    clock.t += 601                                  # and a long quiet spell forgets it
    assert lim.failure(keys) == 0 and lim.failure(keys) == 0 and lim.failure(keys) == 1.0


def test_one_password_check_in_flight_per_key():
    lim = LoginLimiter()
    assert lim.begin(("user:alice", "ip:1"))
    assert not lim.begin(("user:alice", "ip:2"))
    assert not lim.begin(("user:bob", "ip:1"))
    lim.end(("user:alice", "ip:1"))
    assert lim.begin(("user:alice", "ip:2"))
