#!/usr/bin/env python3
"""Host throughput benchmark: samples per second of each filter through imulink.core.run.

Not a test (timings on shared machines are noisy): run it and read the table.
The input is a simulated random-motion run; the best of --repeat runs is kept.

    python tools/bench_core.py [--samples 1000000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import time

from imulink import core, sim


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=1_000_000, help="samples per run (default 1e6)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per filter and arithmetic; best kept (default 3)")
    parser.add_argument("--filters", default=",".join(core.FILTERS), help="comma-separated filter names")
    args = parser.parse_args()

    rate = 100.0
    data = sim.make_scenario("random", args.samples / rate, rate, seed=1)
    print(f"{'filter':<6} {'arith':<6} {'samples/s':>12}")
    for name in args.filters.split(","):
        for arithmetic in core.ARITHMETICS:
            best = float("inf")
            for _ in range(args.repeat):
                start = time.perf_counter()
                core.run_counts(name, data.gyr_counts, data.acc_counts, data.mag_counts, rate, arithmetic)
                best = min(best, time.perf_counter() - start)
            print(f"{name:<6} {arithmetic:<6} {len(data.t) / best:12.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
