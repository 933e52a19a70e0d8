"""The dashboard's HTTP API as an OpenAPI 3.1 description, served at ``/api/openapi.json``
. Built from the same constants the handlers use (the commands, the speed keys),
so it cannot drift from them; tests/ui/test_openapi.py checks every route is described and
that the login form posts the fields ``/api/login`` reads."""

from __future__ import annotations

from typing import Any

from feeder_bt.control.operate import COMMANDS, SPEED_KEYS

LOGIN_FIELDS = ("user", "password")     # the form's input names are the same (index.html)
CONTROL_ACTIONS = ("take", "release", "force-release")


def _json(schema: dict[str, Any]) -> dict[str, Any]:
    return {"required": True, "content": {"application/json": {"schema": schema}}}


def _ok(what: str) -> dict[str, Any]:
    return {"200": {"description": what},
            "4XX": {"description": 'refused: `{"error": "one line saying why"}`'}}


def spec() -> dict[str, Any]:
    """The OpenAPI document. Every state-changing request is a same-origin POST with a
    JSON body (``Content-Type: application/json``); the session is the cookie
    ``/api/login`` sets."""
    obj = {"type": "object"}
    return {
        "openapi": "3.1.0",
        "info": {"title": "feeder_bt operator dashboard", "version": "1",
                 "description": "See docs/operator-ui.md. Log in first: the session "
                                "cookie authorises everything else."},
        "paths": {
            "/api/login": {"post": {
                "summary": "log in; sets the session cookie",
                "requestBody": _json({**obj, "required": list(LOGIN_FIELDS), "properties": {
                    "user": {"type": "string"}, "password": {"type": "string"}}}),
                "responses": {**_ok("the session: user, admin, control"),
                              "429": {"description": "too many failed logins (Retry-After)"}}}},
            "/api/logout": {"post": {"summary": "end this session (and release control)",
                                     "responses": _ok("logged out")}},
            "/api/me": {"get": {"summary": "this session: user, admin, users, control",
                                "responses": _ok("the session")}},
            "/api/status": {"get": {"summary": "the cell's status (as the page shows it)",
                                    "responses": _ok("the status object")}},
            "/api/control": {"post": {
                "summary": "take or release control (force-release: admins only)",
                "requestBody": _json({**obj, "required": ["action"], "properties": {
                    "action": {"enum": list(CONTROL_ACTIONS)}}}),
                "responses": _ok("the new control state")}},
            "/api/command": {"post": {
                "summary": "operate the cell (the holder of control only)",
                "requestBody": _json({**obj, "required": ["command"], "properties": {
                    "command": {"enum": list(COMMANDS)},
                    "scenario": {"type": "string", "description": "load: a scenario file "
                                 "in the folder of the one `feeder run` was given"},
                    **{k: {"type": "number", "description": "speeds"} for k in SPEED_KEYS},
                    "engaged": {"type": "boolean", "description": "adjust: the "
                                "auto-adjuster on or off"}}}),
                "responses": _ok("the command's outcome")}},
            "/api/tree/nodes": {"get": {"summary": "the trees' nodes (id, parent, tree, "
                                        "name, kind)", "responses": _ok("the nodes")}},
            "/api/tree/at": {"get": {
                "summary": "the trees and blackboard at a time (default: the latest)",
                "parameters": [{"name": "t", "in": "query", "required": False,
                                "schema": {"type": "number"}}],
                "responses": _ok("statuses, blackboard, span and timeline marks")}},
            "/api/camera": {"get": {"summary": "the camera's last frame: what was located "
                                    "and rejected", "responses": _ok("frame metadata")}},
            "/api/camera/{name}": {"get": {
                "summary": "a frame as JPEG: name is SEQ.jpg, SEQ its number (at most 18 "
                           "digits; anything else is a 404)", "parameters": [
                    {"name": "name", "in": "path", "required": True,
                     "schema": {"type": "string", "pattern": "^[0-9]{1,18}\\.jpg$"}}],
                "responses": _ok("image/jpeg")}},
            "/api/openapi.json": {"get": {"summary": "this description",
                                          "responses": _ok("OpenAPI 3.1")}},
            "/ws": {"get": {"summary": "websocket: status, history and messages pushed as "
                            "they change (`update`), `logout` when the session ends",
                            "responses": {"101": {"description": "switching protocols"}}}},
        },
    }
