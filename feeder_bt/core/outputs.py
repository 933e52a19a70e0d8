"""Files a run writes (its report, an overlay, a plot): checked before the run starts, and
never lost at its end. A run of eight hours whose result cannot be written at the path the
operator gave still leaves it somewhere, named in one line.
"""

from __future__ import annotations

import os
import stat
import sys
import tempfile
import time
from pathlib import Path

from feeder_bt.core.errors import FeederError, UsageError


def check_output_file(path: str | Path, what: str) -> None:
    """Refuse, before anything runs, a path ``what`` (``--report``) cannot be written to: a
    directory, something that is not a regular file (``/proc/version``, a FIFO), a path
    under a file, a folder without write permission."""
    p = Path(path)
    where = f"{what} {path}"
    try:
        st = p.stat()
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise UsageError(f"{where}: a folder on the way is a file") from None
    except OSError as e:
        raise UsageError(f"{where}: {e.strerror or e}") from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise UsageError(f"{where}: is a directory; give a file name") from None
        if not stat.S_ISREG(st.st_mode) or str(p.resolve()).startswith("/proc/"):
            raise UsageError(f"{where}: is not a regular file")
        try:
            with open(p, "a"):
                pass
        except OSError as e:
            raise UsageError(f"{where}: cannot be written: {e.strerror or e}") from None
        return
    parent = p.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise UsageError(f"{where}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{where}: no permission to write in {parent}")


def write_or_fallback(path: str | Path, text: str, what: str, fallback_dir: str | Path) -> Path:
    """Write ``text`` to ``path``; if that fails (a full disk, a folder removed meanwhile),
    to a time-stamped file in ``fallback_dir`` (else the system's temporary folder), saying
    where in one line on standard error. Returns where it went."""
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        return p
    except OSError as e:
        why = e.strerror or str(e)
    name = f"{p.stem or 'report'}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}{p.suffix}"
    for folder in (Path(fallback_dir), Path(tempfile.gettempdir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            dest = folder / name
            dest.write_text(text)
        except OSError:
            continue
        print(f"feeder: cannot write the {what} to {path} ({why}); written to {dest} instead",
              file=sys.stderr)
        return dest
    raise FeederError(f"cannot write the {what} to {path} ({why}), nor to {fallback_dir} or "
                      "the temporary folder")
