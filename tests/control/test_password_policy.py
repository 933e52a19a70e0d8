"""A password policy that refuses common and user-derived passwords, with zxcvbn
and (where it is not installed) with the bundled word list."""

from __future__ import annotations

import builtins
import io

import pytest

from feeder_bt.cli.main import main
from feeder_bt.control.users import UsersError, check_password

WEAK = [("Password1!", "bob"), ("P@ssw0rd", "bob"), ("Summer2024", "bob"),
        ("alice123", "alice"), ("Alice2024!", "alice"), ("Feeder2024!", "bob"),
        ("qwertyuiop1", "bob"), ("Welcome123", "bob")]
GOOD = [("alice-secret-1", "alice"), ("bob-pass-123", "bob"), ("correct horse battery", "x"),
        ("tulip-gearbox-93", "alice")]


@pytest.fixture(params=["zxcvbn", "word list"])
def estimator(request, monkeypatch):
    if request.param == "word list":
        real = builtins.__import__

        def no_zxcvbn(name, *args, **kw):
            if name == "zxcvbn":
                raise ImportError(name)
            return real(name, *args, **kw)
        monkeypatch.setattr(builtins, "__import__", no_zxcvbn)
    else:
        pytest.importorskip("zxcvbn")
    return request.param


@pytest.mark.parametrize("password,name", WEAK)
def test_common_and_user_derived_passwords_are_refused(estimator, password, name):
    with pytest.raises(UsersError, match="password refused"):
        check_password(password, name)


@pytest.mark.parametrize("password,name", GOOD)
def test_passphrases_are_accepted(estimator, password, name):
    assert check_password(password, name) == password


def test_feeder_users_add_refuses_a_weak_one_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("sys.stdin", io.StringIO("Summer2024\n"))
    assert main(["users", "add", "alice", "--password-stdin", "--users",
                 str(tmp_path / "users.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "password refused" in err and len(err.splitlines()) == 1
