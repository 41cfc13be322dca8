"""Tests of imulink.sim: quaternion helpers, truth trajectories and sensor models."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imulink import sim
from imulink.core.counts import DEFAULT_PROFILE, STANDARD_GRAVITY
from imulink.sim import quat as Q
from imulink.sim.sensors import AccModel, GyroModel, MagModel, SensorSuite


def to_scipy(q):
    """w-first (N,4) -> scipy Rotation (scalar-last)."""
    q = np.asarray(q)
    return Rotation.from_quat(np.concatenate([q[..., 1:], q[..., :1]], axis=-1))


def from_scipy(r):
    x = r.as_quat()
    return np.concatenate([x[..., 3:], x[..., :3]], axis=-1)


def same_rotation(q1, q2, atol=1e-12):
    """True when q1 == +-q2 element-wise."""
    return np.allclose(q1, q2, atol=atol) or np.allclose(q1, -np.asarray(q2), atol=atol)


# --------------------------------------------------------------------------- quaternions


def test_rotate_and_inverse_compose_to_identity():
    rng = np.random.default_rng(1)
    q = Q.normalize(rng.standard_normal((50, 4)))
    v = rng.standard_normal((50, 3))
    np.testing.assert_allclose(Q.rotate_inverse(q, Q.rotate(q, v)), v, atol=1e-12)
    np.testing.assert_allclose(Q.rotate(Q.conjugate(q), Q.rotate(q, v)), v, atol=1e-12)
    ident = Q.multiply(q, Q.conjugate(q))
    np.testing.assert_allclose(ident, np.tile(Q.IDENTITY, (50, 1)), atol=1e-12)


def test_rotate_and_rotmat_match_scipy():
    rng = np.random.default_rng(2)
    q = Q.normalize(rng.standard_normal((20, 4)))
    v = rng.standard_normal((20, 3))
    r = to_scipy(q)
    np.testing.assert_allclose(Q.rotate(q, v), r.apply(v), atol=1e-12)
    np.testing.assert_allclose(Q.to_rotmat(q), r.as_matrix(), atol=1e-12)
    # Hamilton product: (p ⊗ q) rotates like R_p R_q.
    p = Q.normalize(rng.standard_normal((20, 4)))
    np.testing.assert_allclose(Q.to_rotmat(Q.multiply(p, q)), (to_scipy(p) * r).as_matrix(), atol=1e-12)


def test_from_rotvec_known_axis_angle():
    # 90 deg about z: [cos 45, 0, 0, sin 45].
    np.testing.assert_allclose(Q.from_rotvec([0, 0, np.pi / 2]),
                               [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(Q.from_rotvec([0.0, 0.0, 0.0]), Q.IDENTITY)
    rng = np.random.default_rng(3)
    rv = rng.standard_normal((30, 3)) * np.array([[1e-9], [1.0], [3.0]]).repeat(10, axis=0)
    expected = from_scipy(Rotation.from_rotvec(rv))
    got = Q.from_rotvec(rv)
    for a, b in zip(got, expected):
        assert same_rotation(a, b, atol=1e-14)
    axis, angle = np.array([1.0, -2.0, 0.5]), 0.7
    assert same_rotation(Q.from_axis_angle(axis, angle),
                         from_scipy(Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle)))


def test_from_zyx_and_angle_between():
    roll, pitch, yaw = np.deg2rad([3.0, -2.0, 30.0])
    expected = from_scipy(Rotation.from_euler("ZYX", [yaw, pitch, roll]))
    assert same_rotation(Q.from_zyx(roll, pitch, yaw), expected)
    q1 = Q.from_zyx(0.1, 0.2, 0.3)
    dq = Q.from_rotvec([1e-7, -2e-7, 0.5e-7])
    q2 = Q.multiply(q1, dq)
    assert Q.angle_between(q1, q2) == pytest.approx(np.linalg.norm([1e-7, -2e-7, 0.5e-7]), rel=1e-6)
    assert Q.angle_between(q1, -q2) == pytest.approx(Q.angle_between(q1, q2))
    assert Q.angle_between(Q.IDENTITY, Q.from_rotvec([0, 2.5, 0])) == pytest.approx(2.5)


def test_cumulative_product_matches_loop():
    rng = np.random.default_rng(4)
    steps = Q.from_rotvec(rng.standard_normal((37, 3)))
    expected = [steps[0]]
    for s in steps[1:]:
        expected.append(Q.multiply(expected[-1], s))
    np.testing.assert_allclose(Q.cumulative_product(steps), np.array(expected), atol=1e-13)


# --------------------------------------------------------------------------- trajectories


def test_truth_is_integral_of_gyro_samples():
    traj = sim.random_motion(60.0, 100.0, seed=7)
    dt = traj.dt
    assert traj.quat.shape == (6000, 4) and traj.gyr.shape == (6000, 3)
    # Independent re-integration with scipy: R[k] = R[k-1] * exp(gyr[k] dt) (sample k
    # covers the interval that ends at t_k).
    steps = Rotation.from_rotvec(traj.gyr * dt)
    r = to_scipy(traj.quat[0])
    err = 0.0
    for k in range(1, len(traj.t)):
        r = r * steps[k]
        err = max(err, (to_scipy(traj.quat[k]).inv() * r).magnitude())
    assert err < 1e-9
    # The motion is substantial and soft-limited.
    rate_dps = np.rad2deg(np.linalg.norm(traj.gyr, axis=1))
    assert 30.0 < rate_dps.mean() and rate_dps.max() < 200.0
    assert not traj.rest.any()
    np.testing.assert_allclose(traj.acc_lin.std(axis=0), 1.0, rtol=0.5)


def test_static_trajectory():
    traj = sim.static(5.0, 50.0)
    assert traj.rest.all() and not traj.gyr.any() and not traj.acc_lin.any()
    assert np.allclose(traj.quat, sim.DEFAULT_INITIAL)
    q = Q.from_zyx(0.3, 0.2, -1.0)
    assert np.allclose(sim.static(1.0, 10.0, initial=q).quat, q)


def test_turntable_heading_changes_by_rate_times_time():
    rate_dps, settle = 10.0, 10.0
    traj = sim.turntable(60.0, 100.0, rate_dps=rate_dps, settle_s=settle)
    yaw = np.unwrap(to_scipy(traj.quat).as_euler("ZYX")[:, 0])
    ks = np.searchsorted(traj.t, settle)
    assert traj.rest[:ks].all() and not traj.rest[ks:].any()
    # Sample ks is the first moving one: it covers (t_ks-1, t_ks].
    np.testing.assert_allclose(yaw[:ks], yaw[0], atol=1e-12)
    np.testing.assert_allclose(np.rad2deg(yaw[ks - 1:] - yaw[ks - 1]), rate_dps * (traj.t[ks - 1:] - traj.t[ks - 1]),
                               atol=1e-8)
    # Roll and pitch relative to the vertical do not change: the up axis in body is fixed.
    up_body = Q.rotate_inverse(traj.quat, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(up_body, np.broadcast_to(up_body[0], up_body.shape), atol=1e-10)


def test_motion_with_rests():
    traj = sim.motion_with_rests(120.0, 100.0, seed=3)
    assert 0.1 < traj.rest.mean() < 0.7
    assert traj.rest[0]  # starts with a rest
    assert not traj.gyr[traj.rest].any() and not traj.acc_lin[traj.rest].any()
    assert np.all(np.linalg.norm(traj.gyr[~traj.rest], axis=1) > 0)
    # Attitude constant inside each rest (consecutive rest samples).
    both = traj.rest[1:] & traj.rest[:-1]
    np.testing.assert_allclose(Q.angle_between(traj.quat[1:][both], traj.quat[:-1][both]), 0.0, atol=1e-12)
    # Smooth transitions: no large jump of the rate between samples (0.5 s ramps).
    jump_dps = np.rad2deg(np.linalg.norm(np.diff(traj.gyr, axis=0), axis=1))
    assert jump_dps.max() < 20.0
    # Deterministic.
    again = sim.motion_with_rests(120.0, 100.0, seed=3)
    np.testing.assert_array_equal(traj.quat, again.quat)


def _displacement(traj) -> tuple[float, float]:
    """Largest speed (m/s) and distance from the start (m), the linear acceleration
    integrated from rest."""
    velocity = np.cumsum(traj.acc_lin, axis=0) * traj.dt
    position = np.cumsum(velocity, axis=0) * traj.dt
    return float(np.abs(velocity).max()), float(np.abs(position).max())


def test_a_bounded_translation_stays_within_reach_and_comes_back():
    """translation="bounded": the acceleration of a position within reach (a hand's), back
    at the rest spot after each move; the sustained model's velocity wanders without bound."""
    bounded = sim.motion_with_rests(300.0, 100.0, seed=0, translation="bounded")
    sustained = sim.motion_with_rests(300.0, 100.0, seed=0)
    speed, distance = _displacement(bounded)
    assert speed < 1.0 and distance < 0.3
    assert min(_displacement(sustained)) > 5.0
    assert not bounded.acc_lin[bounded.rest].any()
    moving = ~bounded.rest
    np.testing.assert_allclose(bounded.acc_lin[moving].std(axis=0), 1.0, rtol=0.2)
    # Same rotation stream: only the translation differs.
    np.testing.assert_array_equal(bounded.quat, sustained.quat)


def test_a_bounded_translation_has_almost_nothing_a_low_pass_keeps():
    """Below 0.15 Hz (what a 3 s low-pass keeps) the bounded model holds a few mm/s^2 where
    the sustained one holds a third of its total (tools/eval_translation.py)."""
    def low_share(traj):
        spectrum = np.abs(np.fft.rfft(traj.acc_lin[:, :2], axis=0)) ** 2
        freq = np.fft.rfftfreq(len(traj.t), traj.dt)
        return np.sqrt(spectrum[freq < 0.15].sum() / spectrum.sum())
    bounded = sim.random_motion(300.0, 100.0, seed=1, accel_std=3.0, translation="bounded")
    sustained = sim.random_motion(300.0, 100.0, seed=1, accel_std=3.0)
    assert low_share(bounded) < 0.02 < 0.2 < low_share(sustained)


def test_an_unknown_translation_is_refused():
    with pytest.raises(ValueError, match="translation"):
        sim.random_motion(1.0, 100.0, translation="wobbly")


# --------------------------------------------------------------------------- sensors


def test_seed000_gyro_values():
    g = GyroModel.seed000()
    np.testing.assert_allclose(np.rad2deg(g.bias_instability) * 3600, [39.8887, 36.4465, 34.5215])
    np.testing.assert_allclose(np.rad2deg(g.arw) * 60, [3.3197, 2.6794, 2.885])
    np.testing.assert_allclose(np.rad2deg(g.rrw) * 3600 * 60, [520.5, 598.05, 471.84])
    ideal = GyroModel.ideal()
    white, bias = ideal.sample(100, 0.01, np.random.default_rng(0))
    assert not white.any() and not bias.any()


def test_static_accelerometer_and_magnetometer():
    traj = sim.static(120.0, 100.0)
    res = sim.simulate(traj, seed=1)
    expected_acc = Q.rotate_inverse(traj.quat[0], [0.0, 0.0, STANDARD_GRAVITY])
    # noise 0.02 m/s^2 / sqrt(12000) ~ 2e-4; quantisation is dithered by the noise.
    np.testing.assert_allclose(res.acc.mean(axis=0), expected_acc, atol=2e-3)
    mag_norm = np.linalg.norm(res.mag, axis=1)
    assert mag_norm.mean() == pytest.approx(49.0, abs=0.1)
    expected_mag = Q.rotate_inverse(traj.quat[0], res.earth_field_uT)
    np.testing.assert_allclose(res.mag.mean(axis=0), expected_mag, atol=0.05)
    np.testing.assert_allclose(res.earth_field_uT,
                               49.0 * np.array([0, np.cos(np.deg2rad(67)), -np.sin(np.deg2rad(67))]))
    # Default gyro at rest reads its true bias (white noise averages out) ...
    np.testing.assert_allclose(res.gyr.mean(axis=0), res.gyro_bias_true.mean(axis=0), atol=4e-4)
    # ... which is the (0.2, -0.3, 0.1) deg/s turn-on bias plus slow drifts (RRW ~0.03 deg/s
    # after 120 s, Gauss-Markov ~0.01 deg/s).
    np.testing.assert_allclose(np.rad2deg(res.gyro_bias_true[0]), [0.2, -0.3, 0.1], atol=0.05)
    np.testing.assert_allclose(np.rad2deg(res.gyr.mean(axis=0)), [0.2, -0.3, 0.1], atol=0.15)


def test_readings_are_quantised_counts():
    res = sim.make_scenario("random", 20.0, 100.0, seed=2)
    p = res.profile
    for si, counts, scale in ((res.gyr, res.gyr_counts, p.gyro_scale),
                              (res.acc, res.acc_counts, p.acc_scale),
                              (res.mag, res.mag_counts, p.mag_scale)):
        assert counts.dtype == np.int16 and counts.shape == (2000, 3)
        np.testing.assert_array_equal(si, counts * scale)
    assert res.saturated == {"gyr": 0, "acc": 0, "mag": 0}


def test_arw_noise_std():
    arw = GyroModel.seed000().arw
    suite = SensorSuite(GyroModel(arw=arw, bias_instability=0.0, rrw=0.0), AccModel(), MagModel())
    rate = 100.0
    res = sim.simulate(sim.static(600.0, rate), suite, seed=4)
    np.testing.assert_allclose(res.gyr.std(axis=0), arw * np.sqrt(rate), rtol=0.05)
    assert not res.gyro_bias_true.any()


def test_rrw_bias_variance_grows_linearly():
    rrw = GyroModel.seed000().rrw
    model = GyroModel(arw=0.0, bias_instability=0.0, rrw=rrw)
    dt, n, runs = 0.1, 1001, 200
    finals = []
    for seed in range(runs):
        white, bias = model.sample(n, dt, np.random.default_rng(seed))
        assert not white.any()
        finals.append(bias[[0, n // 2, n - 1]])
    finals = np.array(finals)  # (runs, 3 times, 3 axes)
    assert not finals[:, 0].any()  # the random walk starts at zero
    for idx, t in ((1, (n // 2) * dt), (2, (n - 1) * dt)):
        ratio = (finals[:, idx] ** 2).mean(axis=0) / (rrw**2 * t)
        # 200 runs: relative std of a variance estimate ~ 10 %, per axis.
        np.testing.assert_allclose(ratio, 1.0, rtol=0.35)
        assert abs(ratio.mean() - 1.0) < 0.2


def test_gauss_markov_bias_instability():
    model = GyroModel(arw=0.0, bias_instability=1e-3, rrw=0.0, bias=(0.01, 0.0, -0.01),
                      bias_instability_tau_s=1.0)
    dt = 0.05
    _, bias = model.sample(80000, dt, np.random.default_rng(5))
    gm = bias - np.array([0.01, 0.0, -0.01])
    np.testing.assert_allclose(gm.std(axis=0), 1e-3, rtol=0.1)
    lag = int(round(1.0 / dt))
    corr = [np.corrcoef(gm[:-lag, i], gm[lag:, i])[0, 1] for i in range(3)]
    np.testing.assert_allclose(corr, np.exp(-1.0), atol=0.08)


def test_gyro_bias_truth_is_what_the_gyro_reads():
    suite = SensorSuite(GyroModel(arw=0.0, bias_instability=2e-3, rrw=1e-3, bias=(0.01, 0.02, 0.03)),
                        AccModel(), MagModel())
    traj = sim.random_motion(30.0, 100.0, seed=1)
    res = sim.simulate(traj, suite, seed=9)
    np.testing.assert_allclose(res.gyr - res.gyr_true, res.gyro_bias_true,
                               atol=0.5 * DEFAULT_PROFILE.gyro_scale + 1e-12)


def test_determinism_for_a_seed():
    a = sim.make_scenario("rests", 60.0, 100.0, seed=5)
    b = sim.make_scenario("rests", 60.0, 100.0, seed=5)
    c = sim.make_scenario("rests", 60.0, 100.0, seed=6)
    for name in ("quat_true", "gyr", "acc", "mag", "gyro_bias_true", "rest"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for name in ("quat_true", "gyr", "acc", "mag"):
        assert not np.array_equal(getattr(a, name), getattr(c, name))


def test_acc_spike_saturates():
    traj = sim.static(10.0, 100.0)
    calm = sim.simulate(traj, seed=1)
    assert calm.saturated["acc"] == 0
    res = sim.simulate(traj, seed=1, acc_spikes=[(5.0, 300.0)])  # ~30 g, beyond +-8 g
    assert res.saturated["acc"] > 0
    limit = DEFAULT_PROFILE.ranges_si()["acc_m_s2"]
    tap = (res.t >= 5.0) & (res.t < 5.02)
    assert tap.sum() == 2
    assert np.all(np.abs(res.acc[tap]).max(axis=1) >= limit - 1e-9)
    lo, hi = np.array(DEFAULT_PROFILE.acc_limits) * DEFAULT_PROFILE.acc_scale
    assert res.acc.min() >= lo and res.acc.max() <= hi
    # Outside the tap, the readings are the same as without it; the gyro is unaffected.
    np.testing.assert_array_equal(res.acc[~tap], calm.acc[~tap])
    np.testing.assert_array_equal(res.gyr, calm.gyr)
    # A small tap does not saturate but shows up with its magnitude.
    small = sim.simulate(traj, seed=1, acc_spikes=[(5.0, 20.0)])
    assert small.saturated["acc"] == 0
    np.testing.assert_allclose(np.linalg.norm(small.acc[tap] - calm.acc[tap], axis=1), 20.0, atol=0.1)


def test_free_fall_reads_zero():
    traj = sim.random_motion(20.0, 100.0, seed=2)
    res = sim.simulate(traj, seed=3, free_fall=[(5.0, 6.0)])
    ff = (res.t >= 5.0) & (res.t < 6.0)
    norm = np.linalg.norm(res.acc, axis=1)
    assert norm[ff].max() < 0.15
    assert norm[~ff].min() > 3.0
    np.testing.assert_array_equal(res.quat_true, traj.quat)  # truth attitude is unaffected


def test_magnetic_disturbance_changes_norm():
    extra = (30.0, 0.0, 0.0)
    suite = SensorSuite(GyroModel.ideal(), AccModel(), MagModel(disturbances=[(10.0, 20.0, extra)]))
    traj = sim.turntable(30.0, 100.0, settle_s=2.0)
    res = sim.simulate(traj, suite, seed=1)
    norm = np.linalg.norm(res.mag, axis=1)
    t = res.t
    inside = (t >= 10.5) & (t < 19.5)
    outside = (t < 10.0) | (t >= 20.0)
    disturbed = np.linalg.norm(res.earth_field_uT + np.array(extra))
    assert norm[inside].mean() == pytest.approx(disturbed, abs=0.1)
    assert norm[outside].mean() == pytest.approx(49.0, abs=0.1)
    # Fixed in the earth frame: the body-frame reading matches R^T (B + d).
    expected = Q.rotate_inverse(res.quat_true[inside], res.earth_field_uT + np.array(extra))
    assert np.abs(res.mag[inside] - expected).std() < 0.5
    # Smooth 0.5 s ramp: the norm rises gradually (no jump bigger than a few noise stds).
    ramp = (t >= 9.9) & (t < 10.7)
    assert np.abs(np.diff(norm[ramp])).max() < 3.0


def test_hard_and_soft_iron():
    soft = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.0], [0.0, 0.0, 1.0]])
    hard = np.array([5.0, -10.0, 20.0])
    suite = SensorSuite(GyroModel.ideal(), AccModel(), MagModel(hard_iron=hard, soft_iron=soft))
    traj = sim.static(30.0, 100.0)
    res = sim.simulate(traj, suite, seed=1)
    expected = soft @ Q.rotate_inverse(traj.quat[0], res.earth_field_uT) + hard
    np.testing.assert_allclose(res.mag.mean(axis=0), expected, atol=0.05)


@pytest.mark.parametrize("name", sim.SCENARIOS)
def test_make_scenario(name):
    res = sim.make_scenario(name, 30.0, 50.0, seed=1)
    assert len(res) == 1500 and res.rate_hz == 50.0
    assert res.quat_true.shape == (1500, 4) and res.gyro_bias_true.shape == (1500, 3)
    np.testing.assert_allclose(np.linalg.norm(res.quat_true, axis=1), 1.0, atol=1e-12)


def test_make_scenario_unknown_name():
    with pytest.raises(ValueError):
        sim.make_scenario("nope", 10.0, 100.0)


@pytest.mark.parametrize("name, duration, rate, seed, message", [
    ("rests", float("nan"), 100.0, 0, "must be positive finite numbers"),
    ("rests", float("inf"), 100.0, 0, "must be positive finite numbers"),
    ("rests", 10.0, -1.0, 0, "must be positive finite numbers"),
    ("rests", 0.01, 100.0, 0, "a trajectory needs from 2 to"),
    ("random", 1.0, 1e9, 0, "a trajectory needs from 2 to"),  # 1e9 samples: tens of GB, refused at once
    ("static", 1.0, 100.0, -1, "the seed must be an integer from 0"),
    ("nowhere", 1.0, 100.0, 0, "unknown scenario"),
])
def test_impossible_scenarios_are_refused(name, duration, rate, seed, message):
    with pytest.raises(sim.ScenarioError, match=message):
        sim.make_scenario(name, duration, rate, seed)


def test_from_rotmat_inverts_to_rotmat_for_any_rotation():
    rng = np.random.default_rng(8)
    q = Q.normalize(rng.standard_normal((2000, 4)))
    # and the hard ones: half turns about each axis, the identity
    q = np.vstack([q, [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]]])
    back = Q.from_rotmat(Q.to_rotmat(q))
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)  # the same rotation
    assert np.all(back[:, 0] >= 0.0)
    np.testing.assert_allclose(Q.to_rotmat(back), Q.to_rotmat(q), atol=1e-12)
