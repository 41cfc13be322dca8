#!/usr/bin/env python3
"""`imulink compare` over many recordings: worker processes against the serial loop.

Records one run of the native emulated board with `imulink demo` (ESKF, a simulated
minute at 100 Hz by default), copies it `--files` times into a temporary directory, and
compares the directory twice in one run: with one process (the serial loop) and with
`--jobs` workers (default one per core). Prints both wall times, their ratio, whether the
two runs gave the same rows (they must: exit status 1 if not), and a worker's peak
resident memory after a tenth of the files and after all of them.

    .venv/bin/python tools/bench_compare.py [--files 200] [--jobs N] [--duration 60]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from imulink.hil import batch


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--files", type=int, default=200, help="recordings compared (default 200)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="workers (default: one per core)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of the recorded run (default 60)")
    args = parser.parse_args()
    if args.files < 1 or args.jobs < 1 or args.duration <= 0:
        parser.error("--files, --jobs and --duration must be positive")

    with tempfile.TemporaryDirectory(prefix="bench_compare_") as tmp:
        one = Path(tmp) / "demo.imulog"
        subprocess.run([sys.executable, "-m", "imulink.cli", "demo", "--duration", str(args.duration),
                        "--output", str(one)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        runs = Path(tmp) / "runs"
        runs.mkdir()
        for k in range(args.files):
            shutil.copyfile(one, runs / f"run{k:04d}.imulog")
        paths = batch.expand([str(runs)])
        print(f"{len(paths)} copies of a {args.duration:g} s recording ({one.stat().st_size / 1e6:.2f} MB each)")

        timings = {}
        results = {}
        for label, jobs in (("serial", 1), ("parallel", args.jobs)):
            start = time.perf_counter()
            results[label] = batch.compare_many(paths, jobs=jobs)
            timings[label] = time.perf_counter() - start
            print(f"{label:8s} ({jobs} process{'es' if jobs > 1 else ''}): {timings[label]:6.1f} s, "
                  f"{sum(r['passed'] for r in results[label])} of {len(paths)} bit-exact", flush=True)
        same = results["serial"] == results["parallel"]
        print(f"ratio serial / parallel: {timings['serial'] / timings['parallel']:.2f} with {args.jobs} workers; "
              f"same verdicts: {'yes' if same else 'NO'}")
        # A worker's peak memory after a tenth of the files and after all of them (one worker, so
        # that it sees every file): it must not grow with the number of files.
        with ProcessPoolExecutor(max_workers=1) as pool:
            peaks = list(pool.map(_compare_and_peak, paths))
        tenth = max(1, len(paths) // 10)
        print(f"a worker's peak resident memory: {max(peaks[:tenth]):.0f} MB after {tenth} files, "
              f"{max(peaks):.0f} MB after {len(paths)}")
    return 0 if same else 1


def _compare_and_peak(path) -> float:
    """Compare one recording in this worker; its peak resident memory so far, MB (Linux: kB)."""
    batch.compare_one(path)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


if __name__ == "__main__":
    sys.exit(main())
