"""Fault plans for the emulators: which command to reject, when to drop a connection,
stall a reply or time out a robot servo.

Link cuts at each phase of a command (the Adept emulator; the Galil's knows ``drop``):
``drop`` cuts the link when the command arrives, before anything is done (for a PICK: the
cell sent it, the robot never moved); ``drop_during`` cuts it ``after_s`` into the motion,
which the controller finishes anyway (a V+ task does not read its socket while it moves);
``drop_after`` lets the command finish and cuts the link instead of sending the reply
(after the grip, after the release).

A plan is a list of rules; each emulator asks ``plan.check(controller, command)`` before
it carries out a command and acts on the answer. Rules fire on the n-th matching command
(``nth``), on every n-th (``every``) or with a probability (``rate``, from the plan's own
seeded generator, so a run is repeatable).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

FAULT_KINDS = ("reject", "drop", "drop_during", "drop_after", "stall", "servo_timeout",
               # the pylon camera (controller "camera", command "TRIGGER";
               # emulators/pylon_camera.py): with "drop" (the camera disappears)
               "no_frame", "extra_trigger", "wrong_format")


@dataclass
class FaultRule:
    kind: str                     # one of FAULT_KINDS
    controller: str               # galil | adept | camera | plate (servo_timeout: ends m13)
    command: str = ""             # applies to commands starting with this (case-insensitive)
    nth: int | None = None        # fire on the n-th matching command only (1-based)
    every: int | None = None      # fire on every n-th matching command
    rate: float | None = None     # fire with this probability per matching command
    stall_s: float = 5.0          # for ``stall``: how long the reply is held back at most
    after_s: float = 0.2          # for ``drop_during``: when the link goes, into the motion
    seen: int = 0
    fired: int = 0
    # for ``stall``: set by ``release()``, ends the hold early (the Adept emulator). A test
    # of a time-out holds the reply "for ever" and releases it once the time-out was seen,
    # so the device is truly silent and no machine speed can trip or miss the time-out
    released: threading.Event = field(default_factory=threading.Event, repr=False,
                                      compare=False)

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; one of {', '.join(FAULT_KINDS)}")

    def release(self) -> None:
        """End a ``stall``'s hold now: the held reply goes out."""
        self.released.set()


@dataclass
class FaultPlan:
    rules: list[FaultRule] = field(default_factory=list)
    seed: int = 0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._lock = threading.Lock()
        self.log: list[tuple[str, str, str]] = []      # (controller, kind, command) fired

    def add(self, kind: str, controller: str, command: str = "", **kw) -> FaultRule:
        rule = FaultRule(kind, controller, command, **kw)
        with self._lock:
            self.rules.append(rule)
        return rule

    def check(self, controller: str, command: str) -> FaultRule | None:
        """The rule that fires for this command, if any (each call counts as one command)."""
        with self._lock:
            for rule in self.rules:
                if rule.controller != controller:
                    continue
                if not command.upper().startswith(rule.command.upper()):
                    continue
                rule.seen += 1
                fire = ((rule.nth is not None and rule.seen == rule.nth)
                        or (rule.every is not None and rule.seen % rule.every == 0)
                        or (rule.rate is not None and self._rng.random() < rule.rate))
                if fire:
                    rule.fired += 1
                    self.log.append((controller, rule.kind, command))
                    return rule
        return None
