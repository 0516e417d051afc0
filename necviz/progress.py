"""A live progress line for long work: rewritten in place on a terminal, a line now and then otherwise.

On a terminal the line is redrawn (``\\r``) every ``interval_s``; when the output is a file or a
pipe (a log, CI) a complete line is written every ``log_interval_s`` instead, so logs stay readable.
"""

from __future__ import annotations

import io
import sys
import time


class _Silent(io.TextIOBase):
    """Where ``out=None`` sends text: nowhere (``print(file=None)`` would go to the terminal)."""

    def write(self, text: str) -> int:
        return len(text)


def output(out):
    """The stream a command writes to: ``...`` (the default) is standard output, ``None`` silence."""
    if out is ...:
        return sys.stdout
    return _Silent() if out is None else out


class LiveLine:
    def __init__(self, out, interval_s: float = 0.5, log_interval_s: float = 10.0):
        self.out = None if isinstance(out, _Silent) else out
        self.tty = bool(out is not None and hasattr(out, "isatty") and out.isatty())
        self.interval = interval_s if self.tty else log_interval_s
        self._next = time.perf_counter() + (0 if self.tty else self.interval)
        self._width = 0

    def show(self, text: str, force: bool = False) -> None:
        """Show ``text`` if it is time (or ``force``)."""
        if self.out is None:
            return
        now = time.perf_counter()
        if not force and now < self._next:
            return
        self._next = now + self.interval
        if self.tty:
            pad = max(0, self._width - len(text))
            print("\r" + text + " " * pad, end="", file=self.out, flush=True)
            self._width = len(text)
        else:
            print(text, file=self.out, flush=True)

    def clear(self) -> None:
        """Remove the in-place line (terminal only)."""
        if self.tty and self._width:
            print("\r" + " " * self._width + "\r", end="", file=self.out, flush=True)
            self._width = 0

    def done(self, text: str) -> None:
        """The final state, as a complete line."""
        if self.out is None:
            return
        if self.tty:
            self.show(text, force=True)
            print(file=self.out, flush=True)
            self._width = 0
        else:
            print(text, file=self.out, flush=True)


def plural(n: int, word: str, words: str | None = None) -> str:
    """``1 failure``, ``2 failures``, ``1,234 events`` (``words``: an irregular plural)."""
    return f"{n:,} {word if n == 1 else (words or word + 's')}"
