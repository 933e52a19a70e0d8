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


class UsageError(FeederError):
    """A command-line mistake found after parsing (options that do not go together, an
    output path that cannot be written)."""

    exit_code = 2


#: At most this many problems are shown at once; the rest are counted ("... and N more").
MAX_PROBLEMS = 50


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

    @property
    def problems(self) -> list[ConfigError]:
        """Every problem this error stands for, each a one-line ``ConfigError``."""
        return [self]

    def lines(self, limit: int = MAX_PROBLEMS) -> list[str]:
        """One line per problem, at most ``limit`` of them and then how many more."""
        shown = [str(p) for p in self.problems[:limit]]
        more = len(self.problems) - len(shown)
        return shown + ([f"... and {more} more problem{'s' if more > 1 else ''}"] if more else [])

    @staticmethod
    def of(problems: list[ConfigError]) -> ConfigError:
        """The one error to raise for ``problems`` (not empty): the problem itself when there
        is only one, so a file with one mistake still reads as one line."""
        return problems[0] if len(problems) == 1 else ConfigProblems(problems)


class ConfigProblems(ConfigError):
    """Several problems found in one go (every independent mistake of a file, not only the
    first). ``file``, ``line`` and ``key`` are the first's; the message is one line per
    problem (at most ``MAX_PROBLEMS``)."""

    def __init__(self, problems: list[ConfigError]) -> None:
        first = problems[0]
        self._problems = list(problems)
        self.file, self.line, self.key, self.what = first.file, first.line, first.key, first.what
        FeederError.__init__(self, "\n".join(self.lines()))

    @property
    def problems(self) -> list[ConfigError]:
        return self._problems


class HalError(FeederError):
    """A hardware operation failed; ``kind`` names the fault for statistics and recovery."""

    kind = "hal"


class ServoTimeout(HalError):
    kind = "servo_timeout"


class PowerOff(HalError):
    """The arm lost power from outside the program: an e-stop, a guard door, a light curtain
    (V+ -604 *Robot power off*, or the server's -9007 with its e-stop input on). Never
    recovered by software, whatever ``recover_power_on`` says: a guard that resets itself
    must not give the arm its power back. The cell goes to FAULT; a person releases the
    stop, turns arm power on at the controller and resets the cell."""

    kind = "power_off"


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


class CardFault(ConveyorFault):
    """The conveyor controller's own programs stopped (a thread that cannot be restarted,
    a stuck input monitor): no shake or retry can help, only an operator's reset."""

    kind = "card_fault"


class PlateFault(HalError):
    """A plate feeder's drive reported an error (AnyFeeder: a servo error, an error
    state, no sync signal); the message carries the manual's words."""
    kind = "plate"


class JobCancelled(HalError):
    kind = "cancelled"


class AccountingError(FeederError):
    """The simulated cell lost or created a part: always a bug, never tolerated."""
