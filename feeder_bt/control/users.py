"""The users file: who may log in to the operator UI (``feeder users``).

The thesis's GUI sent and kept passwords in plain text. Here a password is never stored:
each user has a random salt and an scrypt hash (memory-hard, ~50 ms to check), so a stolen
file costs an attacker that much per guess per user. The file is JSON, written atomically
with mode 0600; it is re-read when it changes, so ``feeder users add/remove`` takes effect
on a running UI at once (a removed user's, or a changed password's, sessions end).

The same file holds the UI's access settings (``settings``: Host names, proxies, session
times; see ``access.Settings``) and the last ``feeder users release-control`` request: it is
the one private file an administrator edits, and a running UI already watches it.
"""

from __future__ import annotations

import base64
import datetime as _dt
import hashlib
import hmac
import json
import os
import re
import secrets
import sys
import tempfile
from pathlib import Path
from typing import Any

from feeder_bt.core.errors import FeederError

FORMAT = "feeder_bt users 1"
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,31}")
MIN_PASSWORD = 8
MAX_PASSWORD = 1024            # scrypt of a megabyte "password" is a cheap denial of service
ROLES = ("operator", "admin")  # an admin may also force control free from the dashboard
# Refused whatever their length: the first guesses of anyone who tries (compared without
# case, and after stripping spaces); a password made of one repeated character, or equal
# to the user name, is refused too.
WEAK_PASSWORDS = frozenset({
    "password", "password1", "password12", "password123", "passw0rd", "12345678",
    "123456789", "1234567890", "87654321", "11111111", "qwertyui", "qwerty123", "qwertyuiop",
    "iloveyou", "letmein1", "letmein!", "changeme", "changeit", "welcome1", "abcdefgh",
    "abcd1234", "1q2w3e4r", "administrator", "admin123", "operator", "feeder_bt",
    "feederbt", "feeder123", "trustno1", "sunshine", "football", "baseball", "monkey123",
})

# scrypt cost: n=2**14, r=8 is 16 MiB and about 50 ms per check on one core.
SCRYPT_N, SCRYPT_R, SCRYPT_P, SCRYPT_DKLEN, SALT_BYTES = 2 ** 14, 8, 1, 32, 16


class UsersError(FeederError):
    """A bad user name, password or users file: a usage mistake (exit 2)."""

    exit_code = 2


