"""`feeder replay --ui` signs in with the dashboard's users file; without a
session it serves the login page and nothing of the run."""

from __future__ import annotations

import urllib.request

import pytest

from feeder_bt.app.run import RunOptions, run_job
from tests.support.uiutil import LENSES, PASSWORD, Client, ReplayUi, feeder_cli


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("replay_login")
    db = tmp / "feeder.db"
    run_job(RunOptions(scenario=str(LENSES), duration=8.0, fast=True, seed=1, view="none",
                       db=str(db)))
    ui = ReplayUi(tmp, db)
    ui.db = db
    yield ui
    ui.stop()


def _page(url: str, cookie: str = "") -> str:
    req = urllib.request.Request(url, headers={"Cookie": cookie} if cookie else {})
    with urllib.request.urlopen(req, timeout=20) as resp:
        return resp.read().decode()


def test_replay_refuses_data_without_a_session(replay):
    anon = Client(replay.url)
    for path in ("api/tree/nodes", "api/tree/at", "api/tree/at?t=3", "api/me"):
        code, body, _ = anon.call(path)
        assert code == 401 and body["error"] == "not logged in", path
    forged = Client(replay.url)
    code, _, _ = forged.call("api/tree/nodes", headers={
        "Cookie": "feeder_replay_session=" + "A" * 43})
    assert code == 401
    page = _page(replay.url)
    assert 'id="login-form"' in page and "tree.js" not in page
    assert anon.login("alice", "not-her-password")[0] == 401
    assert anon.login("mallory", PASSWORD)[0] == 401
    assert anon.call("api/tree/nodes")[0] == 401


def test_a_signed_in_viewer_gets_the_run(replay):
    viewer = Client(replay.url)
    code, body, _ = viewer.login("alice", PASSWORD)
    assert code == 200 and body["user"] == "alice"
    code, body, _ = viewer.call("api/tree/nodes")
    assert code == 200 and len(body["nodes"]) > 10
    code, body, _ = viewer.call("api/tree/at?t=3")
    assert code == 200 and "board" in body
    assert "tree.js" in _page(replay.url, viewer.cookie)
    assert viewer.call("api/logout", {})[0] == 200
    assert viewer.call("api/tree/nodes")[0] == 401


def test_the_start_up_lines_say_what_protects_the_replay(replay):
    err = replay.err.read_text()
    assert "needs a session from the users file" in err and str(replay.users) in err


def test_replay_without_users_is_one_line(tmp_path, replay):
    res = feeder_cli("replay", str(replay.db), "--ui", "127.0.0.1:0", "--users",
                     str(tmp_path / "nobody.json"))
    assert res.returncode == 2 and "no users in" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
