#!/usr/bin/env python3
"""Cortex-M4 cost and accuracy of the navigation's strapdown propagation (issue 16).

Builds the fixed-point core for the Cortex-M4 as tools/bench_arm.py does (same flags,
same harness ELF), then runs imu_nav_propagate in the unicorn emulator over the
simulator's car drive (`imulink.sim.navigation.car_drive`, seed 0, 100 Hz) with ideal
sensors: the gyroscope's exact rates and the specific force's mean over each sample
interval (no noise, no quantisation), so what remains is the propagation's own error.
After every sample the position, velocity and quaternion are read back and compared
with the x86 fixed build (tests/c/nav_driver.c, compiled with gcc): the benchmark fails
at the first difference. Reported:

- instructions per IMU step (imu_nav_propagate), mean and max, and the deepest stack;
- sizeof(imu_nav_t) on the target;
- the fixed build's horizontal and vertical position error and velocity error against
  the truth over the run.

    .venv/bin/python tools/bench_nav.py [--seconds 60] [--json]

The GNSS, barometer and rest updates of the filter are not written yet: this measures
the part every IMU sample runs.
"""
from __future__ import annotations

import argparse
import json
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT / "host"))

import bench_arm  # noqa: E402
from imulink.sim import navigation as nv  # noqa: E402
from imulink.sim.sensors import _interval_mean_in_body  # noqa: E402

DRIVER = ROOT / "tests" / "c" / "nav_driver.c"
RATE_HZ = 100.0


def to_q(x: float, q: int) -> int:
    """llround(x 2^q), as the driver converts (halves away from zero)."""
    v = abs(x) * 2.0**q
    n = int(np.floor(v + 0.5))
    return -n if x < 0 else n


def ideal_run(seconds: float):
    traj = nv.car_drive(seconds, RATE_HZ, seed=0)
    f_earth = traj.acc_lin.copy()
    f_earth[:, 2] += traj.gravity
    acc = _interval_mean_in_body(traj.quat, traj.gyr, traj.dt, f_earth)
    return traj, traj.gyr[1:], acc[1:]


