#!/usr/bin/env python3
"""Design study for the `nav` filter (issue 16): a loosely coupled 15-state error-state
Kalman filter in float64 numpy, run on the simulator's car drive (imulink.sim.navigation).

Not the product: the filter of issue 16 is to be C (fixed point and float twin from one
source). This script fixes the design the C code follows and measures what it reaches:

- nominal state: geodetic position (latitude, longitude, height), velocity in the local
  east-north-up frame, the attitude quaternion (sensor to that frame), gyro and
  accelerometer biases; strapdown at the IMU rate (attitude by the exact rotation of
  each gyro sample, velocity with the specific force as the interval's mean in the
  turning body, position by the trapezoid over the rates of latitude, longitude and
  height), normal gravity where the vehicle is;
- error state [dp (metres east, north, up), dv, dtheta (sensor frame), dbg, dba],
  covariance propagated every sample with the first-order transition except for the
  attitude error's, which is the exact rotation back over the sample's turn (the first
  order misplaces P's correlations at a foot's 400 deg/s, and zero-velocity updates then
  turned the heading);
- updates: GNSS position (the fix's latitude, longitude and height as metres from the
  estimate) and velocity together (their accuracies as the receiver reports them),
  gated by the innovation's chi-square (6 degrees of freedom, 99.9 %: 22.46), accepted
  again after 5 s of rejections; at rest (the last fix's speed below 0.3 m/s, the
  bias-corrected gyroscope below 1.5 deg/s and the specific force without a trend over
  0.5 s: the means of its halves within 0.03 m/s^2) zero velocity and the
  magnetometer's heading (the field's east component in the estimated ENU frame);
  `--foot`: no GNSS, zero velocity and zero rate (the gyroscope reads its bias) in every
  stance;
- start: at the first fix, at rest: tilt from the accelerometer, heading from the
  magnetometer, position and velocity from the fix.

    .venv/bin/python tools/nav_prototype.py [--minutes 20] [--seed 0] [--outages] [--correlated]
    .venv/bin/python tools/nav_prototype.py --foot [--minutes 5] [--seed 0]
    .venv/bin/python tools/nav_prototype.py --handheld [--minutes 10] [--seed 0]

Prints RMSEs of horizontal and vertical position, velocity and heading after the first
60 s, the drift at the end of each outage, and the fixes rejected; with --foot, the
position error at the end as a share of the distance walked; with --handheld, the
horizontal error just before each marker's fix.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from imulink.sim import navigation as nv
from imulink.sim import quat as Q
from imulink.sim import simulate
from imulink.sim.sensors import AccModel, GyroModel, MagModel, SensorSuite

DEG = math.pi / 180.0
#: MPU6050 data sheet: gyro rate noise 0.005 deg/s/sqrt(Hz), accelerometer 400 ug/sqrt(Hz).
GYRO_ARW = 0.005 * DEG                 # rad/s/sqrt(Hz) = rad/sqrt(s)
ACC_VRW = 400e-6 * 9.80665             # m/s^2/sqrt(Hz)
#: Turn-on biases (after the factory trim; the data sheet allows more).
GYRO_BIAS = np.array([0.8, -0.5, 0.6]) * DEG
ACC_BIAS = np.array([0.25, -0.3, 0.2])
CHI2_6_999 = 22.46


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotvec_quat(v):
    return Q.from_rotvec(np.asarray(v))


def mean_rotation(phi):
    """(1/theta) int_0^theta Exp(s u) ds for phi = theta u."""
    theta = float(np.linalg.norm(phi))
    if theta < 1e-8:
        return np.eye(3) + skew(phi) / 2.0
    u = skew(phi / theta)
    return np.eye(3) + (1.0 - math.cos(theta)) / theta * u + (1.0 - math.sin(theta) / theta) * u @ u


class Nav:
    """The 15-state loosely coupled filter (float64)."""

    def __init__(self, dt: float):
        self.dt = dt
        self.geo = np.zeros(3)  # latitude, longitude (rad), height (m)
        self.v = np.zeros(3)
        self.q = Q.IDENTITY.copy()
        self.bg = np.zeros(3)
        self.ba = np.zeros(3)
        self.P = np.diag(np.r_[[25.0] * 3, [1.0] * 3, [(2 * DEG) ** 2] * 2, [(10 * DEG) ** 2],
                               [(1.5 * DEG) ** 2] * 3, [0.5 ** 2] * 3])
        # continuous noise densities (squared): velocity (acc white), angle (gyro white), bias random walks;
        # twice the data sheet's white noise, room for quantisation and what the first-order model leaves out
        self.q_acc = (ACC_VRW * 2.0) ** 2
        self.q_gyro = (GYRO_ARW * 2.0) ** 2
        self.q_bg = (1e-5) ** 2
        self.q_ba = (1e-4) ** 2
        self.rejected = 0
        self.rejecting_since = None
        self.field_ref = None

    def propagate(self, gyr, acc):
        dt = self.dt
        w = gyr - self.bg
        f = acc - self.ba
        r0 = Q.to_rotmat(self.q)
        self.q = Q.normalize(Q.multiply(self.q, rotvec_quat(w * dt)))
        # the sample is the specific force's mean in the turning body, M^T R0^T f with M the
        # mean rotation over the interval: f = R0 (M^T)^-1 sample, exact for a constant rate
        # (to first order R0 (I + [phi x] / 2) sample: the middle of the turn)
        a = r0 @ np.linalg.solve(mean_rotation(w * dt).T, f) - np.array([0.0, 0.0, self.gravity()])
        v_new = self.v + a * dt
        self.move((self.v + v_new) * dt / 2)
        self.v = v_new
        F = np.zeros((15, 15))
        F[0:3, 3:6] = np.eye(3)
        F[3:6, 6:9] = -r0 @ skew(f)
        F[3:6, 12:15] = -r0
        F[6:9, 6:9] = -skew(w)
        F[6:9, 9:12] = -np.eye(3)
        Phi = np.eye(15) + F * dt
        # the attitude error's exact transition over the turn (the first order I - [w x] dt
        # misplaces P's correlations at a foot's 400 deg/s)
        Phi[6:9, 6:9] = Q.to_rotmat(rotvec_quat(w * dt)).T
        Qd = np.zeros((15, 15))
        Qd[3:6, 3:6] = np.eye(3) * self.q_acc * dt
        Qd[6:9, 6:9] = np.eye(3) * self.q_gyro * dt
        Qd[9:12, 9:12] = np.eye(3) * self.q_bg * dt
        Qd[12:15, 12:15] = np.eye(3) * self.q_ba * dt
        self.P = Phi @ self.P @ Phi.T + Qd

    def gravity(self) -> float:
        return float(nv.normal_gravity(math.degrees(self.geo[0]), self.geo[2]))

    def move(self, enu):
        """The position moved by metres east, north and up."""
        m, n = nv.radii(math.degrees(self.geo[0]))
        self.geo += [enu[1] / (m + self.geo[2]), enu[0] / ((n + self.geo[2]) * math.cos(self.geo[0])), enu[2]]

    def offsets(self, lat_deg, lon_deg, height_m):
        """Metres east, north, up of a geodetic point from the estimate."""
        return nv.local_offsets(lat_deg, lon_deg, height_m, math.degrees(self.geo[0]), math.degrees(self.geo[1]),
                                self.geo[2])

    def _update(self, y, H, R, gate=None, now=0.0):
        S = H @ self.P @ H.T + R
        nis = float(y @ np.linalg.solve(S, y))
        if gate is not None and nis > gate:
            if self.rejecting_since is None:
                self.rejecting_since = now
            if now - self.rejecting_since < 5.0:
                self.rejected += 1
                return False
        self.rejecting_since = None
        K = self.P @ H.T @ np.linalg.inv(S)
        dx = K @ y
        A = np.eye(15) - K @ H
        self.P = A @ self.P @ A.T + K @ R @ K.T
        self.move(dx[0:3])
        self.v += dx[3:6]
        self.q = Q.normalize(Q.multiply(self.q, rotvec_quat(dx[6:9])))
        self.bg += dx[9:12]
        self.ba += dx[12:15]
        return True

    def gnss(self, lat_deg, lon_deg, height_m, vel, h_acc, v_acc, s_acc, now):
        H = np.zeros((6, 15))
        H[0:3, 0:3] = np.eye(3)
        H[3:6, 3:6] = np.eye(3)
        R = np.diag([h_acc ** 2 / 2, h_acc ** 2 / 2, v_acc ** 2, s_acc ** 2, s_acc ** 2, s_acc ** 2])
        y = np.r_[self.offsets(lat_deg, lon_deg, height_m), vel - self.v]
        return self._update(y, H, R, CHI2_6_999, now)

    def zero_velocity(self):
        H = np.zeros((3, 15))
        H[:, 3:6] = np.eye(3)
        self._update(-self.v, H, np.eye(3) * 0.02 ** 2)

    def still(self, gyr, acc) -> bool:
        """Whether windows of gyroscope and accelerometer samples look like a body at rest:
        the bias-corrected rate below 0.05 rad/s and the specific force within 0.3 m/s^2 of
        gravity throughout (a foot's stance, a walker's pause)."""
        w = np.linalg.norm(gyr - self.bg, axis=1)
        f = np.linalg.norm(acc - self.ba, axis=1)
        return bool(w.max() < 0.05 and np.abs(f - self.gravity()).max() < 0.3)

    def position(self, lat_deg, lon_deg, height_m, accuracy_m):
        """A position-only fix (a marker), its accuracy on each axis."""
        H = np.zeros((3, 15))
        H[:, 0:3] = np.eye(3)
        self._update(self.offsets(lat_deg, lon_deg, height_m), H, np.eye(3) * accuracy_m ** 2)

    def zero_rate(self, gyr):
        """At rest the gyroscope reads its bias: the bias-corrected rate should be zero."""
        H = np.zeros((3, 15))
        H[:, 9:12] = np.eye(3)
        self._update(gyr - self.bg, H, np.eye(3) * (GYRO_ARW * math.sqrt(1.0 / self.dt) * 2.0) ** 2)

    def heading_from_field(self, mag):
        """The field's east component in the estimated ENU frame against the reference's (0)."""
        r = Q.to_rotmat(self.q)
        m_e = r @ mag
        north, up = self.field_ref
        # east of (I - [phi x]) m with phi = R dtheta: phi_z north - phi_y up
        H = np.zeros((1, 15))
        H[0, 6:9] = -(north * r[2, :] - up * r[1, :])
        self._update(np.array([0.0 - m_e[0]]), H, np.array([[1.0 ** 2]]))

    def start(self, acc, mag, lat_deg, lon_deg, height_m, vel):
        up = acc / np.linalg.norm(acc)  # the sensor's up at rest (specific force)
        east = np.cross(mag, up)        # the field points north and down: field x up is east
        east /= np.linalg.norm(east)
        north = np.cross(up, east)
        rot = np.stack([east, north, up])  # rows: the earth axes in the sensor frame, i.e. R (sensor to ENU)
        self.q = Q.from_rotmat(rot)
        self.geo = np.array([math.radians(lat_deg), math.radians(lon_deg), height_m])
        self.v = vel.copy()
        m_e = rot @ mag
        self.field_ref = (m_e[1], m_e[2])


def sensors(rate: float) -> SensorSuite:
    """The MPU6050 data sheet's white noise and the turn-on biases above."""
    return SensorSuite(gyro=GyroModel(arw=GYRO_ARW, bias_instability=0.0, rrw=0.0, bias=GYRO_BIAS),
                       acc=AccModel(noise_std=ACC_VRW * math.sqrt(rate / 2), bias=ACC_BIAS), mag=MagModel())


