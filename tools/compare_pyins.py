#!/usr/bin/env python3
"""The nav filter beside pyins (github.com/nmayorov/pyins), an open loosely coupled GNSS/INS
filter, on the same simulated data: the 20 min car drive of tools/bench_nav.py (MPU6050
data-sheet noise and turn-on biases, GNSS at 1 Hz with white errors of 2.5 m, 5 m,
0.1 m/s, seed 0). A benchmark, not a test: pyins is not on the package index and needs
pandas and numba, which imulink does not use.

Set-up (a pyins snapshot, e.g. commit 8377ede, extracted to SRC; its own virtualenv):

    python3 -m venv /tmp/pyins-venv && /tmp/pyins-venv/bin/pip install numpy scipy pandas numba cffi
    PYTHONPATH=SRC:host /tmp/pyins-venv/bin/python tools/compare_pyins.py [--truth-init] [--time-step 0.1]

(`host` holds the imulink package with its built C core: `make setup` first.)

Both filters start at the first fix with the attitude from the accelerometer and the
magnetometer (--truth-init: pyins from the truth turned by (1, 1, 10) deg) and the same
initial uncertainties (position from the fix, velocity 1 m/s, tilt 2 deg, heading 10 deg,
gyro bias 1.5 deg/s, accelerometer bias 0.5 m/s^2) and sensor noise (twice the data
sheet's densities; bias walks 1e-5 rad/s/sqrt(s), 1e-4 m/s^2/sqrt(s)). Mapping: the
simulator's ENU and sensor axes (x right, y forward, z up) to pyins' NED and body FRD by
the same proper rotation; increments theta = gyr dt and dv = (I + [theta x] / 2) acc dt
(the simulator's rate is constant over each interval and its specific force the interval's
mean in the turning body). pyins models the Earth's rotation, which the simulator leaves
out (its effect here: below 0.001 deg and 0.001 m/s). Errors after the first minute.
"""
import argparse
import time

import numpy as np
import pandas as pd
import pyins
from pyins import filters, inertial_sensor, measurements, transform

from imulink.analysis import nav
from imulink.io.nav_input import simulated_input
from imulink.sim import navigation as nv
from imulink.sim import quat as Q
from imulink.sim import simulate

ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                             formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
ap.add_argument("--truth-init", action="store_true", help="pyins starts from the truth turned by (1, 1, 10) deg")
ap.add_argument("--time-step", type=float, default=0.1, help="pyins' covariance step, s (default 0.1, its own)")
args = ap.parse_args()

# ---------------------------------------------------------------- simulated data
RATE_HZ = 100.0
traj = nv.car_drive(1200.0, RATE_HZ, seed=0)
imu = simulate(traj, nv.datasheet_sensors(RATE_HZ), seed=0)
fixes = nv.gnss_fixes(traj, nv.GnssModel(), seed=0)
dt = 1.0 / RATE_HZ
t = traj.t

# Frames: sim ENU / sensor (x right, y forward, z up)  ->  pyins NED / body FRD
# (x forward, y right, z down). Both swaps are the same proper rotation P (det +1).
P = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def enu_to_ned(v):
    return np.asarray(v) @ P.T


def mat_nb_from_quat(q):
    """pyins' C_nb (FRD body -> NED) from the simulator's quaternion (sensor -> ENU, w first)."""
    return P @ Q.to_rotmat(q) @ P.T


# IMU increments. gyr[k] is the constant rate over (t[k-1], t[k]] and acc[k] the mean
# specific force over that interval in the turning body frame, so theta = gyr*dt exactly
# and the velocity increment in the body frame at the interval start (what pyins'
# integrator expects) is (I + 0.5[theta x]) acc*dt to 2nd order. No coning/sculling terms
# (pyins' compute_increments_from_imu would add ones that assume linearly varying rates).
theta = enu_to_ned(imu.gyr[1:]) * dt           # P maps sensor axes to FRD as well
dvel = enu_to_ned(imu.acc[1:]) * dt
dvel = dvel + 0.5 * np.cross(theta, dvel)
increments = pd.DataFrame(np.column_stack([np.full(len(theta), dt), theta, dvel]),
                          index=pd.Index(t[1:], name="time"),
                          columns=["dt", "theta_x", "theta_y", "theta_z",
                                   "dv_x", "dv_y", "dv_z"])

