"""Which robots the part server trusts (docs/part-server.md, "Robots must be trusted").

The robots file (``feeder run --part-server ... --robots FILE``) names each robot and how it
proves who it is: a secret, an allow-list of addresses it connects from, or both (then the
secret is accepted only from those addresses)::

    {"format": "feeder_bt robots 1",
     "max_outstanding": 4,
     "robots": {"cobra1": {"secret_sha256": "9f86d0...", "addresses": ["10.0.0.21"]},
                "cell2":  {"addresses": ["10.0.0.22"]},
                "ur5":    {"secret_sha256": "...", "plain_secret": true}}}

A robot with a secret proves it by challenge and response (``core.part_protocol``): the
server sends a fresh nonce on each connection and the robot answers
HMAC-SHA256(SHA-256(secret), nonce), so neither the secret nor anything that works on
another connection crosses the network. The HMAC key is the SHA-256 the file already
keeps, so the file format is unchanged, and that hash is now the credential: whoever
reads the file can answer for the robot. The file is written mode 0600 and must be
protected like a password file. ``plain_secret: true`` lets one robot still send
``HELLO NAME SECRET`` (a robot language without HMAC-SHA256), on a trusted network only:
that line can be captured and replayed. It is off unless written.

Secrets are random tokens (``python -m feeder_bt.plant.robots add NAME --robots FILE``
makes one, prints it once and stores only its SHA-256), so a fast hash is enough: no guess
list reaches a 32-byte random token. Without a robots file only this machine (loopback
peers) is trusted, each connection on its own.
"""

from __future__ import annotations

import argparse
import hashlib
import hmac
import ipaddress
import json
import os
import re
import secrets
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from feeder_bt.core.errors import FeederError
from feeder_bt.core.part_protocol import prove

FORMAT = "feeder_bt robots 1"
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_.-]{0,31}")
MAX_OUTSTANDING = 4           # parts handed to one robot and not yet reported, at most


class RobotsError(FeederError):
    exit_code = 2


@dataclass(frozen=True)
class Robot:
    name: str
    secret_sha256: str | None = None
    addresses: frozenset[str] = frozenset()
    plain_secret: bool = False          # HELLO NAME SECRET accepted (replayable: opt-in)


@dataclass
class RobotTrust:
    """The robots file as the part server uses it (``None`` file: loopback only)."""

    robots: dict[str, Robot] = field(default_factory=dict)
    max_outstanding: int = MAX_OUTSTANDING
    path: Path | None = None

    @classmethod
    def load(cls, path: str | Path | None) -> RobotTrust:
        if path is None:
            return cls()
        p = Path(path).expanduser()
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except OSError as e:
            raise RobotsError(f"{p}: cannot read the robots file: {e.strerror}") from None
        except json.JSONDecodeError as e:
            raise RobotsError(f"{p}:{e.lineno}: not a robots file (bad JSON: {e.msg})") \
                from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT \
                or not isinstance(doc.get("robots"), dict):
            raise RobotsError(f"{p}: not a robots file (expected \"format\": \"{FORMAT}\" "
                              "and a \"robots\" object)")
        n = doc.get("max_outstanding", MAX_OUTSTANDING)
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 100:
            raise RobotsError(f"{p}: max_outstanding: a whole number 1-100, got {n!r}")
        robots = {}
        for name, entry in doc["robots"].items():
            robots[name] = _robot(p, name, entry)
        return cls(robots, n, p)

    def by_address(self, ip: str) -> Robot | None:
        """The robot an address alone identifies (an entry with addresses, no secret)."""
        for r in self.robots.values():
            if r.secret_sha256 is None and ip in r.addresses:
                return r
        return None

    def _candidate(self, name: str, ip: str) -> Robot | None:
        r = self.robots.get(name)
        if r is None or r.secret_sha256 is None or (r.addresses and ip not in r.addresses):
            return None
        return r

    def answer(self, name: str, nonce: str, response: str, ip: str) -> Robot | None:
        """The robot that answered the challenge ``nonce`` with ``response`` (``PROOF``)
        from ``ip`` proves to be, or None. The key is the stored SHA-256 of its secret."""
        r = self._candidate(name, ip)
        if r is None or r.secret_sha256 is None:
            prove(b"\0" * 32, nonce)            # the same work either way
            return None
        want = prove(bytes.fromhex(r.secret_sha256), nonce)
        got = response.lower().encode("utf-8", "replace")
        return r if hmac.compare_digest(want.encode("ascii"), got) else None

    def hello(self, name: str, secret: str, ip: str) -> Robot | None:
        """The robot the plain ``HELLO name secret`` from ``ip`` proves to be, or None:
        only for a robot the file lets use it (``plain_secret``), as it can be replayed."""
        r = self._candidate(name, ip)
        if r is None or not r.plain_secret or r.secret_sha256 is None:
            return None
        got = hashlib.sha256(secret.encode("utf-8", "replace")).hexdigest()
        return r if hmac.compare_digest(got, r.secret_sha256) else None

    def add_runtime(self, name: str) -> str:
        """A robot known only to this process (the simulated robot): its secret."""
        token = secrets.token_urlsafe(24)
        self.robots[name] = Robot(name, hashlib.sha256(token.encode()).hexdigest())
        return token