def run_foot(minutes: float, seed: int) -> dict:
    """A foot-mounted walk without GNSS: zero velocity and zero rate in every stance (a
    detector on the gyroscope and the specific force over 50 ms)."""
    rate = 100.0
    traj = nv.foot_walk(minutes * 60.0, rate, seed=seed)
    imu = simulate(traj, sensors(rate), seed=seed)
    nav = Nav(1.0 / rate)
    o = traj.origin
    nav.start(imu.acc[0], imu.mag[0], o.lat_deg, o.lon_deg, o.height_m, np.zeros(3))
    window = 5
    stances = 0
    for k in range(1, len(traj)):
        nav.propagate(imu.gyr[k], imu.acc[k])
        if k >= window and nav.still(imu.gyr[k - window:k + 1], imu.acc[k - window:k + 1]):
            nav.zero_velocity()
            nav.zero_rate(imu.gyr[k])
            stances += 1
    end = -nav.offsets(traj.lat_deg[-1], traj.lon_deg[-1], traj.height_m[-1])  # the estimate minus the truth
    walked = float(np.sum(np.linalg.norm(traj.vel_enu[:, :2], axis=1)) * traj.dt)
    return {"walked_m": walked, "end_error_m": float(np.linalg.norm(end[:2])),
            "end_error_percent_of_distance": 100.0 * float(np.linalg.norm(end[:2])) / walked,
            "end_height_error_m": float(end[2]), "samples_with_zero_velocity": stances}