# ---------------------------------------------------------------- initialisation
k0 = int(fixes.index[0])            # the first fix, IMU sample 0
t0 = t[k0]
if args.truth_init:
    rph_true = transform.mat_to_rph(mat_nb_from_quat(traj.quat[k0]))
    rph0 = rph_true + np.array([1.0, 1.0, 10.0])
else:
    # TRIAD: up from the accelerometer, north from the magnetometer (the sim's field
    # points to true north with a dip), both in sensor axes at sample k0.
    up = imu.acc[k0] / np.linalg.norm(imu.acc[k0])
    m = imu.mag[k0]
    north = m - (m @ up) * up
    north /= np.linalg.norm(north)
    east = np.cross(north, up)
    R_enu_s = np.vstack([east, north, up])   # rows: ENU axes in sensor coordinates
    rph0 = transform.mat_to_rph(P @ R_enu_s @ P.T)

initial_pva = pd.Series(
    np.hstack([[fixes.lat_deg[0], fixes.lon_deg[0], fixes.height_m[0]],
               enu_to_ned(fixes.vel_enu[0]), rph0]),
    index=["lat", "lon", "alt", "VN", "VE", "VD", "roll", "pitch", "heading"], name=t0)

sd_h0 = fixes.h_acc_m[0] / np.sqrt(2.0)   # per horizontal axis
sd_v0 = fixes.v_acc_m[0]
VEL_SD, LEVEL_SD, AZIMUTH_SD = 1.0, 2.0, 10.0

# pyins takes one position sd for all three axes: wrap its covariance initialisation to
# give the vertical its own sd (P_ins = T P_out T^T, so add (sv^2 - sh^2) T[:,D] T[:,D]^T).
_orig_init_cov = filters._initialize_covariance


def _init_cov(pva, pos_sd, *rest):
    Pm = _orig_init_cov(pva, pos_sd, *rest)
    error_model = rest[3]
    T = error_model.transform_to_internal(pva)
    col = T[:, error_model.DRD]
    n = error_model.n_states
    Pm[:n, :n] += (sd_v0**2 - pos_sd**2) * np.outer(col, col)
    return Pm


filters._initialize_covariance = _init_cov

# Sensor models for the filter (states: 3 gyro biases + 3 accel biases).
gyro_model = inertial_sensor.EstimationModel(
    bias_sd=np.deg2rad(1.5), noise=2 * np.deg2rad(0.005), bias_walk=1e-5)
accel_model = inertial_sensor.EstimationModel(
    bias_sd=0.5, noise=2 * 400e-6 * 9.80665, bias_walk=1e-4)

# ---------------------------------------------------------------- GNSS measurements
use = np.arange(len(fixes)) > 0        # fix 0 initialised the state: not reused
ft = t[fixes.index[use]]
pos_df = pd.DataFrame({"lat": fixes.lat_deg[use], "lon": fixes.lon_deg[use],
                       "alt": fixes.height_m[use]}, index=ft)
vel_df = pd.DataFrame(enu_to_ned(fixes.vel_enu[use]), columns=["VN", "VE", "VD"], index=ft)


class GnssPosition(measurements.Position):
    """pyins Position with R = diag(h/sqrt2, h/sqrt2, v)^2 from each fix's accuracies."""

    def __init__(self, data, h_acc, v_acc):
        super().__init__(data, 1.0)
        self.sd = pd.DataFrame({"h": np.asarray(h_acc) / np.sqrt(2.0),
                                "v": np.asarray(v_acc)}, index=data.index)

    def compute_matrices(self, time, pva, error_model):
        ret = super().compute_matrices(time, pva, error_model)
        if ret is None:
            return None
        z, H, _ = ret
        s = self.sd.loc[time]
        R = np.diag([s.h**2, s.h**2, s.v**2])[:len(z), :len(z)]
        return z, H, R


pos_meas = GnssPosition(pos_df, fixes.h_acc_m[use], fixes.v_acc_m[use])
s_acc = np.unique(fixes.s_acc_m_s)
assert len(s_acc) == 1
vel_meas = measurements.NedVelocity(vel_df, float(s_acc[0]))

