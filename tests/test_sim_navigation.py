"""The navigation simulator (imulink.sim.navigation): WGS-84 geometry and gravity against
published values, a car drive's kinematics against themselves and its limits, the GNSS
and barometer error models against their settings."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imulink.sim import navigation as nv
from imulink.sim import quat as Q
from imulink.sim import simulate
from imulink.sim.sensors import AccModel, GyroModel, SensorSuite


def ecef(lat_deg, lon_deg, height_m):
    """The test's own exact reference: earth-centred earth-fixed coordinates of geodetic
    points (m)."""
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    n = nv.WGS84_A / np.sqrt(1.0 - nv.WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + height_m) * np.cos(lat) * np.cos(lon), (n + height_m) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - nv.WGS84_E2) + height_m) * np.sin(lat)], axis=-1)


def exact_offsets(lat_deg, lon_deg, height_m, ref_lat_deg, ref_lon_deg, ref_height_m):
    """East, north, up of points in the tangent frame at each reference point, through ECEF."""
    d = ecef(lat_deg, lon_deg, height_m) - ecef(ref_lat_deg, ref_lon_deg, ref_height_m)
    lat, lon = np.deg2rad(ref_lat_deg), np.deg2rad(ref_lon_deg)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros_like(lon)], axis=-1)
    north = np.stack([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], axis=-1)
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    return np.stack([np.sum(d * east, -1), np.sum(d * north, -1), np.sum(d * up, -1)], axis=-1)


def test_radii_of_curvature_match_wgs84():
    m, n = nv.radii(np.array([0.0, 90.0]))
    np.testing.assert_allclose(m, [6_335_439.327, 6_399_593.626], atol=1e-3)  # a (1 - e^2) and a^2 / b
    np.testing.assert_allclose(n, [6_378_137.0, 6_399_593.626], atol=1e-3)    # a and a^2 / b


def test_local_offsets_are_the_exact_geometry_to_first_order():
    """Within 1 km the first-order offsets are the tangent-plane ones but for terms of order
    d / R: the earth's curvature under the plane (d^2 / 2R up, 8 cm at 1 km) and, across,
    the longitude's scale taken at the reference latitude and the local vertical's tilt
    under a height difference u (below (d^2 + 2 |u| d) / R)."""
    rng = np.random.default_rng(5)
    ref = (-33.9, 151.2, 40.0)
    m, n = nv.radii(ref[0])
    enu = rng.uniform(-700.0, 700.0, (1000, 3)) * [1, 1, 0.05]
    lat = ref[0] + np.degrees(enu[:, 1] / (m + ref[2]))
    lon = ref[1] + np.degrees(enu[:, 0] / ((n + ref[2]) * np.cos(np.radians(ref[0]))))
    np.testing.assert_allclose(nv.local_offsets(lat, lon, ref[2] + enu[:, 2], *ref), enu, atol=1e-8)
    exact = exact_offsets(lat, lon, ref[2] + enu[:, 2], *ref)
    curvature = np.sum(enu[:, :2] ** 2, axis=1) / (2.0 * 6_371_000.0)
    across = np.linalg.norm(exact[:, :2] - enu[:, :2], axis=1)
    d = np.linalg.norm(enu[:, :2], axis=1)
    assert np.all(across <= (d**2 + 2.0 * np.abs(enu[:, 2]) * d) / 6_371_000.0) and across.max() > 0.01
    np.testing.assert_allclose(enu[:, 2] - exact[:, 2], curvature, rtol=0.01, atol=1e-4)


def test_normal_gravity_matches_wgs84():
    assert nv.normal_gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert nv.normal_gravity(90.0, 0.0) == pytest.approx(9.8321849378, abs=1e-10)
    # TR8350.2's closed form with its published constants k and e^2
    for lat in (10.0, 45.0, 63.0):
        s2 = math.sin(math.radians(lat)) ** 2
        published = 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)
        assert nv.normal_gravity(lat, 0.0) == pytest.approx(published, abs=1e-9)
    gradient = (nv.normal_gravity(45.0, 1000.0) - nv.normal_gravity(45.0, 0.0)) / 1000.0
    assert gradient == pytest.approx(-3.086e-6, rel=2e-3)  # the free-air gradient


@pytest.fixture(scope="module")
def drive():
    return nv.car_drive(1200.0, 100.0, seed=2)


def test_the_car_drives_forward_within_a_cars_limits(drive):
    speed = np.linalg.norm(drive.vel_enu, axis=1)
    forward = Q.rotate(drive.quat, [0.0, 1.0, 0.0])
    moving = speed > 0.1
    # the velocity is along the body's y axis
    np.testing.assert_allclose(drive.vel_enu[moving] / speed[moving, None], forward[moving], atol=1e-9)
    assert speed.max() <= 25.0 and np.linalg.norm(drive.acc_lin, axis=1).max() <= 3.2
    lateral = np.linalg.norm(np.cross(drive.acc_lin, forward), axis=1)
    assert lateral.max() <= 3.2
    assert np.degrees(np.linalg.norm(drive.gyr, axis=1)).max() <= 26.0
    assert 8_000 < np.sum(speed) * drive.dt < 20_000  # metres driven in 20 min
    grade = np.degrees(np.arcsin(forward[:, 2]))
    assert 1.0 < np.abs(grade).max() <= math.degrees(math.atan(0.06)) + 0.01


def test_the_car_kinematics_are_consistent(drive):
    dt = drive.dt
    np.testing.assert_allclose(np.diff(drive.vel_enu, axis=0), drive.acc_lin[1:] * dt, atol=1e-9)
    np.testing.assert_allclose(np.diff(drive.pos_enu, axis=0), (drive.vel_enu[:-1] + drive.vel_enu[1:]) * dt / 2,
                               atol=1e-9)
    np.testing.assert_allclose(drive.quat, Q.normalize(drive.quat), atol=1e-12)
    np.testing.assert_array_equal(drive.pos_enu[0], [0.0, 0.0, 0.0])
    # at rest: still, and the first 10 s are rest
    assert drive.rest[: int(9.9 * drive.rate_hz)].all()
    assert np.all(drive.vel_enu[drive.rest] == 0.0) and np.all(drive.gyr[drive.rest] == 0.0)
    assert 0.01 < drive.rest.mean() < 0.2
    # the geodetic path moves as the velocity says, over the ellipsoid
    step = exact_offsets(drive.lat_deg[1:], drive.lon_deg[1:], drive.height_m[1:], drive.lat_deg[:-1],
                         drive.lon_deg[:-1], drive.height_m[:-1])
    np.testing.assert_allclose(step, (drive.vel_enu[:-1] + drive.vel_enu[1:]) * dt / 2, atol=1e-6)  # ECEF rounding
    np.testing.assert_allclose(drive.height_m, drive.origin.height_m + drive.pos_enu[:, 2], atol=1e-9)
    np.testing.assert_allclose(drive.gravity, nv.normal_gravity(drive.lat_deg, drive.height_m))
    # the same seed gives the same drive
    again = nv.car_drive(1200.0, 100.0, seed=2)
    np.testing.assert_array_equal(again.pos_enu, drive.pos_enu)


def test_the_accelerometer_reads_normal_gravity_at_rest():
    equator = nv.car_drive(60.0, 100.0, seed=1, origin=nv.Origin(0.0, 0.0, 0.0))
    suite = SensorSuite(gyro=GyroModel.ideal(), acc=AccModel(bias=(0.0, 0.0, 0.0), noise_std=0.0),
                        mag=SensorSuite.default().mag)
    result = simulate(equator, suite, seed=1)
    norm = np.linalg.norm(result.acc[equator.rest], axis=1)
    # 9.78033 m/s^2, 26 mm/s^2 below standard gravity; within the quantisation (2.4 mm/s^2)
    assert abs(norm.mean() - nv.normal_gravity(0.0, 0.0)) < 0.003


def test_gnss_white_errors_have_the_settings_sizes(drive):
    fixes = nv.gnss_fixes(drive, nv.GnssModel(rate_hz=5.0), seed=3)
    error = fixes.pos_enu - fixes.truth_pos_enu
    assert len(fixes) == 6000
    assert math.sqrt(np.mean(np.sum(error[:, :2] ** 2, axis=1))) == pytest.approx(2.5, rel=0.04)
    assert np.std(error[:, 2]) == pytest.approx(5.0, rel=0.04)
    assert np.std(fixes.vel_enu - fixes.truth_vel_enu) == pytest.approx(0.1, rel=0.04)
    np.testing.assert_array_equal(fixes.h_acc_m, 2.5)
    # the geodetic fix is the truth's geodetic position moved by the error (metres, local)
    k = fixes.index
    offsets = nv.local_offsets(fixes.lat_deg, fixes.lon_deg, fixes.height_m, drive.lat_deg[k], drive.lon_deg[k],
                               drive.height_m[k])
    np.testing.assert_allclose(offsets, error, atol=1e-6)


def test_gnss_outages_latency_multipath_and_correlated_errors(drive):
    model = nv.GnssModel(h_sigma_m=0.0, v_sigma_m=0.0, vel_sigma_m_s=0.0, correlated_h_m=3.0, correlated_v_m=4.0,
                         tau_s=60.0, latency_s=0.12, outages=((300.0, 330.0), (700.0, 730.0)),
                         multipath=((500.0, 510.0, 15.0, -10.0, 5.0),))
    fixes = nv.gnss_fixes(drive, model, seed=4)
    t = fixes.t_valid
    assert len(fixes) == 1200 - 60
    assert not np.any((t >= 300) & (t < 330)) and not np.any((t >= 700) & (t < 730))
    np.testing.assert_allclose(fixes.t_arrival - t, 0.12)
    error = fixes.pos_enu - fixes.truth_pos_enu
    jump = (t >= 500) & (t < 510)
    without = nv.gnss_fixes(drive, nv.GnssModel(**{**model.__dict__, "multipath": ()}), seed=4)
    assert jump.sum() == 10
    np.testing.assert_allclose(fixes.pos_enu[jump] - without.pos_enu[jump], np.tile([15.0, -10.0, 5.0], (10, 1)),
                               atol=1e-6)
    np.testing.assert_array_equal(fixes.pos_enu[~jump], without.pos_enu[~jump])
    clean = ~jump
    east = error[clean, 0]
    lag1 = np.corrcoef(east[:-1], east[1:])[0, 1]
    assert lag1 == pytest.approx(math.exp(-1.0 / 60.0), abs=0.02)
    np.testing.assert_allclose(fixes.h_acc_m, 3.0)
    np.testing.assert_allclose(fixes.v_acc_m, 4.0)


def test_isa_pressure_and_height_are_inverse_and_standard():
    assert nv.pressure_at(0.0) == pytest.approx(101_325.0)
    assert nv.pressure_at(1000.0) == pytest.approx(89_874.6, abs=1.0)  # the ISA table
    heights = np.linspace(-400.0, 9000.0, 50)
    np.testing.assert_allclose(nv.height_at(nv.pressure_at(heights)), heights, atol=1e-6)


def test_barometer_noise_and_drifts(drive):
    quiet = nv.baro_samples(drive, nv.BaroModel(noise_pa=0.0, temperature_drift_c=0.0, weather_pa_per_sqrt_h=0.0))
    msl = quiet.truth_height_m - 47.0
    np.testing.assert_allclose(nv.height_at(quiet.pressure_pa), msl, atol=1e-6)
    assert len(quiet) == 1200 * 50
    noisy = nv.baro_samples(drive, nv.BaroModel(temperature_drift_c=0.0, weather_pa_per_sqrt_h=0.0), seed=2)
    height_noise = np.std(nv.height_at(noisy.pressure_pa) - msl)
    assert 0.08 < height_noise < 0.14  # 1.2 Pa at about 11 Pa/m near the ground
    warm = nv.baro_samples(drive, nv.BaroModel(noise_pa=0.0, weather_pa_per_sqrt_h=0.0))
    assert warm.temperature_c[-1] == pytest.approx(30.0)
    assert warm.pressure_pa[-1] - quiet.pressure_pa[-1] == pytest.approx(2.5)  # 0.5 Pa/K over 5 K


def test_a_foot_mounted_walk_stands_still_in_every_stance_and_stays_in_the_sensors_ranges():
    walk = nv.foot_walk(300.0, 100.0, seed=1)
    speed = np.linalg.norm(walk.vel_enu, axis=1)
    assert 0.5 < walk.rest.mean() < 0.62  # 10 s standing, then 55 % of each stride
    assert np.all(speed[walk.rest] == 0.0) and np.all(walk.gyr[walk.rest] == 0.0)
    # strides: runs of motion of 0.45-0.54 s, each about 1.4 m
    moving = ~walk.rest
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts, ends = edges[::2] + 1, edges[1::2] + 1
    horizontal = np.linalg.norm(walk.vel_enu[:, :2], axis=1)
    lengths = [np.sum(horizontal[a:b]) * walk.dt for a, b in zip(starts, ends)]
    assert len(lengths) > 200
    np.testing.assert_allclose(lengths, 1.4, rtol=1e-2)  # along the ground (a turning stride's chord is shorter)
    assert np.degrees(np.linalg.norm(walk.gyr, axis=1)).max() < 2000.0  # the MPU6050's range
    assert np.linalg.norm(walk.acc_lin, axis=1).max() < 6 * 9.81        # and within +-8 g with gravity
    assert speed.max() < 7.0 and walk.pos_enu[:, 2].max() < 0.13 and walk.pos_enu[:, 2].min() > -1e-3
    assert abs(walk.pos_enu[-1, 2]) < 1e-9  # back on the floor
    # laps of the rectangle: the same path each time, back at the start after each
    extent = walk.pos_enu.max(axis=0) - walk.pos_enu.min(axis=0)
    assert 8.0 < extent[0] < 12.0 and 18.0 < extent[1] < 22.0
    stride_ends = walk.pos_enu[ends]
    laps = len(nv._rectangle_headings((20.0, 10.0), 1.4))
    np.testing.assert_allclose(stride_ends[laps - 1], 0.0, atol=1e-4)  # a turn sampled differently: um
    np.testing.assert_allclose(stride_ends[2 * laps - 1], 0.0, atol=1e-4)


def test_a_handheld_walk_bobs_and_sways_and_pauses():
    walk = nv.handheld_walk(300.0, 100.0, seed=1)
    speed = np.linalg.norm(walk.vel_enu[:, :2], axis=1)
    assert speed.max() < 1.6 and 0.05 < walk.rest.mean() < 0.3
    assert np.all(walk.vel_enu[walk.rest] == 0.0) and np.all(walk.gyr[walk.rest] == 0.0)
    walking = speed > 1.0
    assert 0.015 < np.std(walk.pos_enu[walking, 2]) < 0.03  # the bob, 2 cm
    tilt = np.degrees(np.arccos(np.clip(Q.rotate(walk.quat, [0.0, 0.0, 1.0])[:, 2], -1, 1)))
    assert 1.0 < tilt[walking].max() < 5.0
    extent = walk.pos_enu.max(axis=0) - walk.pos_enu.min(axis=0)
    assert 14.0 < extent[0] < 16.5 and 29.0 < extent[1] < 31.5  # the 30 m x 15 m loop


def test_the_accelerometer_sample_is_the_specific_force_averaged_over_the_turning_interval():
    """Strapdown undoing the interval's mean rotation (exact for a constant rate) gets each
    interval's acceleration of a foot swinging at 400 deg/s back from error-free samples,
    to the accelerometer's quantisation; the end attitude alone (the attitude scenarios'
    sampling) would be off by up to metres per second squared."""
    walk = nv.foot_walk(60.0, 100.0, seed=3)
    suite = SensorSuite(gyro=GyroModel.ideal(), acc=AccModel(noise_std=0.0), mag=SensorSuite.default().mag,
                        saturate=False)
    imu = simulate(walk, suite, seed=1)
    r = Q.to_rotmat(walk.quat)
    phi = walk.gyr * walk.dt
    theta = np.maximum(np.linalg.norm(phi, axis=1), 1e-12)
    u = phi / theta[:, None]
    skew = np.zeros((len(u), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
    mean = (np.eye(3) + ((1 - np.cos(theta)) / theta)[:, None, None] * skew
            + (1 - np.sin(theta) / theta)[:, None, None] * skew @ skew)
    gravity = np.zeros((len(walk), 3))
    gravity[:, 2] = walk.gravity
    # the sample is M^T R_{k-1}^T f: f = R_{k-1} (M^T)^-1 sample
    body = np.linalg.solve(np.transpose(mean[1:], (0, 2, 1)), imu.acc[1:, :, None])[:, :, 0]
    acc = np.einsum("kij,kj->ki", r[:-1], body) - gravity[1:]
    assert np.abs(acc - walk.acc_lin[1:]).max() < 0.003  # half a count (1.2 mm/s^2) on each axis
    end_only = np.einsum("kij,kj->ki", r[1:], imu.acc[1:]) - gravity[1:]
    assert np.abs(end_only - walk.acc_lin[1:]).max() > 0.3


def test_a_drone_tilts_into_its_acceleration_so_its_accelerometer_reads_along_z():
    flight = nv.drone_flight(300.0, 100.0, seed=2)
    speed = np.linalg.norm(flight.vel_enu, axis=1)
    assert speed.max() <= 12.01 and np.linalg.norm(flight.acc_lin, axis=1).max() <= 4.01
    assert 15.0 < flight.pos_enu[:, 2].max() < 41.0 and flight.pos_enu[:, 2].min() > -1e-6
    assert np.abs(flight.pos_enu[:, :2]).max() < 300.0
    suite = SensorSuite(gyro=GyroModel.ideal(), acc=AccModel(noise_std=0.0), mag=SensorSuite.default().mag,
                        saturate=False)
    imu = simulate(flight, suite, seed=1)
    # a multirotor's thrust (all its specific force, air drag aside) is along its z axis
    assert np.abs(imu.acc[:, :2]).max() < 0.01
    tilt = np.degrees(np.arccos(np.clip(Q.rotate(flight.quat, [0.0, 0.0, 1.0])[:, 2], -1.0, 1.0)))
    assert 10.0 < tilt.max() < 30.0


def test_marker_fixes_are_where_the_body_is_within_their_accuracy():
    walk = nv.handheld_walk(600.0, 100.0, seed=4)
    markers = nv.marker_fixes(walk, every_s=60.0, accuracy_m=0.1, seed=2)
    np.testing.assert_array_equal(markers.index, np.arange(1, 10) * 6000)
    k = markers.index
    error = nv.local_offsets(markers.lat_deg, markers.lon_deg, markers.height_m, walk.lat_deg[k], walk.lon_deg[k],
                             walk.height_m[k])
    assert 0.02 < np.std(error) < 0.2 and np.abs(error).max() < 0.5
