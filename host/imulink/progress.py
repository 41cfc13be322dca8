"""How long jobs show their progress.

- :data:`CountProgress`: a `progress(done, total)` callback (reading a long file).
- :data:`PhaseProgress`: a `progress(phase, done, total)` callback (flashing: erase, write,
  verify); :class:`Bars` is one: on a terminal it draws one bar per phase, rewritten in
  place; when stderr is not a terminal it prints each phase's line once, when it ends.
- :class:`StatusLine`: one status line that a job rewrites (recording, injecting, the demo).
"""
from __future__ import annotations

import sys
import time
from typing import Callable

_WIDTH = 30

CountProgress = Callable[[int, int], None]
PhaseProgress = Callable[[str, int, int], None]


class Bars:
    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self._phase: str | None = None
        self._started = 0.0
        self._last_draw = 0.0

    def __call__(self, phase: str, done: int, total: int) -> None:
        now = time.monotonic()
        if phase != self._phase:
            self._phase, self._started = phase, now
        finished = done >= total
        if self.tty and (finished or now - self._last_draw >= 0.1):
            self._last_draw = now
            self.stream.write("\r\x1b[K" + self._line(phase, done, total, now) + ("\n" if finished else ""))
            self.stream.flush()
        elif not self.tty and finished:
            self.stream.write(self._line(phase, done, total, now) + "\n")
            self.stream.flush()

    def _line(self, phase: str, done: int, total: int, now: float) -> str:
        fraction = done / total if total else 1.0
        filled = int(round(fraction * _WIDTH))
        elapsed = max(now - self._started, 1e-9)
        rate = done / elapsed / 1024
        return (f"{phase:<7} [{'#' * filled}{'.' * (_WIDTH - filled)}] {fraction * 100:5.1f}% "
                f"{done / 1024:7.1f} of {total / 1024:.1f} KiB, {rate:6.1f} KiB/s")


class StatusLine:
    """One status line on stderr: rewritten in place on a terminal, a plain line every
    `interval_s` seconds otherwise."""

    def __init__(self, stream=None, interval_s: float = 5.0):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.interval_s = 0.25 if self.tty else interval_s
        self._last = 0.0
        self._shown = False

    def due(self) -> bool:
        """Whether an update would be shown now (so the caller can skip building it)."""
        return time.monotonic() - self._last >= self.interval_s

    def update(self, text: str, force: bool = False) -> None:
        if not force and not self.due():
            return
        self._last = time.monotonic()
        if self.tty:
            self.stream.write("\r\x1b[K" + text)
            self._shown = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line of its own (a board LOG, a warning) that does not clobber the status line."""
        if self._shown:
            self.stream.write("\r\x1b[K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def done(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False
