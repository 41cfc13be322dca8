#!/usr/bin/env python3
"""How much linear acceleration a low-pass cannot average out: BROAD's recordings against
the simulator's two translation models.

An attitude filter reads the vertical from the specific force low-passed over seconds
(the ESKF's earth-frame low-pass, VQF's): what survives the low-pass is the horizontal
linear acceleration at the lowest frequencies, and it tilts the estimate. This measures it.

- BROAD: for every trial of the shared subset, the horizontal linear acceleration in the
  earth frame, R_ref a - g e_up (the optical reference's attitude, the movement phase,
  reference gaps skipped); it also holds the reference's own attitude error times g and the
  accelerometer's bias, so it bounds the true linear acceleration from above.
- The simulator: ``handheld`` (imulink.sim.motion_with_rests, 1 m/s^2 per axis) and
  ``fast`` (imulink.sim.random_motion, 400 deg/s, 3 m/s^2) with each ``translation``:
  ``sustained`` (band-limited acceleration, flat down to 0 Hz) and ``bounded`` (the second
  derivative of a band-limited position), moving samples only.

Reported per row: the RMS of the horizontal linear acceleration (m/s^2), its RMS after a
first-order 3 s low-pass (the ESKF's default ``acc_lowpass``) and that share of the total,
and its RMS in frequency bands (Welch, 60 s segments).

A measurement, not a gate (exit 0; 2: usage error, BROAD data missing).

    .venv/bin/python tools/eval_translation.py --markdown
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import signal

from imulink import sim
from imulink.io.broad import BroadError, data_dir, load_broad
from imulink.sim import quat as Q

#: Frequency bands of the table, Hz.
BANDS = ((0.0, 0.05), (0.05, 0.15), (0.15, 0.5), (0.5, 1.5), (1.5, 5.0))
#: The low-pass of the table's third column, s.
LOWPASS_S = 3.0
GRAVITY = 9.80665
SIM_RATE_HZ = 100.0
SIM_DURATION_S = 300.0


def lowpass(x: np.ndarray, tau_s: float, dt: float) -> np.ndarray:
    """First-order low-pass along axis 0, started from the first value."""
    alpha = dt / (tau_s + dt)
    return signal.lfilter([alpha], [1.0, alpha - 1.0], x, axis=0, zi=(1.0 - alpha) * x[:1])[0]


def measure(horizontal: np.ndarray, dt: float) -> dict:
    """{"rms", "lowpassed", "bands": [rms per band]} of an (n,2) horizontal acceleration."""
    freq, psd = signal.welch(horizontal, fs=1.0 / dt, nperseg=min(len(horizontal), round(60.0 / dt)), axis=0)
    psd = psd.sum(axis=1)
    bands = []
    for lo, hi in BANDS:
        sel = (freq >= lo) & (freq < hi)
        bands.append(float(np.sqrt(np.trapezoid(psd[sel], freq[sel]))) if sel.sum() > 1 else float("nan"))
    smooth = lowpass(horizontal, LOWPASS_S, dt)
    return {"rms": float(np.sqrt(np.mean(np.sum(horizontal**2, axis=1)))),
            "lowpassed": float(np.sqrt(np.mean(np.sum(smooth**2, axis=1)))), "bands": bands}


def broad_rows(directory) -> list[tuple[str, dict]]:
    rows = []
    for path in sorted(directory.glob("*.mat")):
        trial = load_broad(path)
        known = ~np.isnan(trial.quat_ref).any(axis=1)
        quat = np.where(known[:, None], trial.quat_ref, np.array([1.0, 0.0, 0.0, 0.0]))
        linear = Q.rotate(quat, trial.acc) - np.array([0.0, 0.0, GRAVITY])
        keep = known & trial.movement.astype(bool)
        rows.append((f"BROAD {path.stem}", measure(linear[keep][:, :2], 1.0 / trial.rate_hz)))
    return rows


def sim_rows() -> list[tuple[str, dict]]:
    rows = []
    for translation in sim.TRANSLATIONS:
        cases = {
            "handheld": sim.motion_with_rests(SIM_DURATION_S, SIM_RATE_HZ, seed=0, accel_std=1.0,
                                              translation=translation),
            "fast": sim.random_motion(SIM_DURATION_S, SIM_RATE_HZ, seed=0, max_rate_dps=400.0, accel_std=3.0,
                                      translation=translation),
        }
        for name, traj in cases.items():
            moving = ~traj.rest
            rows.append((f"simulator {name}, {translation}", measure(traj.acc_lin[moving][:, :2], traj.dt)))
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default=None, help="directory with the BROAD .mat files (default: $IMULINK_BROAD_DIR, "
                                                "else shared/data/broad beside the repository)")
    p.add_argument("--markdown", action="store_true", help="print a markdown table")
    args = p.parse_args(argv)
    try:
        directory = Path(args.data) if args.data else data_dir()
        rows = broad_rows(directory)
    except (BroadError, OSError) as exc:
        print(f"eval_translation: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print(f"eval_translation: no BROAD .mat files in {directory}", file=sys.stderr)
        return 2
    rows += sim_rows()
    band_names = [f"{lo:g}-{hi:g} Hz" for lo, hi in BANDS]
    if args.markdown:
        print("| horizontal linear acceleration | RMS | after 3 s low-pass | share | " + " | ".join(band_names) + " |")
        print("|---" * (4 + len(BANDS)) + "|")
    for name, m in rows:
        share = m["lowpassed"] / m["rms"]
        bands = [f"{b:.3f}" for b in m["bands"]]
        if args.markdown:
            print(f"| {name} | {m['rms']:.3f} | {m['lowpassed']:.3f} | {share:.1%} | " + " | ".join(bands) + " |")
        else:
            print(f"{name:58s} rms {m['rms']:7.3f}  lowpassed {m['lowpassed']:6.3f} ({share:5.1%})  "
                  + "  ".join(f"{n} {b}" for n, b in zip(band_names, bands)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