def run_handheld(minutes: float, seed: int) -> dict:
    """A handheld walk indoors without GNSS: a marker's position fix each minute, zero
    velocity and zero rate while the walker pauses (the foot's detector over 0.5 s)."""
    rate = 100.0
    traj = nv.handheld_walk(minutes * 60.0, rate, seed=seed)
    imu = simulate(traj, sensors(rate), seed=seed)
    markers = nv.marker_fixes(traj, 60.0, 0.1, seed=seed)
    at = {int(k): j for j, k in enumerate(markers.index)}
    nav = Nav(1.0 / rate)
    o = traj.origin
    nav.start(imu.acc[0], imu.mag[0], o.lat_deg, o.lon_deg, o.height_m, np.zeros(3))  # at a marker
    window = 50
    before = []
    for k in range(1, len(traj)):
        nav.propagate(imu.gyr[k], imu.acc[k])
        if k in at:
            j = at[k]
            before.append(float(np.linalg.norm(nav.offsets(traj.lat_deg[k], traj.lon_deg[k], traj.height_m[k])[:2])))
            nav.position(markers.lat_deg[j], markers.lon_deg[j], markers.height_m[j], markers.accuracy_m)
        if k >= window and nav.still(imu.gyr[k - window:k + 1], imu.acc[k - window:k + 1]):
            nav.zero_velocity()
            nav.zero_rate(imu.gyr[k])
    return {"horizontal_error_before_each_marker_m": [round(e, 1) for e in before],
            "mean_before_marker_m": float(np.mean(before)), "max_before_marker_m": float(np.max(before))}


