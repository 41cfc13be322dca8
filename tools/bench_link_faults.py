#!/usr/bin/env python3
"""Recordings over lossy links with retransmission (RESEND): what reaches the file and what
`compare` verifies, for every filter, at 100 Hz and 1 kHz (issue 39).

Each case: an emulated board (the firmware as a native process, or the ARM image in QEMU
with `--target qemu`) streaming in real time behind the fault proxy, recorded with
`imulink.hil.record` (which asks for every lost frame again), then loaded and compared.
The faults are the proxy's (imulink.board.proxy.FaultConfig): bytes dropped or bits flipped
at 2e-4, 1e-3 and 1e-2 of the board's bytes, and stalls of 2 s (about one in 20 s). The nav filter runs the car
drive with its GNSS receiver and barometer; the others the `random` scenario.

Per case: samples the board sent that are missing from the recording, the estimates
received and the share of them verified bit for bit, the frames recovered, the filter
restarts (each a SAMPLE lost for good), and the bytes per second received: the link budget,
beside what 921 600 baud carries (92 160 bytes/s at 10 bits a byte). Worst seed of
`--seeds` (default 1) per case.

    .venv/bin/python tools/bench_link_faults.py                 # 60 s at 100 Hz, 10 s at 1 kHz
    .venv/bin/python tools/bench_link_faults.py --quick         # 10 s and 3 s: a smoke run
    .venv/bin/python tools/bench_link_faults.py --target qemu --filters eskf

Cases run in parallel (`--jobs`, default 3: the boards run in real time and mostly wait).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from imulink import hil
from imulink.board.emulator import NAV_SCENARIO, EmulatedBoard
from imulink.board.proxy import FaultConfig
from imulink.errors import ImulinkError
from imulink.io.recording import load_recording

BAUD_921600_BYTES_S = 92160
FAULTS = {
    "clean": {},
    "drop 2e-4": {"drop_byte": 2e-4},
    "drop 1e-3": {"drop_byte": 1e-3},
    "flip 2e-4": {"flip_bit": 2e-4},
    "flip 1e-3": {"flip_bit": 1e-3},
    "drop 1e-2": {"drop_byte": 1e-2},
    "stall 2 s": {"stall_s": 2.0},  # about one stall in 20 s (STALLS_EVERY_S), whatever the frame rate
}
#: The stall case: the link holds everything for 2 s about once in this many seconds.
STALLS_EVERY_S = 20.0
#: Frames per sample, roughly (SAMPLE, ESTIMATE, NAV_STATE, BARO, STATUS), to turn that into a
#: probability per frame.
FRAMES_PER_SAMPLE = 3.0


def run_case(target: str, filter_name: str, rate_hz: float, duration_s: float, fault: str, seed: int) -> dict:
    """One case's row; a recording that failed is a row with its error."""
    try:
        return _measure(target, filter_name, rate_hz, duration_s, fault, seed)
    except ImulinkError as exc:
        return {"target": target, "filter": filter_name, "rate_hz": rate_hz, "duration_s": duration_s, "fault": fault,
                "seed": seed, "error": str(exc)}


def _measure(target: str, filter_name: str, rate_hz: float, duration_s: float, fault: str, seed: int) -> dict:
    scenario = NAV_SCENARIO if filter_name == "nav" else "random"
    stall = 1.0 / (rate_hz * FRAMES_PER_SAMPLE * STALLS_EVERY_S) if "stall_s" in FAULTS[fault] else 0.0
    faults = FaultConfig(seed=seed, stall=stall, **FAULTS[fault])
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "run.imulog"
        with EmulatedBoard(target, duration_s=duration_s + 30.0, rate_hz=rate_hz, filter_name=filter_name,
                           scenario=scenario, realtime=True, faults=faults, seed=seed) as board:
            result = hil.record(board.address, path, duration_s=duration_s)
            injector = board.proxy.faults if board.proxy is not None else None  # None on a clean link
            stalls = injector.counts["stalls"] if injector is not None else 0
        recording = load_recording(path)
        comparison = hil.compare(recording, min_verified=0.0)
    samples = recording.samples
    sent = int(samples.index.max()) + 1 if len(samples) and recording.segments == 1 else len(samples)
    received = len(recording.estimates)
    return {"target": target, "filter": filter_name, "rate_hz": rate_hz, "duration_s": duration_s, "fault": fault,
            "seed": seed, "samples": len(samples), "samples_missing": sent - len(samples) if recording.segments == 1
            else None, "segments": recording.segments, "restarts": result.filter_restarts,
            "estimates": received, "verified": comparison.verified_count,
            "verified_share": comparison.verified_count / received if received else 0.0,
            "different": comparison.verified_count - comparison.identical_count, "recovered": dict(recording.recovered),
            "lost_for_good": result.recovery.get("gone", 0) + result.recovery.get("unanswered", 0),
            # the link budget: bytes received per second of samples (the recording's own pace)
            "bytes_per_s": result.counters["bytes"] * rate_hz / max(1, len(samples)), "stalls": stalls}


def _worst(rows: list[dict]) -> dict:
    failed = [r for r in rows if "error" in r]
    return failed[0] if failed else min(rows, key=lambda r: (r["verified_share"], -(r["samples_missing"] or 0)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--target", choices=("native", "qemu"), default="native")
    parser.add_argument("--filters", default="eecf,kf1d,eskf,nav")
    parser.add_argument("--faults", default=",".join(FAULTS), help=f"comma-separated, of: {', '.join(FAULTS)}")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="10 s at 100 Hz and 3 s at 1 kHz")
    parser.add_argument("--rates", default="100,1000")
    parser.add_argument("--jobs", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    durations = {100.0: 10.0 if args.quick else 60.0, 1000.0: 3.0 if args.quick else 10.0}
    cases = [(args.target, f, float(rate), durations.get(float(rate), 10.0), fault, seed)
             for rate in args.rates.split(",") for f in args.filters.split(",") for fault in args.faults.split(",")
             for seed in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(run_case, *zip(*cases)))
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print("| target | filter | rate | fault | samples missing | estimates verified | recovered frames "
          "| restarts | stalls | bytes/s | of 921600 baud |")
    print("|---|---|---:|---|---:|---:|---|---:|---:|---:|---:|")
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["target"], row["filter"], row["rate_hz"], row["fault"]), []).append(row)
    for (target, filter_name, rate, fault), group in groups.items():
        r = _worst(group)
        if "error" in r:
            print(f"| {target} | {filter_name} | {rate:g} Hz | {fault} | FAILED (seed {r['seed']}): {r['error']} |")
            continue
        recovered = ", ".join(f"{n} {k}" for k, n in sorted(r["recovered"].items())) or "0"
        missing = "?" if r["samples_missing"] is None else str(r["samples_missing"])
        print(f"| {target} | {filter_name} | {rate:g} Hz | {fault} | {missing} | {r['verified']} of {r['estimates']} "
              f"({100 * r['verified_share']:.2f} %) | {recovered} | {r['restarts']} | {r['stalls']} "
              f"| {r['bytes_per_s']:,.0f} "
              f"| {100 * r['bytes_per_s'] / BAUD_921600_BYTES_S:.0f} % |")
    different = [r for r in rows if r.get("different")]
    for r in different:
        print(f"DIFFERENT: {r['filter']} {r['rate_hz']:g} Hz {r['fault']} seed {r['seed']}: "
              f"{r['different']} estimates differ from the host build")
    return 1 if different or any("error" in r for r in rows) else 0  # a low share is reported in the table


if __name__ == "__main__":
    sys.exit(main())
