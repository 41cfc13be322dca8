"""Fixed-size numpy ring buffers for the live plots: appending is a copy into
preallocated memory (no Python lists grow at 1 kHz), and reading the newest rows is one
or two slices."""
from __future__ import annotations

import threading

import numpy as np


class RingBuffer:
    """The newest `capacity` rows of `width` float64 columns; thread-safe (the link's
    worker appends while the window's timer reads)."""

    def __init__(self, capacity: int, width: int):
        self._data = np.full((capacity, width), np.nan)
        self._capacity = capacity
        self._end = 0  # rows ever appended; the newest row is at (_end - 1) % capacity
        self._lock = threading.Lock()

    @property
    def capacity(self) -> int:
        return self._capacity

    def __len__(self) -> int:
        return min(self._end, self._capacity)

    @property
    def appended(self) -> int:
        """Rows appended since the buffer was made or cleared (those dropped included)."""
        return self._end

    def append(self, rows) -> None:
        """Append (N, width) rows (or one row); only the newest `capacity` are kept."""
        rows = np.asarray(rows, np.float64).reshape(-1, self._data.shape[1])
        with self._lock:
            n = len(rows)
            if n >= self._capacity:  # only the last `capacity` rows stay, the newest where the next append goes
                self._end += n
                self._data[:] = np.roll(rows[-self._capacity:], self._end % self._capacity, axis=0)
                return
            start = self._end % self._capacity
            first = min(n, self._capacity - start)
            self._data[start:start + first] = rows[:first]
            self._data[:n - first] = rows[first:]
            self._end += n

    def latest(self, count: int | None = None) -> np.ndarray:
        """A copy of the newest `count` rows (all kept rows by default), oldest first."""
        with self._lock:
            kept = min(self._end, self._capacity)
            count = kept if count is None else min(count, kept)
            stop = self._end % self._capacity
            if count <= stop:
                return self._data[stop - count:stop].copy()
            return np.concatenate((self._data[self._capacity - (count - stop):], self._data[:stop]))

    def since(self, column: int, low: float) -> np.ndarray:
        """A copy of the newest rows whose value in `column` (increasing, e.g. time) is at
        least `low`: a binary search over the kept rows, so only the rows returned are copied."""
        with self._lock:
            kept = min(self._end, self._capacity)
            first = self._end - kept  # logical index of the oldest kept row
            lo, hi = 0, kept
            while lo < hi:
                mid = (lo + hi) // 2
                if self._data[(first + mid) % self._capacity, column] < low:
                    lo = mid + 1
                else:
                    hi = mid
            count = kept - lo
        return self.latest(count)

    def clear(self) -> None:
        with self._lock:
            self._end = 0
