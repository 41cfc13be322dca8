#!/usr/bin/env python3
"""Speed of the virtual reference board (imulink.board.stm32f407): the reference image streaming
SAMPLE + ESTIMATE at 100 Hz with its barometer and a u-blox receiver (NAV-PVT at 10 Hz once the
driver has configured it), in virtual time on one core, no host process in the loop.

Prints, per filter: virtual seconds, wall seconds, the ratio (above 1: faster than real time),
the bytes the board sent, and the frames by kind. docs/performance.md has the table.

    .venv/bin/python tools/bench_virtual_board.py [--seconds 20] [--filters eskf,nav]
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "host"))

from imulink import core, protocol, sim  # noqa: E402
from imulink.board import stm32f407  # noqa: E402
from imulink.board.emulator import baro_conversions, gnss_messages, reference_flash  # noqa: E402
from imulink.sim import navigation  # noqa: E402

ELF = ROOT / "firmware" / "build" / "stm32f407" / "imulink-stm32f407-gy86.elf"


def run(filter_name: str, seconds: float) -> dict:
    rate = 100.0
    traj = navigation.car_drive(seconds + 2.0, rate, seed=0)
    simulated = sim.simulate(traj, navigation.datasheet_sensors(rate), seed=0)
    fixes = navigation.gnss_fixes(traj, navigation.GnssModel(), seed=0)
    baro = navigation.baro_samples(traj, seed=0)
    n = len(simulated.gyr_counts)
    feed = stm32f407.Feed(rate, simulated.gyr_counts, simulated.acc_counts, simulated.mag_counts,
                          baro=baro_conversions(n, rate, baro), gnss=gnss_messages(fixes, rate, n))
    flash, elf = reference_flash(ELF)
    board = stm32f407.ReferenceBoard(flash, elf=elf, feed=feed)
    board.run_for(0.5)
    board.put(protocol.encode_command(0, "SELECT_FILTER", 1, filter_id=core.BOARD_FILTERS[filter_name][0]))
    board.put(protocol.encode_command(1, "START_STREAM", 2))
    board.run_for(0.1)
    decoder = protocol.FrameDecoder()
    decoder.feed(board.take())
    started = time.perf_counter()
    board.run_for(seconds)
    wall = time.perf_counter() - started
    data = board.take()
    kinds = Counter(m.name for m in decoder.feed(data) if isinstance(m, protocol.Message))
    return dict(filter=filter_name, virtual_s=seconds, wall_s=wall, ratio=seconds / wall, bytes=len(data),
                frames=dict(kinds), problems=board.soc.problems)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="virtual seconds of streaming (default 20)")
    parser.add_argument("--filters", default="eskf,nav", help="filters to run, comma-separated (default eskf,nav)")
    args = parser.parse_args()
    print(f"{'filter':8} {'virtual s':>9} {'wall s':>7} {'ratio':>6} {'kB/s':>6}  frames")
    for name in args.filters.split(","):
        r = run(name, args.seconds)
        frames = ", ".join(f"{k} {v}" for k, v in sorted(r["frames"].items()))
        print(f"{name:8} {r['virtual_s']:9.1f} {r['wall_s']:7.2f} {r['ratio']:6.2f} "
              f"{r['bytes'] / r['virtual_s'] / 1000:6.1f}  {frames}")
        for problem in r["problems"]:
            print(f"  problem: {problem}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
