"""Peak decimation for drawing: a curve of many thousand points on a plot a few hundred
pixels wide is drawn from the smallest and largest value in each pixel-sized bin, which
looks the same (every spike stays) and costs a fraction. Done in numpy, on a whole table
at once, before the data reach pyqtgraph, so that pyqtgraph's per-point work (bounds,
paths) runs on two points per bin instead of every sample."""
from __future__ import annotations

import numpy as np


def peaks(rows: np.ndarray, bins: int) -> np.ndarray:
    """`rows` (N, k; column 0 the time) reduced to two rows per run of consecutive rows,
    about `bins` runs: the minimum, then the maximum of every other column over the run
    (NaN ignored; a run of NaN stays NaN, a gap in the curve), both at the time of the
    run's first row. The newest rows that do not fill a run are kept as they are; at most
    2 * bins rows are returned unchanged."""
    n = len(rows)
    if n <= 2 * bins:
        return rows
    step = -(-n // bins)
    whole = n - n % step
    # each run's values of a column contiguous: numpy reduces along the last axis several
    # times faster than across a strided middle one
    runs = np.ascontiguousarray(rows[:whole].reshape(-1, step, rows.shape[1]).transpose(0, 2, 1))
    out = np.empty((2 * len(runs), rows.shape[1]))
    out[0::2], out[1::2] = np.fmin.reduce(runs, axis=2), np.fmax.reduce(runs, axis=2)
    out[0::2, 0] = out[1::2, 0] = runs[:, 0, 0]
    return np.concatenate([out, rows[whole:]])
