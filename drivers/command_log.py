"""Exposure commands sent to a live camera, and the frame each one took effect on.

A live camera learns which command a frame used from the exposure the frame reports (its *echo*): the
DAVIS logic reports each frame's exposure in ADC cycles (misc10 words), dv-processing a frame's exposure
in µs. :class:`CommandLog` keeps the commands still waiting for their frame and marks a command applied at
the first frame that starts after it was issued and echoes its value — within a tolerance, because an echo
need not equal the register exactly (a cycle of rounding in the logic is enough), and a rule that demanded
equality would never mark a command applied and never change the digital gain.

Memory stays bounded over a long session: at most :data:`PENDING_COMMANDS` wait for their frame (older ones
are superseded anyway) and :meth:`CommandLog.records` keeps the last :data:`COMMAND_HISTORY`.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.frames import Frame
from necviz.drivers.source import CAMERA, CommandRecord

#: commands kept for :meth:`CommandLog.records` (the oldest are forgotten; ``issued`` counts all)
COMMAND_HISTORY = 4096
#: commands still waiting for a frame exposed with them (a controller issues at most a few per frame)
PENDING_COMMANDS = 256


class _Command:
    """A command as issued; ``applied_start_us`` is filled in when a frame used it."""

    __slots__ = ("issue_time_us", "exposure_us", "gain", "value", "applied_start_us")

    def __init__(self, issue_time_us: int, exposure_us: float, gain: float, value: float):
        self.issue_time_us, self.exposure_us, self.gain, self.value = issue_time_us, exposure_us, gain, value
        self.applied_start_us: int | None = None

    def record(self) -> CommandRecord:
        return CommandRecord(self.issue_time_us, self.exposure_us, self.gain, self.applied_start_us)


class CommandLog:
    """Commands of one camera and the frames that used them (thread-safe: commands come from the control
    loop, frames from the stream).

    Parameters
    ----------
    tolerance_abs : float
        An echo within this much of a command's value (its unit: ADC cycles, µs) matches it ...
    tolerance_rel : float
        ... or within this fraction of the value, whichever is larger.
    """

    def __init__(self, tolerance_abs: float, tolerance_rel: float = 0.0):
        self.tolerance_abs = float(tolerance_abs)
        self.tolerance_rel = float(tolerance_rel)
        self._lock = threading.Lock()
        self._history: deque[_Command] = deque(maxlen=COMMAND_HISTORY)
        self._pending: deque[_Command] = deque(maxlen=PENDING_COMMANDS)  # not yet applied, oldest first
        #: every command received
        self.issued = 0
        #: the digital gain of the last command a frame used (1 before any)
        self.gain = 1.0

    def issue(self, issue_time_us: int, exposure_us: float, gain: float, value: float) -> None:
        """A command was sent: ``value`` is what a frame exposed with it will echo."""
        c = _Command(int(issue_time_us), float(exposure_us), float(gain), float(value))
        with self._lock:
            self._history.append(c)
            self._pending.append(c)
            self.issued += 1

    def matches(self, value: float, echo: float) -> bool:
        """Whether a frame echoing ``echo`` was exposed with a command of ``value``."""
        return abs(echo - value) <= max(self.tolerance_abs, self.tolerance_rel * abs(value))

    def frame(self, exposure_start_us: int, echo: float | None) -> float:
        """A frame exposed from ``exposure_start_us`` reported ``echo`` (``None``: it reports nothing, the newest
        command issued before it is taken). The newest waiting command issued no later than the frame's start
        whose value matches is marked applied at that start; it and the older ones (superseded before they
        took effect) stop waiting. Returns the digital gain to apply to the frame."""
        with self._lock:
            chosen = None
            for c in reversed(self._pending):
                if c.issue_time_us <= exposure_start_us and (echo is None or self.matches(c.value, echo)):
                    chosen = c
                    break
            if chosen is not None:
                chosen.applied_start_us = int(exposure_start_us)
                self.gain = chosen.gain
                while self._pending and self._pending.popleft() is not chosen:
                    pass
            return self.gain

    def records(self) -> list[CommandRecord]:
        """The last :data:`COMMAND_HISTORY` commands, each with the start of the first exposure that used it."""
        with self._lock:
            return [c.record() for c in self._history]


def check_command(camera: str, exposure_us, gain) -> tuple[float, float]:
    """A command for a single-camera source, checked: ``camera`` is ``"camera"``, the exposure a positive finite
    number of µs and the gain a finite linear factor >= 1. Returns them as floats.

    Raises
    ------
    ParameterError
        Another camera name, or a value out of range.
    """
    if camera != CAMERA:
        raise ParameterError(f"this source has one camera, {CAMERA!r}; got {camera!r}")
    for label, v in (("exposure_us", exposure_us), ("gain", gain)):
        if (
            isinstance(v, bool)
            or not isinstance(v, (int, float, np.integer, np.floating))
            or not math.isfinite(v)
            or v <= 0
        ):
            raise ParameterError(f"{label} must be a positive finite number, got {v!r}")
    if gain < 1.0:
        raise ParameterError(f"gain must be >= 1 (linear), got {gain}")
    return float(exposure_us), float(gain)


class CommandedCamera:
    """What a live camera source tells about its commands (mixed into the camera classes; their
    ``_commands`` is a :class:`CommandLog`)."""

    _commands: CommandLog

    def commands(self) -> list[CommandRecord]:
        """The last :data:`COMMAND_HISTORY` commands received (all of a short run), each with the start of the
        first exposure that used it (``commands_issued`` counts every command)."""
        return self._commands.records()

    @property
    def commands_issued(self) -> int:
        """Every exposure command received."""
        return self._commands.issued


def with_gain(frame: Frame, gain: float) -> Frame:
    """``frame`` with digital gain ``gain`` applied: ``clip(round(Z * gain), 0, 255)``, ``Frame.gain = gain``
    (a DAVIS has no analog gain; the camera sources apply the commanded gain this way)."""
    if gain == 1.0:
        return frame
    img = np.clip(np.rint(frame.image.astype(np.float32) * np.float32(gain)), 0, 255).astype(np.uint8)
    return Frame(img, frame.exposure_start_us, frame.exposure_end_us, gain, frame.sequence)


__all__ = ["COMMAND_HISTORY", "PENDING_COMMANDS", "CommandLog", "CommandedCamera", "check_command", "with_gain"]
