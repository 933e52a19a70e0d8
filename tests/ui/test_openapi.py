"""The dashboard's HTTP API is described (OpenAPI at /api/openapi.json, docs/operator-ui.md),
every route and only those, and the login form posts the fields /api/login reads."""

from __future__ import annotations

import re
from pathlib import Path

from starlette.routing import Mount

from feeder_bt.control.operate import COMMANDS
from feeder_bt.ui.openapi import LOGIN_FIELDS, spec
from tests.support.uiutil import Browser, make_ui

ROOT = Path(__file__).resolve().parents[2]


def test_every_route_is_described_and_nothing_else(tmp_path):
    ui, _, _ = make_ui(tmp_path)
    served = {re.sub(r"\{(\w+):\w+\}", r"{\1}", r.path) for r in ui.app.routes
              if not isinstance(r, Mount) and r.path != "/"}
    assert served == set(spec()["paths"])


def test_the_description_is_served_and_names_the_commands(tmp_path):
    ui, _, _ = make_ui(tmp_path)
    code, body = Browser(ui).call("GET", "/api/openapi.json")
    assert code == 200 and body["openapi"].startswith("3.")
    cmd = body["paths"]["/api/command"]["post"]["requestBody"]["content"]["application/json"]
    assert cmd["schema"]["properties"]["command"]["enum"] == list(COMMANDS)


def test_the_login_form_posts_the_fields_the_api_reads(tmp_path):
    html = (ROOT / "feeder_bt/ui/static/index.html").read_text()
    form = re.search(r'<form id="login-form".*?</form>', html, flags=re.S).group(0)
    assert tuple(re.findall(r'<input[^>]* name="(\w+)"', form)) == LOGIN_FIELDS
    js = (ROOT / "feeder_bt/ui/static/app.js").read_text()
    assert re.search(r'api\("/api/login", \{\s*user: .*, password: ', js)
    login = spec()["paths"]["/api/login"]["post"]["requestBody"]["content"]
    assert tuple(login["application/json"]["schema"]["properties"]) == LOGIN_FIELDS
    ui, _, _ = make_ui(tmp_path)
    b = Browser(ui)
    code, _ = b.call("POST", "/api/login", dict(zip(LOGIN_FIELDS, ("alice", "nope"), strict=True)))
    assert code == 401                                   # read, checked and refused
    code, body = b.call("POST", "/api/login", {"username": "alice", "password": "x"})
    assert code == 400 and "user name" in body["error"]
    doc = (ROOT / "docs/operator-ui.md").read_text()
    assert "/api/openapi.json" in doc and '"user"' in doc
