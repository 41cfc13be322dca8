#!/usr/bin/env python3
"""Host throughput benchmark of the C core through imulink.core.run_counts.

Not a test (timings on shared machines are noisy): run it and read the table.

- samples/s: a simulated random-motion run, best of --repeat runs, per filter and
  arithmetic (fixed build and float twin);
- --instructions: x86-64 instructions per sample counted by valgrind's callgrind
  (repeatable whatever the machine's load): the difference between runs of 2N and N
  samples, divided by N, so the Python call overhead cancels.

    python tools/bench_core.py [--samples 1000000] [--repeat 3] [--instructions]
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

from imulink import core, sim

RATE_HZ = 100.0


def throughput(name: str, arithmetic: str, data, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        core.run_counts(name, data.gyr_counts, data.acc_counts, data.mag_counts, RATE_HZ, arithmetic)
        best = min(best, time.perf_counter() - start)
    return len(data.t) / best


_CHILD = """
import sys
from imulink import core, sim
name, arithmetic, n, total = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
data = sim.make_scenario("random", total / 100.0, 100.0, seed=1)  # the same data for both runs
core.run_counts(name, data.gyr_counts[:n], data.acc_counts[:n], data.mag_counts[:n], 100.0, arithmetic)
"""


def instructions(name: str, arithmetic: str, n: int) -> float:
    """Instructions per sample from two callgrind runs (n and 2n samples)."""
    counts = []
    with tempfile.TemporaryDirectory() as tmp:
        for samples in (n, 2 * n):
            out = os.path.join(tmp, f"cg.{samples}")
            proc = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}",
                                   sys.executable, "-c", _CHILD, name, arithmetic, str(samples), str(2 * n)],
                                  capture_output=True, text=True, check=True)
            match = re.search(r"Collected\s*:\s*(\d+)", proc.stderr) or re.search(r"refs:\s*([\d,]+)", proc.stderr)
            counts.append(int(match.group(1).replace(",", "")))
    return (counts[1] - counts[0]) / n


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=1_000_000, help="samples per run (default 1e6)")
    parser.add_argument("--repeat", type=int, default=3, help="runs per filter and arithmetic; best kept (default 3)")
    parser.add_argument("--filters", default=",".join(core.FILTERS), help="comma-separated filter names")
    parser.add_argument("--instructions", action="store_true",
                        help="also count instructions per sample with valgrind (slow: about a minute per filter)")
    args = parser.parse_args()
    if args.instructions and shutil.which("valgrind") is None:
        parser.error("--instructions needs valgrind (apt-get install valgrind)")

    data = sim.make_scenario("random", args.samples / RATE_HZ, RATE_HZ, seed=1)
    print(f"{'filter':<6} {'arith':<6} {'samples/s':>12}" + (f" {'instr/sample':>13}" if args.instructions else ""))
    for name in args.filters.split(","):
        for arithmetic in core.ARITHMETICS:
            line = f"{name:<6} {arithmetic:<6} {throughput(name, arithmetic, data, args.repeat):12.0f}"
            if args.instructions:
                line += f" {instructions(name, arithmetic, 20000):13.0f}"
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
