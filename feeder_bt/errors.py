"""Typed errors.

Everything the project raises on purpose derives from ``FeederError`` so that the CLI can
print one clear line and exit non-zero instead of a traceback.
"""

from __future__ import annotations


def one_line(text: str) -> str:
    """Escape anything that would break a one-line message (a newline inside a YAML key)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class FeederError(Exception):
    """Base of every error the project raises deliberately."""

    exit_code = 1


class ConfigError(FeederError):
    """A scenario or cell description is wrong; the message reads ``FILE:LINE: key: what``."""

    exit_code = 2

    def __init__(self, message: str, file: str | None = None, line: int | None = None,
                 key: str | None = None) -> None:
        self.file, self.line, self.key, self.what = file, line, key, message
        where = ""
        if file:
            where = f"{file}:{line}: " if line else f"{file}: "
        super().__init__(one_line(f"{where}{key + ': ' if key else ''}{message}"))


class HalError(FeederError):
    """A hardware operation failed; ``kind`` names the fault for statistics and recovery."""

    kind = "hal"


class ServoTimeout(HalError):
    kind = "servo_timeout"


class EnvelopeError(HalError):
    kind = "envelope"


class MissedGrab(HalError):
    kind = "missed_grab"


class CommsLost(HalError):
    kind = "comms_lost"


class UnknownPart(HalError):
    """The gripper holds something no pick of this run gripped: the operator's to remove."""

    kind = "unknown_part"


class GrabFailed(HalError):
    kind = "grab_failed"


class ConveyorFault(HalError):
    kind = "conveyor"


class JobCancelled(HalError):
    kind = "cancelled"


class AccountingError(FeederError):
    """The simulated cell lost or created a part: always a bug, never tolerated."""
