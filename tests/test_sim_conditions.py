"""The simulator's rough conditions (imulink.sim.sensors: vibration, bias steps, shocks,
magnetic disturbances; imulink.sim.navigation: GNSS outliers, velocity blunders,
multipath episodes, cold start, stairs) each do what they say, a run without them is bit
for bit what it was before they existed, and the scenario suite (imulink.analysis.nav_scenarios)
measures what it says. No number of the nav filter is asserted here: the filter changes."""
from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from imulink import sim
from imulink.analysis import nav_scenarios as ns
from imulink.core.counts import DEFAULT_PROFILE
from imulink.sim import navigation as nv
from imulink.sim import quat as Q
from imulink.sim.sensors import (
    AccModel,
    GyroModel,
    MagModel,
    SensorSuite,
    Shock,
    Vibration,
    extra_field,
    norm_change,
    rotated_field,
)


def digest(*arrays, scale=None) -> str:
    """A short hash of arrays; floats first rounded to 1/scale (immune to last-bit noise)."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.asarray(a)
        if scale is not None and a.dtype.kind == "f":
            a = np.round(a * scale).astype(np.int64)
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


@pytest.fixture(scope="module")
def drive():
    """A car drive at 10 Hz: enough for fixes at 5 Hz, quick to make."""
    return nv.car_drive(1000.0, 10.0, seed=5)


def test_runs_without_the_conditions_are_what_they_were_before_them():
    """Digests of the outputs the simulator gave before the conditions existed."""
    r = sim.make_scenario("rests", 60.0, 100.0, seed=2)
    assert digest(r.gyr_counts, r.acc_counts, r.mag_counts) == "a5767520151f08f6"
    car = nv.car_drive(300.0, 100.0, seed=3)
    c = sim.simulate(car, nv.datasheet_sensors(100.0), seed=3)
    assert digest(c.gyr_counts, c.acc_counts, c.mag_counts) == "2464cc7a04db7cdb"
    models = {"d7981004eb980475": nv.GnssModel(),
              "20d10b14bda0876d": nv.GnssModel(rate_hz=5, correlated_h_m=2, correlated_v_m=3, latency_s=0.2,
                                               outages=((50, 80),), multipath=((100, 110, 15, -10, 5),),
                                               reported_multipath=True)}
    for expected, model in models.items():
        g = nv.gnss_fixes(car, model, seed=7)
        assert digest(g.index, g.pos_enu, g.vel_enu, g.h_acc_m, g.v_acc_m, g.t_arrival, scale=1e6) == expected
        assert not any(flag.any() for flag in g.flags.values())
    f = nv.foot_walk(120.0, 100.0, seed=1)
    assert digest(f.pos_enu, f.quat, scale=1e9) == "b6ad21297b5f2476"


def test_the_new_streams_leave_the_other_errors_as_they_were():
    traj = sim.random_motion(20.0, 200.0, seed=1)
    suite = SensorSuite(GyroModel.seed000(), AccModel(), MagModel(), saturate=False)
    plain = sim.simulate(traj, suite, seed=4)
    rough = sim.simulate(traj, suite, seed=4, vibration=Vibration(), shocks=[Shock(5.0, 30.0, None)])
    np.testing.assert_array_equal(rough.mag, plain.mag)
    np.testing.assert_array_equal(rough.gyro_bias_true, plain.gyro_bias_true)
    # what differs is the vibration and the shock, to the quantisation
    q = DEFAULT_PROFILE
    np.testing.assert_allclose(rough.gyr - plain.gyr, rough.vibration_gyr, atol=q.gyro_scale * 1.01)
    shock = Shock(5.0, 30.0, None).waveform(traj.t)
    added = rough.acc - plain.acc - rough.vibration_acc
    np.testing.assert_allclose(np.linalg.norm(added, axis=1), np.abs(shock), atol=2 * q.acc_scale)


def test_vibration_has_its_rms_and_band():
    t = np.arange(60_000) / 1000.0  # 1 kHz: nothing aliases
    v = Vibration(orders=(1.0,), order_rms=(1.0,), freq_min_hz=20.0, freq_max_hz=45.0)
    acc, gyr = v.sample(t, np.random.default_rng(3))
    assert math.sqrt(np.mean(np.sum(acc**2, axis=1))) == pytest.approx(0.7, rel=0.15)
    assert math.degrees(math.sqrt(np.mean(np.sum(gyr**2, axis=1)))) == pytest.approx(2.0, rel=0.15)
    assert np.all(np.abs(acc.mean(axis=0)) < 0.02)  # no rectification of its own
    rms = np.sqrt(np.mean(acc**2, axis=0))
    assert rms[2] > 1.5 * rms[0] and rms[2] > 1.5 * rms[1]  # a car's engine: mostly vertical
    freq = np.fft.rfftfreq(len(t), 1e-3)
    power = np.abs(np.fft.rfft(acc, axis=0)) ** 2
    in_band = (freq >= 19.0) & (freq <= 46.0)
    assert power[in_band].sum() / power.sum() > 0.95
    f0 = v.frequency(len(t), 1e-3, np.random.default_rng(4))
    assert f0.min() >= 20.0 and f0.max() <= 45.0 and f0.max() - f0.min() > 5.0  # it wanders, within the band
    # a 2nd order of 40-90 Hz read at 100 Hz aliases into 10-50 Hz, and nothing lands near 0 Hz
    acc, _ = Vibration(orders=(2.0,), order_rms=(1.0,)).sample(np.arange(60_000) / 100.0, np.random.default_rng(5))
    freq = np.fft.rfftfreq(60_000, 0.01)
    power = np.abs(np.fft.rfft(acc[:, 2])) ** 2
    assert power[(freq >= 9.0) & (freq <= 50.0)].sum() / power.sum() > 0.95
    assert power[freq < 5.0].sum() / power.sum() < 0.01


def test_coherent_vibration_moves_rate_and_force_together():
    t = np.arange(20_000) / 1000.0
    acc, gyr = Vibration(coherent=True).sample(t, np.random.default_rng(1))
    assert np.corrcoef(acc[:, 2], gyr[:, 0])[0, 1] > 0.999  # the same phase: sculling
    assert np.mean(acc[:, 2] * gyr[:, 0]) > 0.5 * np.std(acc[:, 2]) * np.std(gyr[:, 0])
    acc, gyr = Vibration(coherent=False).sample(t, np.random.default_rng(1))
    assert abs(np.corrcoef(acc[:, 2], gyr[:, 0])[0, 1]) < 0.3
    # 90 deg between two gyro axes: coning (the product averages to nothing, the cross term does not)
    _, gyr = Vibration(coherent=True, gyro_phase_deg=(0.0, 90.0, 0.0), orders=(1.0,),
                       order_rms=(1.0,)).sample(t, np.random.default_rng(2))
    assert abs(np.corrcoef(gyr[:, 0], gyr[:, 1])[0, 1]) < 0.1


def test_vibration_windows_switch_it_on_and_off():
    t = np.arange(4000) / 100.0
    acc, gyr = Vibration(windows=((10.0, 20.0),)).sample(t, np.random.default_rng(0))
    assert np.all(acc[(t < 10.0) | (t >= 20.0)] == 0.0) and np.all(gyr[t < 10.0] == 0.0)
    assert np.std(acc[(t >= 11.0) & (t < 19.0)]) > 0.1


def test_bias_steps_are_in_the_readings_and_the_truth():
    traj = sim.static(20.0, 100.0)
    step = np.radians([0.0, 0.0, 0.5])
    suite = SensorSuite(GyroModel(arw=0.0, bias_instability=0.0, rrw=0.0, bias=np.radians([0.1, 0.2, 0.3]),
                                  bias_steps=[(10.0, step)]),
                        AccModel(noise_std=0.0, bias=(0.1, 0.0, 0.0), bias_steps=[(12.0, (0.0, 0.3, 0.0))]),
                        MagModel(), saturate=False)
    res = sim.simulate(traj, suite, seed=1)
    before, after = res.t < 10.0, res.t >= 10.0
    np.testing.assert_allclose(res.gyro_bias_true[after] - res.gyro_bias_true[0], np.tile(step, (after.sum(), 1)),
                               atol=1e-15)
    np.testing.assert_allclose(res.gyro_bias_true[before], np.radians([[0.1, 0.2, 0.3]] * int(before.sum())))
    jump = res.gyr[after].mean(axis=0) - res.gyr[before].mean(axis=0)
    np.testing.assert_allclose(jump, step, atol=DEFAULT_PROFILE.gyro_scale)
    np.testing.assert_allclose(res.acc_bias_true[res.t >= 12.0], [[0.1, 0.3, 0.0]] * int((res.t >= 12.0).sum()))
    np.testing.assert_allclose(res.acc_bias_true[res.t < 12.0], [[0.1, 0.0, 0.0]] * int((res.t < 12.0).sum()))


def test_a_gyro_scale_error_reads_the_rate_through_i_plus_m():
    traj = sim.random_motion(5.0, 100.0, seed=3, max_rate_dps=300.0)
    error = np.array([[0.02, 0.01, -0.005], [0.0, -0.015, 0.008], [0.003, -0.01, 0.01]])
    gyro = GyroModel.ideal()
    gyro.scale_error = error
    res = sim.simulate(traj, SensorSuite(gyro, AccModel(), MagModel(), saturate=False), seed=1)
    np.testing.assert_allclose(res.gyr, traj.gyr @ (np.eye(3) + error).T, atol=2e-3)  # 2e-3: a count of the range
    plain = sim.simulate(traj, SensorSuite(GyroModel.ideal(), AccModel(), MagModel(), saturate=False), seed=1)
    np.testing.assert_array_equal(plain.acc, res.acc)  # the rest unchanged


def test_a_shock_along_a_direction_clips_and_otherwise_leaves_no_velocity():
    traj = sim.static(4.0, 100.0)
    calm = sim.simulate(traj, seed=2)
    limit = DEFAULT_PROFILE.ranges_si()["acc_m_s2"]
    direction = np.array([0.0, -0.4, 1.0])
    res = sim.simulate(traj, seed=2, shocks=[Shock(2.0, 12.0 * 9.80665, direction, duration_s=0.02)])
    assert res.saturated["acc"] > 0
    assert np.abs(res.acc).max() <= limit + 1e-9
    peak = np.argmin(np.abs(res.t - 2.0))
    hit = Q.rotate(res.quat_true[peak], res.acc[peak] - calm.acc[peak])  # in the earth frame
    assert np.any(np.isclose(np.abs(res.acc[peak]), limit, atol=1e-6))
    body = res.acc[peak] - calm.acc[peak]
    assert np.dot(body, direction) / (np.linalg.norm(body) * np.linalg.norm(direction)) > 0.95
    assert np.linalg.norm(hit) > 5.0 * 9.80665
    # away from the shock (beyond its side lobes) nothing changes
    far = np.abs(res.t - 2.0) > 0.1
    np.testing.assert_array_equal(res.acc[far], calm.acc[far])
    # unclipped and sampled finely, a shock changes neither the velocity nor the position
    fine = sim.static(2.0, 2000.0)
    suite = SensorSuite(GyroModel.ideal(), AccModel(noise_std=0.0), MagModel(), saturate=False)
    base = sim.simulate(fine, suite, seed=3)
    knock = sim.simulate(fine, suite, seed=3, shocks=[Shock(1.0, 40.0, (1.0, 0.0, 0.0), duration_s=0.01)])
    pulse = (knock.acc - base.acc)[:, 0]
    assert pulse.max() == pytest.approx(40.0, abs=0.05) and pulse.min() == pytest.approx(-0.446 * 40.0, abs=0.1)
    assert abs(np.sum(pulse) / 2000.0) < 1e-4 and abs(np.sum(np.cumsum(pulse)) / 2000.0**2) < 1e-5
    shape = Shock(1.0, 40.0, duration_s=0.01).waveform(fine.t)
    crossings = fine.t[np.flatnonzero(shape[:-1] * shape[1:] < 0)]
    assert crossings[1] - crossings[0] == pytest.approx(0.01, abs=1e-3)  # the main lobe's width


def test_magnetic_disturbances_change_the_norm_or_the_dip_as_asked():
    mag = MagModel()
    traj = sim.turntable(40.0, 100.0, settle_s=2.0)

    def field_enu(model):
        res = sim.simulate(traj, SensorSuite(GyroModel.ideal(), AccModel(), model), seed=1)
        return Q.rotate(res.quat_true, res.mag), res.t

    def dip(b):
        return np.degrees(np.arctan2(-b[..., 2], np.hypot(b[..., 0], b[..., 1])))

    start, end = extra_field(10.0, 20.0, 30.0, (1.0, 2.0, 0.5))[:2]
    assert (start, end) == (10.0, 20.0)
    assert np.linalg.norm(extra_field(10.0, 20.0, 30.0, (1.0, 2.0, 0.5))[2]) == pytest.approx(30.0)
    for disturbance, norm, dip_deg in ((norm_change(mag, 10.0, 30.0, 20.0), 69.0, 67.0),
                                       (rotated_field(mag, 10.0, 30.0, dip_change_deg=-15.0), 49.0, 52.0),
                                       (rotated_field(mag, 10.0, 30.0, declination_change_deg=40.0), 49.0, 67.0)):
        b, t = field_enu(MagModel(disturbances=[disturbance]))
        inside = (t >= 11.0) & (t < 29.0)
        mean = b[inside].mean(axis=0)
        assert np.linalg.norm(mean) == pytest.approx(norm, abs=0.1)
        assert dip(mean) == pytest.approx(dip_deg, abs=0.2)
        outside = (t < 10.0) | (t >= 30.0)
        assert np.linalg.norm(b[outside].mean(axis=0)) == pytest.approx(49.0, abs=0.1)
    b, t = field_enu(MagModel(disturbances=[rotated_field(mag, 10.0, 30.0, declination_change_deg=40.0)]))
    inside = (t >= 11.0) & (t < 29.0)
    heading = np.degrees(np.arctan2(-b[inside, 0], b[inside, 1])).mean()  # anticlockwise from north
    assert heading == pytest.approx(40.0, abs=0.5)


def test_gnss_outliers_are_the_share_and_size_asked_and_not_reported(drive):
    model = nv.GnssModel(rate_hz=5.0, outages=((100.0, 160.0),), outlier_fraction=0.02, outlier_m=(20.0, 50.0),
                         outlier_vertical_m=(5.0, 10.0))
    clean = nv.gnss_fixes(drive, nv.GnssModel(rate_hz=5.0, outages=((100.0, 160.0),)), seed=8)
    fixes = nv.gnss_fixes(drive, model, seed=8)
    bad = fixes.flags["outlier"]
    assert bad.sum() == round(0.02 * len(fixes)) == 94
    off = fixes.pos_enu - clean.pos_enu
    horizontal = np.hypot(off[bad, 0], off[bad, 1])
    assert horizontal.min() >= 20.0 and horizontal.max() <= 50.0 and horizontal.max() - horizontal.min() > 20.0
    assert np.all((np.abs(off[bad, 2]) >= 5.0) & (np.abs(off[bad, 2]) <= 10.0))
    angles = np.arctan2(off[bad, 0], off[bad, 1])
    assert np.abs(np.mean(np.exp(1j * angles))) < 0.3  # random directions
    np.testing.assert_array_equal(fixes.pos_enu[~bad], clean.pos_enu[~bad])
    np.testing.assert_array_equal(fixes.h_acc_m, clean.h_acc_m)
    np.testing.assert_array_equal(fixes.vel_enu, clean.vel_enu)
    # the geodetic fix carries the same error
    k = fixes.index[bad]
    local = nv.local_offsets(fixes.lat_deg[bad], fixes.lon_deg[bad], fixes.height_m[bad], drive.lat_deg[k],
                             drive.lon_deg[k], drive.height_m[k])
    np.testing.assert_allclose(local, fixes.pos_enu[bad] - fixes.truth_pos_enu[bad], atol=1e-6)


def test_a_velocity_outlier_is_on_the_fix_asked(drive):
    error = (20.0, -22.0, 1.0)
    clean = nv.gnss_fixes(drive, nv.GnssModel(), seed=2)
    fixes = nv.gnss_fixes(drive, nv.GnssModel(velocity_outliers=((300.4, error),)), seed=2)
    flagged = np.flatnonzero(fixes.flags["velocity_outlier"])
    assert len(flagged) == 1 and fixes.t_valid[flagged[0]] == pytest.approx(301.0)
    np.testing.assert_allclose(fixes.vel_enu[flagged[0]] - clean.vel_enu[flagged[0]], error, atol=1e-12)
    others = np.ones(len(fixes), bool)
    others[flagged] = False
    np.testing.assert_array_equal(fixes.vel_enu[others], clean.vel_enu[others])
    np.testing.assert_array_equal(fixes.pos_enu, clean.pos_enu)
    np.testing.assert_array_equal(fixes.s_acc_m_s, clean.s_acc_m_s)


def test_a_multipath_episode_wanders_within_its_amplitude_and_ramps_in_and_out(drive):
    episodes = ((200.0, 260.0, 4.0), (500.0, 700.0, 4.0))
    clean = nv.gnss_fixes(drive, nv.GnssModel(rate_hz=5.0), seed=9)
    fixes = nv.gnss_fixes(drive, nv.GnssModel(rate_hz=5.0, multipath_episodes=episodes, multipath_tau_s=10.0,
                                              multipath_ramp_s=5.0), seed=9)
    bias = fixes.pos_enu - clean.pos_enu
    t = fixes.t_valid
    inside = np.zeros(len(t), bool)
    for start, end, _ in episodes:
        inside |= (t >= start) & (t < end)
    assert np.all(bias[~inside] == 0.0)
    size = np.hypot(bias[:, 0], bias[:, 1])
    assert size.max() <= 4.0 and np.abs(bias[:, 2]).max() <= 4.0
    assert size[inside].max() > 2.0 and math.sqrt(np.mean(size[inside] ** 2)) > 1.0  # metres, not centimetres
    # ramped: small in its first and last second, the ramps' raised cosine bounding it
    for start, end, _ in episodes:
        edge = ((t >= start) & (t < start + 1.0)) | ((t >= end - 1.0) & (t < end))
        assert size[edge].max() <= 4.0 * (0.5 - 0.5 * math.cos(math.pi / 5.0)) + 1e-9
    # slowly wandering: neighbouring fixes (0.2 s apart) nearly the same, a minute apart not
    middle = (t >= 520.0) & (t < 680.0)
    east = bias[middle, 0]
    assert np.corrcoef(east[:-1], east[1:])[0, 1] > 0.95
    assert np.std(east) > 0.5
    assert fixes.flags["multipath"][inside].mean() > 0.9 and not fixes.flags["multipath"][~inside].any()
    np.testing.assert_array_equal(fixes.h_acc_m, clean.h_acc_m)  # the receiver does not see it
    np.testing.assert_array_equal(fixes.v_acc_m, clean.v_acc_m)


def test_a_cold_start_is_off_by_the_offset_then_converges(drive):
    offset = (800.0, -750.0, 30.0)
    clean = nv.gnss_fixes(drive, nv.GnssModel(outages=((0.0, 3.0),)), seed=1)
    fixes = nv.gnss_fixes(drive, nv.GnssModel(outages=((0.0, 3.0),), cold_start_offset_m=offset, cold_start_fixes=1,
                                              cold_start_acc_m=(3.0, 4.0)), seed=1)
    off = fixes.pos_enu - clean.pos_enu
    assert fixes.t_valid[0] == 3.0  # the first fix the receiver makes
    np.testing.assert_allclose(off[0], offset, atol=1e-9)
    assert np.all(off[1:] == 0.0)
    assert (fixes.h_acc_m[0], fixes.v_acc_m[0]) == (3.0, 4.0) and np.all(fixes.h_acc_m[1:] == clean.h_acc_m[1:])
    assert fixes.flags["cold_start"].sum() == 1
    converging = nv.gnss_fixes(drive, nv.GnssModel(cold_start_offset_m=offset, cold_start_fixes=30,
                                                   cold_start_tau_s=10.0), seed=1)
    off = converging.pos_enu - nv.gnss_fixes(drive, nv.GnssModel(), seed=1).pos_enu
    size = np.linalg.norm(off, axis=1)
    assert size[0] == pytest.approx(np.linalg.norm(offset))
    assert size[10] == pytest.approx(np.linalg.norm(offset) * math.exp(-1.0), rel=1e-9)
    assert np.all(np.diff(size[:30]) < 0) and np.all(size[30:] == 0.0)
    np.testing.assert_array_equal(converging.h_acc_m, 2.5)  # the usual accuracy when none is given


def test_stairs_climb_their_steps_and_the_foot_lands_flat():
    stairs = ((30.0, 6, 0.17), (60.0, 6, -0.17))
    walk = nv.foot_walk(100.0, 100.0, seed=3, stairs=stairs)
    height = walk.pos_enu[:, 2]
    rest = walk.rest
    levels = np.unique(np.round(height[rest], 9))
    np.testing.assert_allclose(levels, 0.34 * np.arange(7), atol=1e-6)  # two 0.17 m steps a stride
    assert abs(height[-1]) < 1e-9 and height.max() < 2.04 + 0.13
    assert np.all(walk.vel_enu[rest] == 0.0)
    plain = nv.foot_walk(100.0, 100.0, seed=3)
    np.testing.assert_array_equal(walk.pos_enu[walk.t < 30.0], plain.pos_enu[plain.t < 30.0])
    # a stair stride goes straight on, two treads
    moving = ~rest
    edges = np.flatnonzero(np.diff(moving.astype(int)))
    starts, ends = edges[::2] + 1, edges[1::2] + 1
    rises = [height[b] - height[a - 1] for a, b in zip(starts, ends)]
    runs = [np.linalg.norm(walk.pos_enu[b, :2] - walk.pos_enu[a - 1, :2]) for a, b in zip(starts, ends)]
    up = np.isclose(rises, 0.34, atol=1e-6)
    assert up.sum() == 6 and np.isclose(rises, -0.34, atol=1e-6).sum() == 6
    np.testing.assert_allclose(np.array(runs)[up], 2 * nv.STAIR_TREAD_M, atol=1e-3)


def test_heel_strikes_are_where_the_foot_lands():
    walk = nv.foot_walk(40.0, 100.0, seed=2)
    strikes = ns.heel_strikes(walk)
    assert len(strikes) > 20
    assert np.all(walk.rest[strikes]) and not np.any(walk.rest[strikes - 1])


def truth_result(scenario: ns.Scenario):
    """A NavResult that is the truth itself, every fix accepted (its counters, whatever the
    filter counts, zero)."""
    import dataclasses

    from imulink.analysis.nav import STATES, NavResult

    traj, inp = scenario.traj, scenario.inp
    given = dict(start=0, timestamp_us=inp.timestamp_us, lat_deg=traj.lat_deg, lon_deg=traj.lon_deg,
                 height_m=traj.height_m, vel_enu=traj.vel_enu, quat=traj.quat, sigma=np.zeros((len(traj), STATES)),
                 fix_index=inp.fix_index[1:], fix_accepted=np.ones(len(inp.fix_index) - 1, bool))
    counters = {f.name: 0 for f in dataclasses.fields(NavResult) if f.name not in given}
    return NavResult(**given, **counters)


def test_evaluate_and_gnss_alone_measure_what_they_say():
    scenario = ns.build("car_velocity_outlier", 1)
    metrics = ns.evaluate(scenario, truth_result(scenario))
    assert metrics["horizontal_rmse_m"] < 1e-6 and metrics["minute_after_horizontal_max_m"] < 1e-6
    assert metrics["good_fixes_rejected_after"] == 0 and metrics["outlier_accepted"] == 1
    assert all(scenario.targets[name] >= metrics[name] for name in scenario.targets)
    alone = ns.gnss_alone(scenario)
    f = scenario.fixes
    late = f.t_valid >= 60.0
    error = np.hypot(*(f.pos_enu - f.truth_pos_enu)[late, :2].T)
    assert alone["horizontal_rmse_m"] == pytest.approx(math.sqrt(np.mean(error**2)))
    assert alone["minute_after_velocity_max_m_s"] == pytest.approx(30.0, abs=1.0)  # the blunder itself
    assert alone["good_fixes_rejected_after"] is None
    # the clean twin: the same truth and sensors, no blunder
    assert scenario.clean_imu is scenario.imu and not scenario.clean_fixes.flags["velocity_outlier"].any()
    np.testing.assert_array_equal(scenario.clean.fix_index, scenario.inp.fix_index)


def test_gnss_alone_holds_the_last_fix_through_an_outage():
    scenario = ns.build("handheld_rough", 0)
    start, end = scenario.events["outage_s"]
    alone = ns.gnss_alone(scenario)
    t = scenario.traj.t
    inside = (t >= start) & (t < end)
    before = scenario.fixes.index[scenario.fixes.t_valid < start][-1]
    held = scenario.fixes.pos_enu[scenario.fixes.index == before][0] - scenario.traj.pos_enu[inside]
    assert alone["outage_horizontal_mean_m"] == pytest.approx(np.mean(np.hypot(held[:, 0], held[:, 1])))
    assert ns.targets_met(scenario, {"horizontal_rmse_m": 1.0, "outage_horizontal_mean_m": math.nan}) == {
        "horizontal_rmse_m": True, "outage_horizontal_mean_m": False}


@pytest.mark.parametrize("name", sorted(ns.SCENARIOS))
def test_every_scenario_runs_in_the_filter(name):
    outcome = ns.run_scenario(name, 0, "fixed")
    scenario = outcome["scenario"]
    assert set(outcome["metrics"]) == set(scenario.metrics) == set(outcome["clean"]) == set(outcome["gnss"])
    assert set(scenario.targets) <= set(scenario.metrics) and scenario.targets
    assert all(math.isfinite(v) for v in outcome["metrics"].values())
    assert set(outcome["met"]) == set(scenario.targets)
    for windows in scenario.windows.values():
        assert all(0.0 <= a < b <= scenario.duration_s + 1e-9 for a, b in windows)
    # the twin is the same run without the conditions
    assert len(scenario.clean) == len(scenario.inp)
    np.testing.assert_array_equal(scenario.clean_imu.quat_true, scenario.imu.quat_true)


def test_unknown_scenario():
    with pytest.raises(KeyError, match="unknown scenario"):
        ns.build("car_smooth", 0)
