"""The strapdown navigation of the `nav` filter (firmware/core/imu_nav.c), both builds
(tests/c/nav_driver.c, with the sanitizers; the fixed one with every narrowing checked),
against the navigation simulator's truth:
normal gravity, a car drive with ideal sensors, and a fast straight run far from the
origin (the curvilinear position's scales)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imulink.sim import navigation as nv
from imulink.sim.sensors import _interval_mean_in_body

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(GCC is None, reason="gcc not found")

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware" / "core"
DRIVER = ROOT / "tests" / "c" / "nav_driver.c"


@pytest.fixture(scope="module")
def drivers(tmp_path_factory):
    out = {}
    for build in ("FIXED", "FLOAT"):
        exe = tmp_path_factory.mktemp("nav") / f"nav_{build.lower()}"
        checked = ["-DIMU_CHECK_NARROWING"] if build == "FIXED" else []
        proc = subprocess.run([GCC, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", f"-DIMU_{build}", *checked,
                               f"-I{CORE}", "-fsanitize=undefined,address", "-fno-sanitize-recover=all", "-o", str(exe),
                               str(DRIVER), str(CORE / "imu_nav.c"), str(CORE / "imu_math.c"), "-lm"],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        out[build.lower()] = exe
    return out


def run(exe, rate, lat_deg, lon_deg, height_m, quat, vel, gyr, acc, saturations=False):
    """(gravity at the origin, (N, 10) east north up (m), velocity ENU, quaternion after each sample);
    no saturation unless `saturations`."""
    head = [rate, lat_deg, lon_deg, height_m, *quat, *vel]
    lines = [" ".join(repr(float(x)) for x in head)]
    lines += [" ".join(repr(float(x)) for x in (*g, *a)) for g, a in zip(gyr, acc)]
    proc = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = proc.stdout.strip().split("\n")
    assert rows[0].startswith("gravity ") and rows[-1].startswith("saturations "), (rows[0], rows[-1])
    assert (rows[-1] != "saturations 0") == saturations, rows[-1]
    return float(rows[0].split()[1]), np.array([row.split() for row in rows[1:-1]], dtype=float)


@pytest.mark.parametrize("lat_deg,height_m", [(0.0, 0.0), (47.38, 450.0), (-33.9, -400.0), (60.0, 3000.0),
                                              (84.0, 9000.0)])
def test_normal_gravity_is_wgs84s(drivers, lat_deg, height_m):
    """Somigliana's formula with the free-air correction, as the simulator computes it
    exactly: the series for 1 / sqrt(1 - e^2 sin^2) and Q24 keep it within 2e-6 m/s^2."""
    expected = float(nv.normal_gravity(lat_deg, height_m))
    for build in ("fixed", "float"):
        gravity, _ = run(drivers[build], 100.0, lat_deg, 10.0, height_m, (1, 0, 0, 0), (0, 0, 0), [], [])
        assert gravity == pytest.approx(expected, abs=2e-6), build


def _truth_offsets(traj, rows=slice(1, None)):
    """Curvilinear east, north (m along the origin's parallel and meridian) and height of the truth."""
    o = traj.origin
    m0, n0 = nv.radii(o.lat_deg)
    north = np.deg2rad(traj.lat_deg[rows] - o.lat_deg) * (m0 + o.height_m)
    east = np.deg2rad(traj.lon_deg[rows] - o.lon_deg) * (n0 + o.height_m) * np.cos(np.deg2rad(o.lat_deg))
    return np.c_[east, north, traj.height_m[rows] - o.height_m]


def test_strapdown_follows_a_car_drive_with_ideal_sensors(drivers):
    """Ten minutes, 5.9 km with turns, stops and hills at 100 Hz: with the gyroscope's exact
    rates and the specific force's interval means, what is left is the propagation's own
    error (the specific force turned to the middle of each step to first order) and, in the
    fixed build, rounding. Measured: horizontal 1 mm (float) and 16 cm (fixed), vertical
    3 cm and 4 mm, velocity 1e-4 and 4e-4 m/s (vertical: normal gravity's series, 1e-6
    m/s^2, in an open vertical channel)."""
    traj = nv.car_drive(600.0, 100.0, seed=0)
    f_earth = traj.acc_lin.copy()
    f_earth[:, 2] += traj.gravity
    acc = _interval_mean_in_body(traj.quat, traj.gyr, traj.dt, f_earth)
    o = traj.origin
    truth = _truth_offsets(traj)
    got = {}
    for build, horizontal, vertical, speed in (("float", 0.01, 0.1, 1e-3), ("fixed", 0.5, 0.1, 2e-3)):
        _, r = run(drivers[build], traj.rate_hz, o.lat_deg, o.lon_deg, o.height_m, traj.quat[0], traj.vel_enu[0],
                   traj.gyr[1:], acc[1:])
        assert len(r) == len(traj.t) - 1
        error = r[:, :3] - truth
        assert np.max(np.hypot(error[:, 0], error[:, 1])) < horizontal, build
        assert np.max(np.abs(error[:, 2])) < vertical, build
        assert np.max(np.abs(r[:, 3:6] - traj.vel_enu[1:])) < speed, build
        got[build] = r
    assert np.max(np.abs(got["fixed"][:, :3] - got["float"][:, :3])) < 0.3


def test_position_stays_geodetic_far_from_the_origin(drivers):
    """A level run at 250 m/s north and 150 m/s east from 60 deg north for ten minutes
    (146 km north, 88 km east): the north and east scales change with the latitude (the
    east one by 4 %), and the offsets must still be the latitude and longitude times the
    origin's radii. Truth: the same trapezoid over the rates of latitude and longitude in
    float64, gravity from the simulator (the filter's series for it is 1e-6 m/s^2 off:
    8 cm of height in ten minutes). Measured: 0.2 mm (float) and 3.8 mm (fixed)."""
    rate, lat0, lon0, h0 = 50.0, 60.0, 10.0, 1000.0
    vel = np.array([150.0, 250.0, 0.0])
    n = int(600 * rate)
    dt = 1.0 / rate
    lat = np.empty(n + 1)
    lon = np.empty(n + 1)
    lat[0], lon[0] = np.deg2rad(lat0), np.deg2rad(lon0)
    for k in range(n):
        m, nn = nv.radii(np.rad2deg(lat[k]))
        lat[k + 1] = lat[k] + vel[1] * dt / (m + h0)
        m2, n2 = nv.radii(np.rad2deg(lat[k + 1]))
        lon[k + 1] = lon[k] + vel[0] * dt / ((nn + h0) * np.cos(lat[k]))
    gravity = nv.normal_gravity(np.rad2deg(lat[:-1]), h0)
    acc = np.c_[np.zeros(n), np.zeros(n), gravity]
    m0, n0 = nv.radii(lat0)
    truth = np.c_[(lon[1:] - lon[0]) * (n0 + h0) * np.cos(lat[0]), (lat[1:] - lat[0]) * (m0 + h0)]
    for build, tolerance in (("float", 0.01), ("fixed", 0.05)):
        _, r = run(drivers[build], rate, lat0, lon0, h0, (1, 0, 0, 0), vel, np.zeros((n, 3)), acc)
        error = np.hypot(*(r[:, :2] - truth).T)
        assert truth[-1, 1] > 145_000 and truth[-1, 0] > 85_000
        assert np.max(error) < tolerance, build
        assert np.max(np.abs(r[:, 2])) < 0.3, build


def test_extreme_motion_saturates_without_undefined_behaviour(drivers):
    """Ten minutes at 10 Hz near the latitude limit of a tumbling board at the MPU6050's
    full scale (35 rad/s, 16 g) pushed straight down: speed, height and the east scale
    leave their ranges and are held there (counted, in both builds: the speed limit is the
    filter's), and the checked, sanitized fixed build finds no overflow."""
    n = 6000
    rng = np.random.default_rng(3)
    gyr = rng.uniform(-35.0, 35.0, (n, 3))
    acc = rng.uniform(-157.0, 157.0, (n, 3))
    acc[:, 2] = -157.0
    for build in ("fixed", "float"):
        _, r = run(drivers[build], 10.0, 84.9, 179.0, 9000.0, (0.5, 0.5, 0.5, 0.5), (500.0, -500.0, -500.0),
                   gyr, acc, saturations=True)
        assert np.all(np.isfinite(r)), build
        assert np.max(np.abs(r[:, 3:6])) <= 512.0, build