def run(minutes: float, seed: int, outages: bool, correlated: bool) -> dict:
    rate = 100.0
    traj = nv.car_drive(minutes * 60.0, rate, seed=seed)
    imu = simulate(traj, sensors(rate), seed=seed)
    spans = ((300.0, 330.0), (700.0, 730.0)) if outages else ()
    model = nv.GnssModel(outages=spans, correlated_h_m=2.0 if correlated else 0.0,
                         correlated_v_m=3.0 if correlated else 0.0,
                         multipath=((420.0, 430.0, 15.0, -10.0, 5.0),) if correlated else ())
    fixes = nv.gnss_fixes(traj, model, seed=seed)
    fix_at = {int(k): j for j, k in enumerate(fixes.index)}
    nav = Nav(1.0 / rate)
    n = len(traj)
    est_geo, est_v, est_q = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 4))
    window = int(0.5 * rate)
    started = False
    last_fix_speed, last_fix_time = math.inf, -math.inf
    for k in range(n):
        gyr, acc, mag = imu.gyr[k], imu.acc[k], imu.mag[k]
        if not started:
            if k in fix_at:
                j = fix_at[k]
                nav.start(acc, mag, fixes.lat_deg[j], fixes.lon_deg[j], fixes.height_m[j], fixes.vel_enu[j])
                started = True
            est_geo[k], est_q[k] = nav.geo, nav.q
            continue
        nav.propagate(gyr, acc)
        if k in fix_at:
            j = fix_at[k]
            nav.gnss(fixes.lat_deg[j], fixes.lon_deg[j], fixes.height_m[j], fixes.vel_enu[j], fixes.h_acc_m[j],
                     fixes.v_acc_m[j], fixes.s_acc_m_s[j], traj.t[k])
        if k in fix_at:
            last_fix_speed, last_fix_time = np.linalg.norm(fixes.vel_enu[fix_at[k]]), traj.t[k]
        if k >= window and k % 10 == 0 and traj.t[k] - last_fix_time < 1.5 and last_fix_speed < 0.3:
            # a car at rest: the receiver says it stands, and the gyroscope and the specific
            # force are still (the force's norm alone cannot see a gentle straight start)
            w = imu.gyr[k - window:k + 1] - nav.bg
            f = imu.acc[k - window:k + 1]
            half = len(f) // 2
            trend = np.linalg.norm(f[half:].mean(axis=0) - f[:half].mean(axis=0))  # a start's rising force
            if np.max(np.linalg.norm(w, axis=1)) < 1.5 * DEG and trend < 0.03:
                nav.zero_velocity()
                nav.heading_from_field(mag)
        est_geo[k], est_v[k], est_q[k] = nav.geo, nav.v, nav.q
    t = traj.t
    settled = t >= 60.0
    error = nv.local_offsets(np.degrees(est_geo[:, 0]), np.degrees(est_geo[:, 1]), est_geo[:, 2], traj.lat_deg,
                             traj.lon_deg, traj.height_m)
    herr = np.linalg.norm(error[:, :2], axis=1)
    verr = np.abs(error[:, 2])
    velerr = np.linalg.norm(est_v - traj.vel_enu, axis=1)
    fwd_true = Q.rotate(traj.quat, [0.0, 1.0, 0.0])
    fwd_est = Q.rotate(est_q, [0.0, 1.0, 0.0])
    heading_err = np.degrees(np.angle(np.exp(1j * (np.arctan2(fwd_est[:, 0], fwd_est[:, 1])
                                                   - np.arctan2(fwd_true[:, 0], fwd_true[:, 1])))))
    result = {
        "horizontal_rmse_m": float(np.sqrt(np.mean(herr[settled] ** 2))),
        "vertical_rmse_m": float(np.sqrt(np.mean(verr[settled] ** 2))),
        "velocity_rmse_m_s": float(np.sqrt(np.mean(velerr[settled] ** 2))),
        "heading_rmse_deg": float(np.sqrt(np.mean(heading_err[settled] ** 2))),
        "rejected_fixes": nav.rejected,
        "gyro_bias_error_deg_s": (np.degrees(nav.bg - GYRO_BIAS)).round(3).tolist(),
        "acc_bias_error_m_s2": (nav.ba - ACC_BIAS).round(3).tolist(),
    }
    for start, end in spans:
        k = int(round(end * rate)) - 1
        result[f"drift_after_outage_{start:g}_s_m"] = float(herr[k])
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--outages", action="store_true", help="two 30 s GNSS outages (at 300 s and 700 s)")
    parser.add_argument("--correlated", action="store_true",
                        help="time-correlated GNSS errors (2 m horizontal, 3 m vertical, 100 s) and a 15 m jump")
    parser.add_argument("--foot", action="store_true",
                        help="instead: a foot-mounted walk (laps of 20 m x 10 m) without GNSS, zero-velocity updates")
    parser.add_argument("--handheld", action="store_true",
                        help="instead: a handheld walk indoors, a marker's position fix each minute, no GNSS")
    args = parser.parse_args()
    started = time.monotonic()
    if args.foot:
        result = run_foot(args.minutes, args.seed)
    elif args.handheld:
        result = run_handheld(args.minutes, args.seed)
    else:
        result = run(args.minutes, args.seed, args.outages, args.correlated)
    for key, value in result.items():
        print(f"{key}: {value if not isinstance(value, float) else round(value, 3)}")
    print(f"({time.monotonic() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
