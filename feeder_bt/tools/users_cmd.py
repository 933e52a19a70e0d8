"""``feeder users add|remove|list``: who may log in to the operator UI (``feeder run --ui``).

Passwords are asked for twice on the terminal (never echoed, never an argument where
``ps`` would show them), or read as one line from standard input with ``--password-stdin``
for scripts. The file keeps salted scrypt hashes only; see docs/operator-ui.md.
"""

from __future__ import annotations

import argparse
import getpass
import sys
from typing import Any

from ..ui.users import UsersError, UsersFile, check_name, check_password, default_path


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
    r = sub.add_parser("remove", parents=[common], help="remove a user (their sessions end)")
    r.add_argument("name")
    sub.add_parser("list", parents=[common], help="list the users, one per line")
    p.set_defaults(handler=cmd_users)
    return p


def read_password(from_stdin: bool) -> str:
    """The new password: one line of stdin, or asked twice on the terminal."""
    if from_stdin:
        line = sys.stdin.readline()
        if not line:
            raise UsersError("--password-stdin: standard input is empty")
        return check_password(line.rstrip("\r\n"))
    if not sys.stdin.isatty():
        raise UsersError("no terminal to ask for the password on: use --password-stdin")
    try:
        first = getpass.getpass("password: ")
        check_password(first)
        if getpass.getpass("again: ") != first:
            raise UsersError("the two passwords differ; nothing changed")
    except EOFError:
        raise UsersError("no password given; nothing changed") from None
    return first


def cmd_users(args: argparse.Namespace) -> int:
    users = UsersFile(args.users)
    if args.action == "list":
        names = users.names()
        for name in names:
            print(name)
        if not names:
            print(f"no users in {users.path}", file=sys.stderr)
        return 0
    if args.action == "remove":
        users.remove(args.name)
        print(f"removed user {args.name} from {users.path} (their sessions end at their next "
              "request)")
        return 0
    check_name(args.name)                   # before asking for a password
    existed = args.name in users.load()
    if existed and not args.replace:
        raise UsersError(f"user {args.name!r} already exists in {users.path} (use --replace "
                         "to set a new password)")
    users.add(args.name, read_password(args.password_stdin), replace=args.replace)
    print(f"{'new password for' if existed else 'added'} user {args.name} in {users.path}")
    return 0