def host_fixed(directory: Path, traj, gyr, acc) -> np.ndarray:
    """The x86 fixed build's state after each sample, as integers (mm, Q20, Q30)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise bench_arm.BenchError("gcc (the host compiler) is missing")
    exe = directory / "nav_fixed"
    bench_arm._run([gcc, "-std=c99", "-O2", "-DIMU_FIXED", f"-I{bench_arm.CORE_DIR}", "-o", str(exe), str(DRIVER),
                    str(bench_arm.CORE_DIR / "imu_nav.c"), str(bench_arm.CORE_DIR / "imu_math.c"), "-lm"],
                   "compiling the x86 navigation driver")
    o = traj.origin
    head = [RATE_HZ, o.lat_deg, o.lon_deg, o.height_m, *traj.quat[0], *traj.vel_enu[0]]
    lines = [" ".join(repr(float(x)) for x in head)]
    lines += [" ".join(repr(float(x)) for x in (*g, *a)) for g, a in zip(gyr, acc)]
    out = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True, text=True)
    if out.returncode != 0:
        raise bench_arm.BenchError(f"the x86 navigation driver failed ({out.returncode}): {out.stderr.strip()}")
    rows = np.array([r.split() for r in out.stdout.strip().split("\n")[1:-1]], dtype=float)
    scale = np.r_[[1000.0] * 3, [2.0**20] * 3, [2.0**30] * 4]
    return np.rint(rows * scale).astype(np.int64)


def run(seconds: float, build_dir: Path, progress=lambda _m: None) -> dict:
    start = time.perf_counter()
    build = bench_arm.build_arm(build_dir)
    bench_arm.check_no_float(build)
    traj, gyr, acc = ideal_run(seconds)
    host = host_fixed(build_dir, traj, gyr, acc)
    progress(f"built {build.elf}; host fixed build run on {len(gyr)} samples")
    emu = bench_arm.Emulator(build)
    o = traj.origin
    emu.write("bench_nav_origin", struct.pack("<3i", to_q(np.deg2rad(o.lat_deg), 29),
                                              to_q(np.deg2rad(o.lon_deg), 29), to_q(o.height_m * 1000.0, 0)))
    emu.write("bench_nav_quat", struct.pack("<4i", *(to_q(float(v), 30) for v in traj.quat[0])))
    emu.write("bench_nav_vel", struct.pack("<3i", *(to_q(float(v), 20) for v in traj.vel_enu[0])))
    status = emu.call("bench_nav_start", to_q(RATE_HZ, 16)).value
    if status != 0:
        raise bench_arm.BenchError(f"bench_nav_start returned {status}")
    nav, g_addr, a_addr = emu.address("bench_nav"), emu.address("bench_nav_gyr"), emu.address("bench_nav_acc")
    counts = np.zeros(len(gyr), np.int64)
    stack = 0
    got = np.zeros((len(gyr), 10), np.int64)
    for i, (g, a) in enumerate(zip(gyr, acc)):
        emu.write(g_addr, struct.pack("<3i", *(to_q(float(v), 24) for v in g)))
        emu.write(a_addr, struct.pack("<3i", *(to_q(float(v), 16) for v in a)))
        r = emu.call("imu_nav_propagate", nav, g_addr, a_addr)
        counts[i], stack = r.instructions, max(stack, r.stack)
        emu.call("bench_nav_read")
        out = struct.unpack("<11i", emu.read("bench_nav_out", 44))
        got[i] = out[:10]
        if out[10] != 0:
            raise bench_arm.BenchError(f"sample {i}: {out[10]} saturations")
        if not np.array_equal(got[i], host[i]):
            raise bench_arm.BenchError(f"sample {i}: the Cortex-M4 build differs from the x86 fixed build: "
                                       f"{got[i].tolist()} vs {host[i].tolist()}")
    m0, n0 = nv.radii(o.lat_deg)
    truth = np.c_[np.deg2rad(traj.lon_deg[1:] - o.lon_deg) * (n0 + o.height_m) * np.cos(np.deg2rad(o.lat_deg)),
                  np.deg2rad(traj.lat_deg[1:] - o.lat_deg) * (m0 + o.height_m), traj.height_m[1:] - o.height_m]
    error = got[:, :3] / 1000.0 - truth
    return {
        "compiler": build.compiler,
        "samples": len(gyr),
        "seconds": seconds,
        "rate_hz": RATE_HZ,
        "distance_m": float(np.sum(np.linalg.norm(traj.vel_enu[:, :2], axis=1)) * traj.dt),
        "instructions_mean": float(counts.mean()),
        "instructions_max": int(counts.max()),
        "stack_bytes": int(stack),
        "state_bytes": build.symbols["bench_nav"].size,
        "horizontal_error_max_m": float(np.max(np.hypot(error[:, 0], error[:, 1]))),
        "vertical_error_max_m": float(np.max(np.abs(error[:, 2]))),
        "velocity_error_max_m_s": float(np.max(np.abs(got[:, 3:6] / 2.0**20 - traj.vel_enu[1:]))),
        "run_s": time.perf_counter() - start,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated drive, s (default 60)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args()
    if args.seconds <= 0:
        parser.error("--seconds must be positive")
    try:
        with tempfile.TemporaryDirectory(prefix="bench_nav.") as tmp:
            r = run(args.seconds, Path(tmp), lambda m: print(m, file=sys.stderr))
    except bench_arm.BenchError as exc:
        print(f"bench_nav: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(f"Cortex-M4 build: {r['compiler']}")
    print(f"car drive, {r['seconds']:g} s at {r['rate_hz']:g} Hz ({r['distance_m']:.0f} m), ideal sensors; "
          f"every sample identical to the x86 fixed build")
    print()
    print("| measured | value |")
    print("|---|---:|")
    print(f"| imu_nav_propagate, instructions per IMU step, mean / max | {r['instructions_mean']:.0f} / "
          f"{r['instructions_max']} |")
    print(f"| stack, bytes (painted) | {r['stack_bytes']} |")
    print(f"| imu_nav_t, bytes | {r['state_bytes']} |")
    print(f"| position error vs truth, horizontal / vertical max, m | {r['horizontal_error_max_m']:.3f} / "
          f"{r['vertical_error_max_m']:.3f} |")
    print(f"| velocity error vs truth, max, m/s | {r['velocity_error_max_m_s']:.5f} |")
    print(f"\nruntime: {r['run_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
