"""Argument types shared by the ``feeder`` sub-commands: a bad value is argparse's one-line
usage error (exit 2), named by the option, never a traceback."""

from __future__ import annotations

import argparse
import math
from pathlib import Path


def _number(text: str, ok, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and ok(v)):
        raise argparse.ArgumentTypeError(f"must be a finite number {what}, got {text}")
    return v


def positive(text: str) -> float:
    """A finite number > 0 (seconds, mm/s)."""
    return _number(text, lambda v: v > 0, "> 0")


def non_negative(text: str) -> float:
    """A finite number >= 0 (a budget that may be nothing)."""
    return _number(text, lambda v: v >= 0, ">= 0")


def positive_int(text: str) -> int:
    """A whole number >= 1 (trials, seeds, workers)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return v


def expect_kind(path: str, kind: str, how: str, hint: str | None = None) -> None:
    """A file given where another kind was expected is named as what it is, in one line
    (not a line per key the other kind does not have); ``hint`` says what to give instead."""
    import yaml

    from feeder_bt.config.loader import read_yaml_text
    from feeder_bt.config.schema import wrong_kind_error
    try:
        root = yaml.compose(read_yaml_text(Path(path), path), Loader=yaml.SafeLoader)
    except Exception:  # noqa: BLE001 - the real load reports it in one line
        return
    err = wrong_kind_error(root, kind, path, how, hint)
    if err is not None:
        raise err
