#!/usr/bin/env python3
"""Regenerate the Allan-deviation figures of docs/calibration.md and print their terms.

- docs/allan_sim_gy86.png: a static run of the emulated GY-86 board (the firmware as a
  native process, its sensors fed by the simulator: [seed 000]'s gyroscopes, 0.02 m/s^2
  per sample on the accelerometer), recorded as `imulink record` records a board and
  analysed as `imulink allan` analyses the recording; the table compares each term
  with the simulator's setting.
- docs/allan_broad_rest.png: the longest rest of a BROAD trial (skipped, with a line
  saying so, when the data is not beside the repository).

The tables are printed as Markdown, to paste into docs/calibration.md.

    .venv/bin/python tools/allan_plots.py [--hours 2] [--rate 100] [--trial NAME] [--broad DIR]
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from imulink import hil
from imulink.analysis import allan, plotting
from imulink.board.emulator import EmulatedBoard
from imulink.io.broad import data_dir as broad_data_dir
from imulink.sim import AccModel, GyroModel

REPO_ROOT = Path(__file__).resolve().parent.parent
DOCS = REPO_ROOT / "docs"
BROAD = broad_data_dir()
DEG = 180.0 / math.pi


def _term(t: allan.NoiseTerm, scale: float) -> str:
    if t.value is None:
        return "not identified"
    return f"{t.value * scale:.4g} ± {t.uncertainty * scale:.2g}"


def table(result: allan.AllanResult, truth: dict | None = None) -> str:
    """Markdown: one row per term and axis, in data-sheet units, with the truth if given."""
    units = {("gyro", "arw"): ("deg/√h", DEG * 60.0), ("gyro", "bias_instability"): ("deg/h", DEG * 3600.0),
             ("gyro", "rrw"): ("deg/h/√h", DEG * 3600.0 * 60.0), ("acc", "vrw"): ("m/s²/√Hz", 1.0),
             ("acc", "bias_instability"): ("m/s²", 1.0), ("acc", "rrw"): ("m/s²/√s", 1.0)}
    head = "| term | unit | x | y | z |" + (" simulated (x, y, z) |" if truth else "")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for sensor, analysis in result.sensors.items():
        for name, terms in analysis.terms.items():
            unit, scale = units[sensor, name]
            row = f"| {sensor} {allan.TERM_NAMES[name]} | {unit} | " + " | ".join(_term(t, scale) for t in terms) + " |"
            if truth:
                values = truth.get((sensor, name))
                row += (" " + ", ".join(f"{v * scale:.4g}" for v in values) if values is not None else " -") + " |"
            lines.append(row)
    return "\n".join(lines)


def simulated(hours: float, rate_hz: float) -> None:
    print(f"emulated GY-86 board, static, {hours:g} h at {rate_hz:g} Hz: recording ...", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "still.imulog"
        with EmulatedBoard(front="tcp", scenario="static", duration_s=hours * 3600.0, rate_hz=rate_hz,
                           filter_name="kf1d") as board:
            hil.record(board.address, path)
        record = allan.load_static(path)
    record.description = f"emulated GY-86 board, static (simulated seed 000 gyros), {hours:g} h"
    result = allan.analyse(record)
    allan.plot(result, DOCS / "allan_sim_gy86.png")
    gyro, acc = GyroModel.seed000(), AccModel()
    truth = {("gyro", "arw"): gyro.arw, ("gyro", "rrw"): gyro.rrw,
             ("acc", "vrw"): np.broadcast_to(acc.noise_std / math.sqrt(rate_hz), 3)}
    print(f"### {result.description} ({result.samples} samples at {result.rate_hz:g} Hz)\n")
    print(table(result, truth))
    print("\nseed 000 Table 1 bias stability: " + ", ".join(f"{v * DEG * 3600:.4g}" for v in gyro.bias_instability)
          + " deg/h; Gauss-Markov correlation time " + f"{gyro.bias_instability_tau_s:g} s\n")
    derived = allan.derive_settings(allan.to_json(result), "eskf")
    print("ESKF settings that follow (`--settings eskf`):\n\n```\n"
          + "\n".join(f"{name}={value:.6g}" for name, value in derived.values.items()) + "\n```\n")


def broad(directory: Path, trial: str) -> None:
    path = directory / f"{trial}.mat"
    if not path.is_file():
        print(f"BROAD trial {path} not found: docs/allan_broad_rest.png not regenerated", file=sys.stderr)
        return
    result = allan.analyse(allan.load_static(path))
    allan.plot(result, DOCS / "allan_broad_rest.png")
    print(f"### {result.description} ({result.samples} samples at {result.rate_hz:.6g} Hz)\n")
    print(table(result) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=2.0, help="length of the simulated run (default: 2)")
    parser.add_argument("--rate", type=float, default=100.0, help="its sample rate, Hz (default: 100)")
    parser.add_argument("--trial", default="02_undisturbed_slow_rotation_B", help="the BROAD trial")
    parser.add_argument("--broad", type=Path, default=BROAD,
                        help="the BROAD directory (default: $IMULINK_BROAD_DIR, else shared/data/broad beside the "
                             "repository)")
    args = parser.parse_args(argv)
    plotting.check_plotting()
    simulated(args.hours, args.rate)
    broad(args.broad, args.trial)
    return 0


if __name__ == "__main__":
    sys.exit(main())
