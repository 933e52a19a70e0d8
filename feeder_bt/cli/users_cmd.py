"""``feeder users add|remove|list|role|release-control|set|settings``: who may log in to
the operator UI (``feeder run --ui``), and its access settings.

Passwords are asked for twice on the terminal (never echoed, never an argument where
``ps`` would show them), or read as one line from standard input with ``--password-stdin``
for scripts. The file keeps salted scrypt hashes only; see docs/operator-ui.md. A running UI
watches the file: removing a user or changing a password ends their sessions at once, and
``release-control`` frees control (recorded in the event log).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import getpass
import json
import sys
from typing import Any

from feeder_bt.control.access import SETTINGS, Settings, parse_setting
from feeder_bt.control.users import (
    ROLES,
    UsersError,
    UsersFile,
    check_name,
    check_password,
    default_path,
    group_or_world_readable,
)


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``users`` on the ``feeder`` sub-command parsers."""
    p = subparsers.add_parser("users", help="add, remove and list the operator UI's users")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--users", metavar="FILE",
                        help=f"the users file (default {default_path()})")
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION",
                           parser_class=type(p))
    a = sub.add_parser("add", parents=[common], help="add a user (asks for the password)")
    a.add_argument("name", help="1-32 letters, digits, '_', '.' or '-'")
    a.add_argument("--password-stdin", action="store_true",
                   help="read the password as one line from standard input (for scripts)")
    a.add_argument("--replace", action="store_true",
                   help="set a new password for an existing user")
    r = sub.add_parser("remove", parents=[common],
                       help="remove a user (their sessions and control end at once)")
    r.add_argument("name")
    sub.add_parser("list", parents=[common], help="list the users, one per line")
    ro = sub.add_parser("role", parents=[common],
                        help="make a user an admin (may force control free) or an operator")
    ro.add_argument("name")
    ro.add_argument("role", choices=ROLES)
    sub.add_parser("release-control", parents=[common],
                   help="force control free on the running UI (recorded in the event log)")
    se = sub.add_parser("set", parents=[common], help="change an access setting: "
                        + "; ".join(f"{k}: {v}" for k, v in SETTINGS.items()))
    se.add_argument("key", choices=list(SETTINGS), metavar="KEY")
    se.add_argument("values", nargs="*", metavar="VALUE",
                    help="the value(s); none resets the setting to its default")
    sub.add_parser("settings", parents=[common], help="print the access settings as JSON")
    p.set_defaults(handler=cmd_users)
    return p


def read_password(from_stdin: bool, name: str = "") -> str:
    """The new password: one line of stdin, or asked twice on the terminal."""
    if from_stdin:
        line = sys.stdin.readline()
        if not line:
            raise UsersError("--password-stdin: standard input is empty")
        return check_password(line.rstrip("\r\n"), name)
    if not sys.stdin.isatty():
        raise UsersError("no terminal to ask for the password on: use --password-stdin")
    try:
        first = getpass.getpass("password: ")
        check_password(first, name)
        if getpass.getpass("again: ") != first:
            raise UsersError("the two passwords differ; nothing changed")
    except EOFError:
        raise UsersError("no password given; nothing changed") from None
    return first


def _set(users: UsersFile, key: str, values: list[str]) -> None:
    current = users.section("settings")
    if values:
        raw: Any = values if key in ("hosts", "proxies") else values[0]
        if key not in ("hosts", "proxies") and len(values) > 1:
            raise UsersError(f"{key}: one value, got {len(values)}")
        parse_setting(key, raw)                      # one line naming what is wrong
        current[key] = raw
    else:
        current.pop(key, None)
    users.set_section("settings", current)


def cmd_users(args: argparse.Namespace) -> int:
    users = UsersFile(args.users)
    if group_or_world_readable(users.path):
        print(f"feeder: warning: {users.path} may be read by other users: chmod 600 it",
              file=sys.stderr)
    if args.action == "role":
        users.set_role(args.name, args.role)
        print(f"user {args.name} is now an {args.role}")
        return 0
    if args.action == "release-control":
        if not users.names():
            raise UsersError(f"no users in {users.path}: no UI uses this file")
        seq = int(users.section("release_control").get("seq", 0) or 0) + 1
        users.set_section("release_control", {
            "seq": seq, "by": getpass.getuser(),
            "at": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")})
        print(f"asked the operator UI using {users.path} to free control (a running UI does "
              "so within a second and records it)")
        return 0
    if args.action == "set":
        _set(users, args.key, args.values)
        now = Settings.of(users.section("settings")).as_dict()[args.key]
        print(f"{args.key}: {json.dumps(now)}")
        return 0
    if args.action == "settings":
        print(json.dumps(Settings.of(users.section("settings")).as_dict(), indent=2))
        return 0
    if args.action == "list":
        names = users.names()
        for name in names:
            print(name + (" (admin)" if users.role(name) == "admin" else ""))
        if not names:
            print(f"no users in {users.path}", file=sys.stderr)
        return 0
    if args.action == "remove":
        users.remove(args.name)
        print(f"removed user {args.name} from {users.path} (their sessions and control end "
              "at once)")
        return 0
    check_name(args.name)                   # before asking for a password
    existed = args.name in users.load()
    if existed and not args.replace:
        raise UsersError(f"user {args.name!r} already exists in {users.path} (use --replace "
                         "to set a new password)")
    users.add(args.name, read_password(args.password_stdin, args.name), replace=args.replace)
    print(f"{'new password for' if existed else 'added'} user {args.name} in {users.path}")
    return 0