def default_path() -> Path:
    """``$XDG_CONFIG_HOME/feeder_bt/users.json`` (``~/.config/...``): outside any work tree,
    so the file is not committed or copied with a project by accident."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "feeder_bt" / "users.json"


def check_name(name: str) -> str:
    """A user name: 1-32 letters, digits, ``_ . -``, starting with a letter or digit."""
    if not NAME_RE.fullmatch(name):
        raise UsersError(f"bad user name {name!r}: use 1-32 letters, digits, '_', '.' or '-', "
                         "starting with a letter or digit")
    return name


MIN_SCORE = 3          # zxcvbn's "safely unguessable" band: about 10^8 guesses and more
# words an attacker tries with any user's name here: the project's and the cell's
CONTEXT_WORDS = ["feeder", "feeder_bt", "feederbt", "cell", "operator", "admin", "robot",
                 "cobra", "adept", "galil", "conveyor"]


def check_password(password: str, name: str = "") -> str:
    """A new password: long enough, not too long, and not one anybody would guess first:
    judged by zxcvbn (Dropbox's estimator: dictionaries, keyboard walks, dates, l33t, the
    user's name) when it is installed, else by the bundled word list."""
    if len(password) < MIN_PASSWORD:
        raise UsersError(f"password too short: at least {MIN_PASSWORD} characters")
    if len(password) > MAX_PASSWORD:
        raise UsersError(f"password too long: at most {MAX_PASSWORD} characters")
    folded = password.strip().casefold()
    if not folded:
        raise UsersError("password refused: it is all blanks")
    if folded in WEAK_PASSWORDS or len(set(folded)) == 1 or folded == name.casefold():
        raise UsersError("password refused: it is among the first an attacker would try")
    why = _too_guessable(password, name)
    if why:
        raise UsersError(f"password refused: {why}")
    return password


def _too_guessable(password: str, name: str) -> str | None:
    """Why ``password`` is too easy to guess, or None."""
    try:
        from zxcvbn import zxcvbn
    except ImportError:
        return _guessable_by_list(password, name)
    r = zxcvbn(password[:100], user_inputs=[name, *CONTEXT_WORDS] if name else CONTEXT_WORDS)
    if r["score"] >= MIN_SCORE:
        return None
    hint = (r.get("feedback") or {}).get("warning") or "it is too easy to guess"
    return f"{hint.rstrip('.')} (choose a longer one: a few unrelated words)"


_LEET = str.maketrans("@4310$5!7+", "aaeiossitt")
_COMMON_WORDS = frozenset({
    "password", "passw0rd", "letmein", "welcome", "qwerty", "qwertz", "azerty", "admin",
    "administrator", "login", "master", "dragon", "monkey", "shadow", "sunshine", "princess",
    "football", "baseball", "soccer", "hockey", "superman", "batman", "trustno", "iloveyou",
    "summer", "winter", "spring", "autumn", "fall", "january", "february", "march", "april",
    "june", "july", "august", "september", "october", "november", "december", "monday",
    "friday", "secret", "changeme", "default", "test", "guest", "hello", "freedom",
    "whatever", "starwars", "computer", "internet", "abc", "abcd", "asdf", "zxcv",
    "qwertyuiop", "qwertyui", "asdfgh", "asdfghjkl", "zxcvbnm", "qazwsx", "qwer",
    *CONTEXT_WORDS,
})


def _guessable_by_list(password: str, name: str) -> str | None:
    """Without zxcvbn: a common word or the user's name, in any case, in l33t, with digits
    and symbols around it, is refused."""
    core = password.casefold().strip("0123456789!@#$%^&*()_+-=.,;:?'\"/\\ ")
    core = "".join(ch for ch in core.translate(_LEET) if ch.isalpha())
    if not core or core in _COMMON_WORDS or (name and core == name.casefold()):
        return "a common word or your name with digits and symbols added"
    return None


def group_or_world_readable(path: Path) -> bool:
    """True if users other than the file's owner may read (or write) the users file."""
    try:
        return bool(path.stat().st_mode & 0o077)
    except OSError:
        return False


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def hash_password(password: str, *, n: int = SCRYPT_N, r: int = SCRYPT_R, p: int = SCRYPT_P,
                  salt: bytes | None = None) -> str:
    """``scrypt$N$r$p$SALT$HASH`` (base64): the parameters travel with the hash, so the
    cost can be raised later without invalidating existing users."""
    salt = secrets.token_bytes(SALT_BYTES) if salt is None else salt
    digest = hashlib.scrypt(password.encode("utf-8"), salt=salt, n=n, r=r, p=p,
                            dklen=SCRYPT_DKLEN, maxmem=256 * n * r + (1 << 20))
    return f"scrypt${n}${r}${p}${_b64(salt)}${_b64(digest)}"


def verify_password(password: str, stored: str) -> bool:
    """True if ``password`` matches ``stored``; a malformed or weak entry never matches."""
    try:
        scheme, n_s, r_s, p_s, salt_s, digest_s = stored.split("$")
        n, r, p = int(n_s), int(r_s), int(p_s)
        salt, digest = base64.b64decode(salt_s, validate=True), base64.b64decode(digest_s,
                                                                                   validate=True)
    except (ValueError, TypeError):
        return False
    if scheme != "scrypt" or n < 2 ** 10 or n > 2 ** 20 or not 1 <= r <= 32 or not 1 <= p <= 16:
        return False
    if len(password) > MAX_PASSWORD:
        return False
    try:
        got = hashlib.scrypt(password.encode("utf-8"), salt=salt, n=n, r=r, p=p,
                             dklen=len(digest), maxmem=256 * n * r + (1 << 20))
    except (ValueError, MemoryError):
        return False
    return hmac.compare_digest(got, digest)


_DUMMY: str | None = None


def _dummy_hash() -> str:
    """A hash to check unknown names against, so that a wrong name takes as long as a
    wrong password (no user enumeration by timing)."""
    global _DUMMY
    if _DUMMY is None:
        _DUMMY = hash_password(secrets.token_urlsafe(16))
    return _DUMMY


class UsersFile:
    """The users file on disk; ``load()`` caches until the file changes."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path).expanduser() if path else default_path()
        self._users: dict[str, dict[str, Any]] = {}
        self._stamp: tuple[int, ...] | None = None
        self._warned: str | None = None
        self._doc: dict[str, Any] = {}

    # ------------------------------------------------------------------ reading
    def _read(self) -> dict[str, dict[str, Any]]:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            self._doc = {}
            return {}
        except OSError as e:
            raise UsersError(f"{self.path}: cannot read the users file: {e.strerror}") from None
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as e:
            raise UsersError(f"{self.path}:{e.lineno}: not a feeder users file "
                             f"(bad JSON: {e.msg})") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT \
                or not isinstance(doc.get("users"), dict):
            raise UsersError(f"{self.path}: not a feeder users file (expected "
                             f"\"format\": \"{FORMAT}\" and a \"users\" object)")
        users = doc["users"]
        for name, entry in users.items():
            if not NAME_RE.fullmatch(name) or not isinstance(entry, dict) \
                    or not str(entry.get("hash", "")).startswith("scrypt$"):
                raise UsersError(f"{self.path}: users.{name}: not a user entry with an "
                                 "scrypt hash")
            if entry.get("role", "operator") not in ROLES:
                raise UsersError(f"{self.path}: users.{name}.role: one of {', '.join(ROLES)}")
        for key in ("settings", "release_control"):
            if not isinstance(doc.get(key, {}), dict):
                raise UsersError(f"{self.path}: {key}: must be an object")
        self._doc = doc
        return users

    def load(self) -> dict[str, dict[str, Any]]:
        """The users, re-read only when the file's size or modification time changed."""
        try:
            st = self.path.stat()      # a new inode at every atomic write: never missed
            stamp: tuple[int, ...] | None = (st.st_ino, st.st_mtime_ns, st.st_size)
        except FileNotFoundError:
            stamp = None
        except OSError as e:
            raise UsersError(f"{self.path}: cannot read the users file: {e.strerror}") from None
        if stamp != self._stamp or stamp is None:
            self._users = self._read()
            self._stamp = stamp
        return self._users

    def load_or_empty(self) -> dict[str, dict[str, Any]]:
        """For the running server: a damaged file locks everyone out (fails closed) with
        one warning, instead of stopping the cell."""
        try:
            users = self.load()
        except UsersError as e:
            if self._warned != str(e):
                print(f"feeder: operator UI: {e}; nobody can log in until it is fixed",
                      file=sys.stderr)
                self._warned = str(e)
            self._users, self._stamp, self._doc = {}, None, {}
            return {}
        self._warned = None
        return users

    def names(self) -> list[str]:
        return sorted(self.load())

    @property
    def stamp(self) -> tuple[int, ...] | None:
        """Changes whenever the file was re-read with new contents (or went missing)."""
        return self._stamp

    def section(self, key: str) -> dict[str, Any]:
        """``settings`` or ``release_control`` as last read (empty if absent or damaged)."""
        self.load_or_empty()
        value = self._doc.get(key)
        return dict(value) if isinstance(value, dict) else {}

    def role(self, name: str) -> str:
        entry = self.load_or_empty().get(name)
        return str(entry.get("role", "operator")) if entry else ""

    def secret_of(self, name: str) -> str | None:
        """The user's stored hash: a session is bound to it, so a new password (or the
        user removed and added again) ends the sessions opened with the old one."""
        entry = self.load_or_empty().get(name)
        return str(entry["hash"]) if entry else None

    def exists(self, name: str) -> bool:
        return name in self.load_or_empty()

    def verify(self, name: str, password: str) -> bool:
        """Check a login; slow on purpose (scrypt), and as slow for an unknown name."""
        entry = self.load_or_empty().get(name)
        if entry is None:
            verify_password(password, _dummy_hash())
            return False
        return verify_password(password, str(entry["hash"]))

    # ------------------------------------------------------------------ writing
    def add(self, name: str, password: str, replace: bool = False) -> None:
        check_name(name)
        users = dict(self.load())
        if name in users and not replace:
            raise UsersError(f"user {name!r} already exists in {self.path} (use --replace to "
                             "set a new password)")
        twin = [n for n in users if n != name and n.casefold() == name.casefold()]
        if twin:
            raise UsersError(f"user {twin[0]!r} already exists in {self.path}: names that "
                             "differ only in case would be confused")
        check_password(password, name)
        role = users.get(name, {}).get("role")
        users[name] = {"hash": hash_password(password),
                       "added": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                       **({"role": role} if role else {})}
        self._write(users)

    def remove(self, name: str) -> None:
        users = dict(self.load())
        if name not in users:
            raise UsersError(f"no user {name!r} in {self.path}")
        del users[name]
        self._write(users)

    def set_role(self, name: str, role: str) -> None:
        if role not in ROLES:
            raise UsersError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
        users = dict(self.load())
        if name not in users:
            raise UsersError(f"no user {name!r} in {self.path}")
        users[name] = {**users[name], "role": role}
        self._write(users)

    def set_section(self, key: str, value: dict[str, Any]) -> None:
        """Replace ``settings`` or ``release_control`` (the users are kept as they are)."""
        users = dict(self.load())
        self._write(users, {**self._doc, key: value})

    def _write(self, users: dict[str, dict[str, Any]],
               doc_extra: dict[str, Any] | None = None) -> None:
        """Atomic replace with mode 0600: a reader sees the old file or the new one."""
        extra = self._doc if doc_extra is None else doc_extra
        doc = {"format": FORMAT, "users": dict(sorted(users.items())),
               **{k: v for k, v in extra.items() if k in ("settings", "release_control")}}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
            fd, tmp = tempfile.mkstemp(prefix=".users-", dir=self.path.parent)
            try:
                os.fchmod(fd, 0o600)
                with os.fdopen(fd, "w", encoding="utf-8") as f:
                    json.dump(doc, f, indent=2)
                    f.write("\n")
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, self.path)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError as e:
            raise UsersError(f"{self.path}: cannot write the users file: {e.strerror}") from None
        self._stamp = None
        self.load()