# ---------------------------------------------------------------- run
t_start = time.perf_counter()
result = filters.run_feedback_filter(
    initial_pva, sd_h0, VEL_SD, LEVEL_SD, AZIMUTH_SD, increments,
    gyro_model=gyro_model, accel_model=accel_model,
    measurements=[pos_meas, vel_meas], time_step=args.time_step, with_altitude=True)
wall = time.perf_counter() - t_start

# ---------------------------------------------------------------- errors
est = result.trajectory
est = est[~est.index.duplicated(keep="last")]
k = np.rint(est.index.values * RATE_HZ).astype(int)
assert np.allclose(t[k], est.index.values)
mask = t[k] >= 60.0
k = k[mask]
est = est[mask]

dpos = nv.local_offsets(est.lat.values, est.lon.values, est.alt.values,
                        traj.lat_deg[k], traj.lon_deg[k], traj.height_m[k])   # ENU
v_est_enu = est[["VN", "VE", "VD"]].values @ P.T                               # P = P^-1
dvel_err = v_est_enu - traj.vel_enu[k]
fwd = Q.rotate(traj.quat[k], np.tile([0.0, 1.0, 0.0], (len(k), 1)))          # sensor y in ENU
hdg_true = np.degrees(np.arctan2(fwd[:, 0], fwd[:, 1]))                        # cw from north
dhdg = (est.heading.values - hdg_true + 180.0) % 360.0 - 180.0



def rms(squares) -> float:
    return float(np.sqrt(np.mean(squares)))


print(f"pyins {getattr(pyins, '__version__', '1.0.1')} ({pyins.__file__})")
print(f"options: init={'truth+(1,1,10)deg' if args.truth_init else 'acc tilt + mag heading'} "
      f"time_step={args.time_step}")
print(f"initial rph {np.round(rph0, 3)}  truth rph "
      f"{np.round(transform.mat_to_rph(mat_nb_from_quat(traj.quat[k0])), 3)}")
print(f"samples compared (t >= 60 s): {len(k)}")
print(f"horizontal RMSE  {rms(dpos[:, 0]**2 + dpos[:, 1]**2):.3f} m")
print(f"vertical   RMSE  {rms(dpos[:, 2]**2):.3f} m")
print(f"velocity   RMSE  {rms(np.sum(dvel_err**2, axis=1)):.4f} m/s")
print(f"heading    RMSE  {rms(dhdg**2):.3f} deg")
g_est = result.gyro.iloc[-1].values
a_est = result.accel.iloc[-1].values
print("final gyro bias est (deg/s, FRD):", np.round(np.degrees(g_est), 4),
      " truth:", np.round(np.degrees(P @ nv.DATASHEET_GYRO_BIAS), 4))
print("final acc bias est (m/s^2, FRD):", np.round(a_est, 4),
      " truth:", np.round(P @ nv.DATASHEET_ACC_BIAS, 4))
print(f"pyins run_feedback_filter wall time: {wall:.1f} s")


# ---------------------------------------------------------------- the nav filter on the same data
for arithmetic in ("fixed", "float"):
    t_start = time.perf_counter()
    ours = nav.run(simulated_input(imu, fixes), arithmetic)
    wall = time.perf_counter() - t_start
    settled = (ours.timestamp_us - ours.timestamp_us[0]) >= 60e6
    e = nv.local_offsets(ours.lat_deg, ours.lon_deg, ours.height_m, traj.lat_deg, traj.lon_deg, traj.height_m)
    forward = Q.rotate(ours.quat, np.tile([0.0, 1.0, 0.0], (len(ours.quat), 1)))
    fwd_true = Q.rotate(traj.quat, np.tile([0.0, 1.0, 0.0], (len(ours.quat), 1)))
    heading = np.degrees(np.arctan2(forward[:, 0], forward[:, 1]) - np.arctan2(fwd_true[:, 0], fwd_true[:, 1]))
    heading = (heading + 180.0) % 360.0 - 180.0
    print(f"imulink nav ({arithmetic}): horizontal {rms(np.sum(e[settled, :2] ** 2, axis=1)):.3f} m, "
          f"vertical {rms(e[settled, 2] ** 2):.3f} m, "
          f"velocity {rms(np.sum((ours.vel_enu - traj.vel_enu)[settled] ** 2, axis=1)):.4f} m/s, "
          f"heading {rms(heading[settled] ** 2):.3f} deg, {wall:.1f} s")
