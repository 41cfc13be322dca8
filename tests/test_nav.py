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
from imulink.sim import quat as Q
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
    error and, in the fixed build, rounding. The simulator's rates are constant over each
    interval, which the plain rotation vector integrates exactly: the coning term, made for
    rates that vary (test_coning_is_integrated), is an error of its own here, 5e-5 deg at
    most, whose gravity leaks into the velocity. Measured: horizontal 0.40 m (float) and
    0.44 m (fixed), vertical 3 cm, velocity 2e-3 m/s (without the coning term: 1 mm and
    16 cm, 1e-4 and 4e-4 m/s; vertical: normal gravity's series, 1e-6 m/s^2, in an open
    vertical channel)."""
    traj = nv.car_drive(600.0, 100.0, seed=0)
    f_earth = traj.acc_lin.copy()
    f_earth[:, 2] += traj.gravity
    acc = _interval_mean_in_body(traj.quat, traj.gyr, traj.dt, f_earth)
    o = traj.origin
    truth = _truth_offsets(traj)
    got = {}
    for build, horizontal, vertical, speed in (("float", 0.5, 0.1, 3e-3), ("fixed", 0.6, 0.1, 3e-3)):
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


# --------------------------------------------------------------------------- coning and sculling

RATE = 100.0
SUBSTEPS = 64  # the continuous motion at 6.4 kHz: each sample is the mean of 64 substeps


def _rotvec(q: np.ndarray) -> np.ndarray:
    """The rotation vectors (N, 3) of unit quaternions (w first, the short way)."""
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    norm = np.linalg.norm(q[:, 1:], axis=1)
    angle = 2.0 * np.arctan2(norm, q[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm[:, None] > 0, q[:, 1:] * (angle / norm)[:, None], 0.0)


def _continuous_motion(quat_at, force_at, seconds: float):
    """A smooth motion sampled as a MEMS IMU's interval means: `quat_at(t)` the attitude
    (sensor to ENU), `force_at(t, q)` the specific force in the sensor frame. Returns the
    samples (rad/s, m/s^2), the attitude at each sample's end and the true ENU velocity
    change (the specific force turned into ENU, gravity excluded: the caller's)."""
    n = int(seconds * RATE)
    h = 1.0 / (RATE * SUBSTEPS)
    t = np.arange(n * SUBSTEPS + 1) * h
    q = quat_at(t)
    omega = _rotvec(Q.multiply(Q.conjugate(q[:-1]), q[1:])) / h  # each substep's (constant) body rate
    mid = t[:-1] + h / 2
    q_mid = quat_at(mid)
    f_body = force_at(mid, q_mid)
    dv = np.cumsum(Q.rotate(q_mid, f_body) * h, axis=0)[SUBSTEPS - 1::SUBSTEPS]
    gyr = omega.reshape(n, SUBSTEPS, 3).mean(axis=1)
    acc = f_body.reshape(n, SUBSTEPS, 3).mean(axis=1)
    return gyr, acc, q[::SUBSTEPS], dv


def _integrate(q0, gyr, coning: bool) -> np.ndarray:
    """Attitude from the samples, exactly per sample, with or without the coning term (numpy)."""
    q, prev, out = np.asarray(q0, float), np.zeros(3), []
    for w in gyr:
        theta = w / RATE
        q = Q.normalize(Q.multiply(q, Q.from_rotvec(theta + (np.cross(prev, theta) / 12.0 if coning else 0.0))))
        prev = theta
        out.append(q)
    return np.array(out)


def test_coning_is_integrated(drivers):
    """A coning motion (the rotation vector's axis turning at 10 Hz in a plane, 0.02 rad):
    rates that vary within each sample make the rotation vectors of the samples' means
    drift (0.93 deg in 20 s); the coning term takes out 92 % of it. Both builds, within 0.002 deg of the
    numpy integration with the term."""
    beta, spin = 0.02, 2 * np.pi * 10.0

    def quat_at(t):
        return Q.from_rotvec(beta * np.c_[np.cos(spin * t), np.sin(spin * t), np.zeros_like(t)])

    def force_at(t, q):
        return Q.rotate_inverse(q, np.array([0.0, 0.0, 9.8]))

    gyr, acc, q_true, _ = _continuous_motion(quat_at, force_at, 20.0)
    plain = np.degrees(Q.angle_between(_integrate(q_true[0], gyr, False), q_true[1:]))[-1]
    coned = np.degrees(Q.angle_between(_integrate(q_true[0], gyr, True), q_true[1:]))[-1]
    assert plain > 0.5 and coned < 0.1 * plain  # what the term is for
    for build in ("float", "fixed"):
        _, r = run(drivers[build], RATE, 45.0, 0.0, 0.0, q_true[0], (0, 0, 0), gyr, acc)
        error = np.degrees(Q.angle_between(r[:, 6:10], q_true[1:]))[-1]
        assert error < 0.1 * plain and error < coned + 0.002, (build, error, coned, plain)


def test_sculling_is_integrated(drivers):
    """A sculling motion (a 10 Hz roll of 0.02 rad in phase with a 2 m/s^2 sideways
    acceleration): its true vertical velocity grows by B alpha / 2 per second; the samples'
    means turned to the middle of each turn rectify it wrongly (0.026 m/s off after 20 s)
    unless the sculling term is there (0.0005 m/s). Both builds: below a tenth of the
    error without the term."""
    alpha, b, spin = 0.02, 2.0, 2 * np.pi * 10.0

    def quat_at(t):
        return Q.from_rotvec(np.c_[alpha * np.sin(spin * t), np.zeros_like(t), np.zeros_like(t)])

    gravity, _ = run(drivers["float"], RATE, 45.0, 0.0, 0.0, (1, 0, 0, 0), (0, 0, 0), [], [])

    def force_at(t, q):
        return np.c_[np.zeros_like(t), b * np.sin(spin * t), np.zeros_like(t)] + \
            Q.rotate_inverse(q, np.array([0.0, 0.0, gravity]))

    gyr, acc, q_true, dv = _continuous_motion(quat_at, force_at, 20.0)
    truth = dv[-1] - np.array([0.0, 0.0, gravity * 20.0])
    assert truth[2] == pytest.approx(b * alpha / 2 * 20.0, rel=0.05)  # the rectified climb, 0.4 m/s
    # without the term: the velocity from the samples turned to the middle of each turn
    v = np.zeros(3)
    q = q_true[0]
    for w, f in zip(gyr, acc):
        theta = w / RATE
        v += (Q.rotate(q, Q.rotate(Q.from_rotvec(theta / 2), f)) - np.array([0.0, 0.0, gravity])) / RATE
        q = Q.normalize(Q.multiply(q, Q.from_rotvec(theta)))
    plain = np.linalg.norm(v - truth)
    assert plain > 0.02
    for build in ("float", "fixed"):
        _, r = run(drivers[build], RATE, 45.0, 0.0, 0.0, q_true[0], (0, 0, 0), gyr, acc)
        error = np.linalg.norm(r[-1, 3:6] - truth)
        assert error < 0.1 * plain, (build, error, plain)
