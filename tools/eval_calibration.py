#!/usr/bin/env python3
"""What a magnetometer calibration is worth, on the simulator.

A simulated GY-86 whose magnetometer has hard iron (12, -7, 20) uT and a symmetric soft
iron (scales 0.92-1.10, cross terms up to 0.05) is turned at random for --turn seconds
(the calibration recording, written as a replay CSV); `imulink calibrate mag` computes
the calibration from it as a user would. Then another run of the same board ("rests"
scenario, --duration s, another seed) goes through a filter in the fixed-point build
without and with that calibration, and the attitude errors after 10 s are printed, with
the field-norm spread of the calibration recording before and after; and, for comparison,
with the exact inverse of the distortion. The filter runs with its default settings.

    .venv/bin/python tools/eval_calibration.py [--filter eskf] [--seed 1]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from imulink import cli, core, sim
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.core import calibration as calfmt
from imulink.io import calibration_file
from imulink.sim.sensors import AccModel, MagModel, SensorSuite

HARD_IRON_UT = (12.0, -7.0, 20.0)
SOFT_IRON = np.array([[1.10, 0.05, -0.03], [0.05, 0.92, 0.04], [-0.03, 0.04, 1.02]])
RATE_HZ = 100.0
SETTLE_S = 10.0


def suite() -> SensorSuite:
    default = SensorSuite.default()
    return SensorSuite(default.gyro, AccModel(), MagModel(hard_iron=HARD_IRON_UT, soft_iron=SOFT_IRON))


def write_csv(path: Path, result) -> None:
    columns = ["time_s"] + [f"{s}_{a}_{u}" for s, u in (("gyr", "rad_s"), ("acc", "m_s2"), ("mag", "uT"))
                            for a in "xyz"]
    np.savetxt(path, np.column_stack([result.t, result.gyr, result.acc, result.mag]), delimiter=",",
               header=",".join(columns), comments="", fmt="%.9g")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--filter", default="eskf", choices=list(core.FILTERS), help="filter (default: eskf)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the evaluation run (default: 1)")
    parser.add_argument("--turn", type=float, default=120.0, help="seconds of the calibration recording (default: 120)")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds of the evaluation run (default: 300)")
    args = parser.parse_args()

    turned = sim.simulate(sim.random_motion(args.turn, RATE_HZ, seed=args.seed + 1000), suite(), seed=args.seed + 1000)
    with tempfile.TemporaryDirectory() as tmp:
        recording, output = Path(tmp) / "turned.csv", Path(tmp) / "calibration.json"
        write_csv(recording, turned)
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(io.StringIO()):
            status = cli.main(["calibrate", "mag", str(recording), "-o", str(output), "--json"])
        if status != 0:
            return status
        report = json.loads(printed.getvalue())["report"]
        board = calibration_file.load(output)

    # the exact inverse of the distortion, for comparison: what a perfect calibration gives
    truth = calfmt.Calibration(board.profile, {"mag": calfmt.SensorCalibration(
        "mag", np.asarray(HARD_IRON_UT) / board.profile.mag_scale, np.linalg.inv(SOFT_IRON))})
    run = sim.simulate(sim.motion_with_rests(args.duration, RATE_HZ, seed=args.seed), suite(), seed=args.seed)
    settle = int(SETTLE_S * RATE_HZ)
    print(f"calibration recording: {args.turn:g} s turned at random; field norm spread (std) "
          f"{report['norm_spread_before_uT']:.3f} uT before, {report['norm_spread_after_uT']:.3f} uT after; "
          f"coverage {report['coverage']['covered']} of {report['coverage']['of']}; hard iron found "
          f"[{', '.join(f'{v:.2f}' for v in report['hard_iron_uT'])}] uT")
    print(f"{args.filter} (fixed point) on {args.duration:g} s of motion with rests, seed {args.seed}, RMS after "
          f"{SETTLE_S:g} s, deg:")
    print(f"{'':<20} {'total':>8} {'heading':>8} {'incl.':>8}")
    for label, cal in (("no calibration", None), ("mag calibration", board), ("the true correction", truth)):
        result = core.run(args.filter, run.gyr, run.acc, run.mag, RATE_HZ, "fixed", None, run.profile, cal)
        err = rmse(attitude_errors(result.quat[settle:], run.quat_true[settle:]))
        print(f"{label:<20} {err['total']:8.3f} {err['heading']:8.3f} {err['inclination']:8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
