"""Virtual time and the events peripherals schedule on it.

Time is an integer count of picoseconds since power-on (``Scheduler.now``): exact enough for
every clock of the chip (a 168 MHz cycle is 5 952 ps) and the same on every run, so a run
with the same inputs gives the same bytes. Peripherals schedule what happens later (a byte
leaves the USART, a timer overflows, an I2C byte ends) with :meth:`Scheduler.at`; the core's
run loop executes instructions up to the next event and then fires it.
"""
from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass, field

PS_PER_S = 1_000_000_000_000
PS_PER_US = 1_000_000


def ps(seconds: float) -> int:
    """Seconds as picoseconds (rounded)."""
    return int(round(seconds * PS_PER_S))


def period_ps(hz: float) -> int:
    """One period of a clock of `hz`, in picoseconds (rounded, at least 1)."""
    return max(1, int(round(PS_PER_S / hz)))


@dataclass(order=True)
class Event:
    time: int
    order: int
    action: Callable[[], None] = field(compare=False)
    cancelled: bool = field(default=False, compare=False)

    def cancel(self) -> None:
        self.cancelled = True


class Scheduler:
    """The virtual clock and a queue of events in time order (ties: the order they were set)."""

    def __init__(self) -> None:
        self.now = 0
        self._queue: list[Event] = []
        self._order = 0

    def at(self, time: int, action: Callable[[], None]) -> Event:
        """Run `action` at `time` (now if `time` has passed)."""
        self._order += 1
        event = Event(max(time, self.now), self._order, action)
        heapq.heappush(self._queue, event)
        return event

    def after(self, delay: int, action: Callable[[], None]) -> Event:
        return self.at(self.now + delay, action)

    def next_time(self) -> int | None:
        """When the next event is due, or None when nothing is scheduled."""
        while self._queue and self._queue[0].cancelled:
            heapq.heappop(self._queue)
        return self._queue[0].time if self._queue else None

    def advance(self, time: int) -> None:
        """Move the clock to `time` (never back), firing every event due by then in order."""
        while True:
            due = self.next_time()
            if due is None or due > time:
                break
            event = heapq.heappop(self._queue)
            self.now = max(self.now, event.time)
            event.action()
        self.now = max(self.now, time)