def _robot(p: Path, name: str, entry: Any) -> Robot:
    here = f"{p}: robots.{name}"
    if not NAME_RE.fullmatch(name):
        raise RobotsError(f"{here}: a name of 1-32 letters, digits, '_', '.', '-', starting "
                          "with a letter")
    if not isinstance(entry, dict) or set(entry) - {"secret_sha256", "addresses",
                                                     "plain_secret"}:
        raise RobotsError(f"{here}: an object with secret_sha256 and/or addresses "
                          "(and plain_secret)")
    plain = entry.get("plain_secret", False)
    if not isinstance(plain, bool):
        raise RobotsError(f"{here}.plain_secret: true or false")
    if plain and entry.get("secret_sha256") is None:
        raise RobotsError(f"{here}.plain_secret: only with secret_sha256")
    digest = entry.get("secret_sha256")
    if digest is not None and (not isinstance(digest, str)
                               or not re.fullmatch(r"[0-9a-f]{64}", digest)):
        raise RobotsError(f"{here}.secret_sha256: 64 lower-case hex digits")
    addrs = entry.get("addresses", [])
    if not isinstance(addrs, list) or not all(isinstance(a, str) for a in addrs):
        raise RobotsError(f"{here}.addresses: a list of IP addresses")
    out = []
    for a in addrs:
        try:
            out.append(str(ipaddress.ip_address(a.strip())))
        except ValueError:
            raise RobotsError(f"{here}.addresses: {a!r} is not an IP address") from None
    if digest is None and not out:
        raise RobotsError(f"{here}: give secret_sha256, addresses, or both")
    return Robot(name, digest, frozenset(out), plain)


def _write(path: Path, doc: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".robots-", dir=path.parent)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        os.fchmod(fd, 0o600)
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    """``python -m feeder_bt.plant.robots add NAME --robots FILE [--address IP...]``: add a
    robot (a new secret, printed once) or ``allow NAME --address IP...`` (addresses only)."""
    ap = argparse.ArgumentParser(prog="python -m feeder_bt.plant.robots")
    ap.add_argument("action", choices=["add", "allow", "remove"])
    ap.add_argument("name")
    ap.add_argument("--robots", required=True, metavar="FILE")
    ap.add_argument("--address", action="append", default=[], metavar="IP")
    ap.add_argument("--plain-secret", action="store_true",
                    help="also accept the replayable HELLO NAME SECRET from this robot "
                         "(a robot language without HMAC-SHA256; trusted networks only)")
    args = ap.parse_args(argv)
    path = Path(args.robots).expanduser()
    try:
        doc = json.loads(path.read_text()) if path.exists() else \
            {"format": FORMAT, "max_outstanding": MAX_OUTSTANDING, "robots": {}}
        RobotTrust.load(path if path.exists() else None)
        robots = doc.setdefault("robots", {})
        if args.action == "remove":
            robots.pop(args.name, None)
        else:
            entry: dict[str, Any] = {"addresses": args.address} if args.address else {}
            token = None
            if args.action == "add":
                token = secrets.token_urlsafe(24)
                entry["secret_sha256"] = hashlib.sha256(token.encode()).hexdigest()
                if args.plain_secret:
                    entry["plain_secret"] = True
            robots[args.name] = entry
            _robot(path, args.name, entry)
            if token:
                how = (f"sends HELLO {args.name} SECRET, replayable: trusted networks only"
                       if args.plain_secret else "answers the part server's challenge "
                       "with it")
                print(f"robot {args.name}: its secret (shown once; the robot {how}): "
                      f"{token}")
        _write(path, doc)
    except (FeederError, OSError, json.JSONDecodeError) as e:
        print(f"robots: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
