"""The browser tests' one way to drive a browser: Debian's Chromium (never a browser
Playwright downloads) under Playwright, a user logging in as a person would, and the
screenshots in docs/.

A browser test module starts with ``sync_api = require_browser()``, which skips the whole
module, saying why, when Chromium or Playwright is missing; its tests take the
``browser`` fixture (one Chromium per module) and the ``shots`` fixture, both in
conftest.py.

Screenshots: every run takes them, into pytest's tmp_path, and checks they are not blank;
only ``python -m pytest --update-shots ...`` writes them into docs/ (smaller: a 256-colour
palette), so that a test run leaves the source tree as it was."""

from __future__ import annotations

import os
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
VIEWPORT = {"width": 1400, "height": 1000}
DOCS = Path(__file__).resolve().parents[2] / "docs"
UPDATE_SHOTS = "--update-shots"


def require_browser() -> ModuleType:
    """``playwright.sync_api``; called at a module's top, it skips that module when
    Chromium or Playwright for Python is missing."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium package "
                    "(apt-get install chromium; .ci/run does)", allow_module_level=True)
    return pytest.importorskip("playwright.sync_api",
                               reason="Playwright for Python not installed (pip install -e "
                                      "'.[test]')")


def new_page(browser: Any) -> Any:
    """A page in a fresh context (its own cookies: one person), the dashboard's size."""
    return browser.new_context(viewport=VIEWPORT).new_page()


def login(page: Any, url: str, user: str, password: str) -> None:
    """Open the dashboard and submit the login form (the outcome is the caller's to check)."""
    page.goto(url)
    page.fill("#login-user", user)
    page.fill("#login-password", password)
    page.click("#login-submit")


def compact_png(src: Path, dest: Path) -> None:
    """``src`` written to ``dest`` with a 256-colour palette: a third of the size or less,
    and flat UI colours survive it. Pillow comes with matplotlib (a runtime dependency)."""
    from PIL import Image

    with Image.open(src) as im:
        small = im.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT,
                                           dither=Image.Dither.NONE)
    tmp = dest.with_suffix(".tmp.png")
    small.save(tmp, optimize=True)
    os.replace(tmp, dest)                 # never a half-written picture in docs/


class Shots:
    """Takes the docs' screenshots: into ``tmp`` always, into docs/ when asked to."""

    def __init__(self, tmp: Path, update: bool) -> None:
        self.tmp, self.update = tmp, update

    def take(self, target: Any, name: str, min_bytes: int, **kw: Any) -> Path:
        """Screenshot ``target`` (a page or a locator) as ``name``; a picture under
        ``min_bytes`` is blank or nearly so. With --update-shots it becomes docs/NAME."""
        path = self.tmp / name
        target.screenshot(path=str(path), **kw)
        assert path.stat().st_size > min_bytes, f"{name}: {path.stat().st_size} bytes"
        if self.update:
            compact_png(path, DOCS / name)
        return path
