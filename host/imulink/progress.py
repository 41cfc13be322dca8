"""Progress bars for long jobs that move bytes (erase, write, verify).

:class:`Bars` is the `progress(phase, done, total)` callback the flashing code calls. On
a terminal it draws one bar per phase, rewritten in place; when stderr is not a terminal it
stays quiet and prints each phase's line once, when the phase ends.
"""
from __future__ import annotations

import sys
import time

_WIDTH = 30


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
