#!/usr/bin/env python3
"""Time and memory of the Allan analysis (imulink.analysis.allan.analyse) on a long static record.

Not a test (timings on shared machines are noisy): run it and read the numbers. The
input is white noise on three gyroscope axes (no accelerometer: the same work again),
by default an hour at 1 kHz, 3.6 million samples an axis; --hours 5.6 makes 2e7.

- seconds: wall time of the analysis alone (the curves of three axes and their terms),
  best of --repeat runs;
- peak memory: the most the analysis allocated on top of its input (tracemalloc, which
  numpy reports its arrays to), and the process's peak resident size (getrusage), which
  includes the input itself (8 bytes a value) and the interpreter.

    python tools/bench_allan.py [--hours 1] [--rate 1000] [--repeat 2]
"""
from __future__ import annotations

import argparse
import resource
import sys
import time
import tracemalloc

import numpy as np

from imulink.analysis import allan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0, help="length of the record (default: 1)")
    parser.add_argument("--rate", type=float, default=1000.0, help="sample rate in Hz (default: 1000)")
    parser.add_argument("--repeat", type=int, default=2, help="runs; the best is reported (default: 2)")
    args = parser.parse_args(argv)

    n = int(args.hours * 3600 * args.rate)
    gyr = np.random.default_rng(1).standard_normal((n, 3)) * 1e-3 * np.sqrt(args.rate)  # 1e-3 rad/sqrt(s)
    record = allan.StaticRecord("white noise", args.rate, gyr, None)
    best = float("inf")
    for _ in range(args.repeat):
        tracemalloc.start()
        start = time.perf_counter()
        result = allan.analyse(record)
        best = min(best, time.perf_counter() - start)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB
    arw = result.sensors["gyro"].terms["arw"]
    print(f"{n} samples x 3 axes ({args.hours:g} h at {args.rate:g} Hz, {n * 3 * 8 / 2**20:.0f} MiB of input): "
          f"{best:.2f} s (best of {args.repeat}), {len(result.sensors['gyro'].curve.tau_s)} averaging times")
    print(f"peak memory: {peak / 2**20:.0f} MiB allocated by the analysis, {rss / 2**20:.0f} MiB resident in all")
    print("angle random walk (truth 1e-3 rad/sqrt(s)): " + ", ".join(f"{t.value:.5g} +- {t.uncertainty:.2g}"
                                                                     for t in arw))
    return 0


if __name__ == "__main__":
    sys.exit(main())
