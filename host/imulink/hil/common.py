"""What every HIL job shares: its error, the settling time of accuracy statistics, the Q
formats of an ESTIMATE's fields, and the way a job over many recordings or boards runs in
worker processes and marks each one's row."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor, as_completed
from typing import Any

from imulink import core
from imulink.errors import ImulinkError

#: Seconds excluded from accuracy statistics (alignment and convergence).
SETTLE_S = 10.0
#: Q formats of the ESTIMATE fields that hold angles and rates.
ESTIMATE_FRAC_BITS = {"quat": core.QUAT_FRAC_BITS, "euler": core.EULER_FRAC_BITS, "gyro_bias": core.RATE_FRAC_BITS}


class HilError(ImulinkError):
    """A HIL job that cannot go on (a board that cannot be configured, a bad input)."""


def rows_in_order(pool: Executor, job: Callable[..., dict], items: Sequence,
                  progress: Callable[[int, dict], None] | None = None,
                  failed: Callable[[Any, BaseException], dict] | None = None, **options) -> list[dict]:
    """job(item, **options) for every item in `pool`'s workers; the rows in the order of
    `items`; `progress(done, row)` as each one finishes. A job that raises (its worker died)
    gets the row `failed(item, exception)`, or without `failed` the exception goes on. On
    leaving, also on Ctrl-C or an error, the pool is shut down and the items not yet begun
    are not run: only the workers' current ones finish (waiting for every queued one would
    take as long as the run)."""
    rows: list[dict | None] = [None] * len(items)
    try:
        futures = {pool.submit(job, item, **options): k for k, item in enumerate(items)}
        for done, future in enumerate(as_completed(futures), 1):
            k = futures[future]
            try:
                rows[k] = future.result()
            except Exception as exc:
                if failed is None:
                    raise
                rows[k] = failed(items[k], exc)
            if progress:
                progress(done, rows[k])  # type: ignore[arg-type]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return rows  # type: ignore[return-value]


def verdict_mark(row: dict) -> str:
    """A row's bit-exact column: ERROR (it could not be checked), yes or NO."""
    if row["error"] is not None:
        return "ERROR"
    return "yes" if row["passed"] else "NO"
