"""The ESKF at the edges of its legal settings and inputs (issue 8's numerical review).

Each test reproduces one reported defect.
Undefined behaviour (signed overflow) is caught by the sanitized campaign
(tests/test_campaign.py); the tests here check the numbers the builds produce.
"""
import numpy as np
import pytest

from imulink import core, sim
from imulink.analysis.attitude import angle_difference, attitude_errors
from imulink.sim import quat as Q

RATE = 100.0


def _fixed_and_float(data, rate, settings, profile=None):
    kwargs = {} if profile is None else {"profile": profile}
    runs = {}
    for arithmetic in ("fixed", "float"):
        f = core.Filter("eskf", rate, arithmetic, settings=settings, **kwargs)
        runs[arithmetic] = (f, f.run_counts(data.gyr_counts, data.acc_counts, data.mag_counts))
    return runs


def _max_difference_deg(runs):
    return float(np.max(angle_difference(runs["fixed"][1].quat, runs["float"][1].quat)))


@pytest.mark.parametrize("acc_noise", [39.2266, 100.0])
def test_large_accelerometer_noise_setting_does_not_wrap(acc_noise):
    """Item 1: acc_noise / g was formed in Q30 (+-2 g) and wrapped above ~18 m/s^2."""
    data = sim.simulate(sim.random_motion(60, RATE, seed=11), sim.SensorSuite.default(), seed=11)
    runs = _fixed_and_float(data, RATE, {"acc_noise": acc_noise})
    assert _max_difference_deg(runs) < 0.05
    assert runs["fixed"][1].saturations == 0


def test_the_largest_gyro_noise_setting_does_not_saturate_the_bias_jump_test():
    """The jump test's noise of the low-passed rate, arw^2 / T times its share: formed in
    Q30 of (rad/s)^2 it saturated above 2 (rad/s)^2, at the largest gyro_arw (0.49) 2 599
    times in 80 s of rest."""
    suite = sim.SensorSuite.default()
    suite.gyro.bias_steps = [(60.0, np.radians([0.0, 0.5, 0.0]))]
    data = sim.simulate(sim.static(80.0, RATE), suite, seed=3)
    runs = _fixed_and_float(data, RATE, {"gyro_arw": 0.49})
    assert runs["fixed"][1].saturations == 0
    assert _max_difference_deg(runs) < 0.05


@pytest.mark.parametrize("rate", [30.0, 40.0, 52.0])
def test_fast_spin_at_low_sensor_rates_matches_the_float_twin(rate):
    """Item 2: at 30-52 Hz a near-full-scale spin overflowed the three-sample rotation vector."""
    tilted = Q.from_zyx(0.4, -0.3, 0.2)
    traj = sim.turntable(20, rate, rate_dps=np.rad2deg(30.0), initial=tilted, settle_s=2.0)
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=12)
    runs = _fixed_and_float(data, rate, {"sample_rate": rate})
    assert _max_difference_deg(runs) < 0.05
    assert runs["fixed"][1].saturations == 0


def test_spin_beyond_one_radian_per_filter_step_is_followed():
    """Item 2: a group rotation of several radians (25 rad/s at 30 Hz: 2.5 rad per filter
    step) is integrated whole, not cut to one radian: without aiding, the attitude is the
    product of the samples' rotations."""
    rate = 30.0
    traj = sim.turntable(20, rate, rate_dps=np.rad2deg(25.0), initial=Q.from_zyx(0.4, -0.3, 0.2), settle_s=0.0)
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=13)
    data.acc_counts[1:] = 0
    data.mag_counts[1:] = 0
    out = core.run_counts("eskf", data.gyr_counts, data.acc_counts, data.mag_counts, rate, "fixed",
                          settings={"sample_rate": rate})
    increments = data.gyr_counts[1:].astype(float) * core.DEFAULT_PROFILE.gyro_scale / rate
    expected = [out.quat[0]]
    for theta in increments:
        expected.append(Q.multiply(expected[-1], Q.from_rotvec(theta)))
    assert np.max(angle_difference(out.quat, np.array(expected))) < 0.05


@pytest.mark.parametrize("name,value,state", [("init_gyro_bias_std", 1e-5, 3), ("init_acc_bias_std", 1e-4, 6)])
def test_small_initial_variances_keep_their_value(name, value, state):
    """Item 4: a variance chooses its exponent before it is rounded (rounded to Q30 first,
    1e-10 would become 0.25)."""
    data = sim.make_scenario("static", 0.02, RATE, seed=1)
    expected = value**2 if name == "init_gyro_bias_std" else (value / 9.80665) ** 2
    for arithmetic in ("fixed", "float"):
        f = core.Filter("eskf", RATE, arithmetic, settings={name: value, "estimate_acc_bias": 1})
        f.run_counts(data.gyr_counts[:1], data.acc_counts[:1], data.mag_counts[:1])
        assert f.covariance()[state, state] == pytest.approx(expected, rel=1e-3)


def _heading_error_deg(out, data, after_s, rate=RATE):
    return np.abs(attitude_errors(out.quat, data.quat_true)["heading"][int(after_s * rate):])


def test_magnetometer_reading_zeros_at_power_up_still_gives_heading():
    """Item 5: an HMC5883L reads zeros before its first conversion; the reference came
    from the first sample unchecked and the filter never had a heading."""
    initial = Q.from_zyx(0.1, -0.05, 2.0)  # heading far from zero
    data = sim.simulate(sim.static(60, RATE, initial=initial), sim.SensorSuite.default(), seed=14)
    data.mag_counts[:5] = 0
    data.mag[:5] = 0.0
    for arithmetic in ("fixed", "float"):
        out = core.run_counts("eskf", data.gyr_counts, data.acc_counts, data.mag_counts, RATE, arithmetic)
        # As from a normal start: the first field's noise, then the Kalman filter's convergence.
        assert np.max(_heading_error_deg(out, data, 10.0)) < 3.0


def test_noisy_first_field_sample_does_not_spoil_the_reference():
    """Item 5: a first magnetometer sample 40 % too strong became the reference norm and
    every later (correct) field was rejected as disturbed."""
    initial = Q.from_zyx(0.1, -0.05, 1.0)
    traj = sim.motion_with_rests(120, RATE, seed=15, accel_std=0.2, initial=initial)
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=15)
    data.mag_counts[0] = np.round(data.mag_counts[0] * 1.4).astype(np.int16)
    f = core.Filter("eskf", RATE, "fixed")
    out = f.run_counts(data.gyr_counts, data.acc_counts, data.mag_counts)
    assert f.measurement_weights()[1] > 0.5
    assert np.sqrt(np.mean(_heading_error_deg(out, data, 30.0) ** 2)) < 2.0


def _rotation_matrix(rotvec):
    angle = np.linalg.norm(rotvec)
    if angle == 0.0:
        return np.eye(3)
    k = rotvec / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


@pytest.mark.parametrize("scale_std", [0.0, 0.003, 0.05])
def test_covariance_follows_the_exact_transition_in_fast_rotation(scale_std):
    """Item 7: Phi = I - [phi x] is first order; at 30 rad/s and a 33 Hz filter rate
    (0.9 rad per step) it inflates the attitude variance step after step. Without any
    aiding (no specific force, no field after the first sample) the filter's covariance
    must be the exact propagation P <- Phi P Phi^T + Q with Phi_att = R(phi)^T, and Q's
    attitude block the gyro noise plus the scale errors' tilt share
    (I - v v^T) diag(sigma phi)^2 (I - v v^T), v the estimate's vertical in the sensor frame."""
    rate = 100.0
    traj = sim.turntable(10, rate, rate_dps=np.rad2deg(30.0), initial=Q.from_zyx(0.5, 0.3, 0.0), settle_s=0.0)
    data = sim.simulate(traj, sim.SensorSuite.default(), seed=16)
    data.acc_counts[1:] = 0
    data.mag_counts[1:] = 0
    defaults = core.default_settings("eskf")
    period = 3.0 / rate
    for arithmetic in ("fixed", "float"):
        f = core.Filter("eskf", rate, arithmetic, settings={"gyro_scale_std": scale_std})
        out = f.run_counts(data.gyr_counts, data.acc_counts, data.mag_counts)
        p = np.diag([defaults["init_attitude_std"] ** 2] * 3 + [defaults["init_gyro_bias_std"] ** 2] * 3)
        q = np.diag([defaults["gyro_arw"] ** 2 * period] * 3 + [defaults["gyro_rrw"] ** 2 * period] * 3)
        gyr = data.gyr_counts[1:].astype(float) * core.DEFAULT_PROFILE.gyro_scale / rate
        for step, (t1, t2, t3) in enumerate(gyr[: len(gyr) // 3 * 3].reshape(-1, 3, 3)):
            phi = t1 + t2 + t3 + 33 / 80 * np.cross(t1, t3) + 57 / 80 * np.cross(t2, t3 - t1)
            transition = np.eye(6)
            transition[:3, :3] = _rotation_matrix(phi).T
            transition[:3, 3:] = -period * np.eye(3)
            up = Q.to_rotmat(out.quat[3 * step + 3])[2]  # the sensor frame's vertical after the step
            tilt = (np.eye(3) - np.outer(up, up)) * (scale_std * phi)
            scale_noise = np.zeros((6, 6))
            scale_noise[:3, :3] = tilt @ tilt.T
            p = transition @ p @ transition.T + q + scale_noise
        np.testing.assert_allclose(f.covariance(), p, rtol=1e-3, atol=1e-9, err_msg=arithmetic)


def test_attitude_variance_is_capped_below_one_radian_squared():
    """Item 7: without aiding for a long time (bias uncertainty times time) the attitude
    variance is kept below 1 rad^2: beyond, a linearised angle error means nothing and
    the next correction would be unbounded."""
    rate = 100.0
    data = sim.simulate(sim.static(200, rate), sim.SensorSuite.default(), seed=17)
    data.acc_counts[1:] = 0
    data.mag_counts[1:] = 0
    for arithmetic in ("fixed", "float"):
        f = core.Filter("eskf", rate, arithmetic, settings={"init_gyro_bias_std": 0.5})
        f.run_counts(data.gyr_counts, data.acc_counts, data.mag_counts)
        p = f.covariance()
        assert np.all(np.isfinite(p))
        assert 0.25 <= np.max(np.diag(p)[:3]) < 1.0
        assert np.all(np.linalg.eigvalsh(p / np.sqrt(np.outer(np.diag(p), np.diag(p)))) > -1e-6)


def test_rounding_level_measurement_rows_are_not_saturations():
    """Item 9: a level board's gravity row [v x] of rounding-level entries was counted as a
    saturation some 25 times a second at 1 kHz, so the counter meant nothing."""
    rate, n = 1000.0, 200_000
    rng = np.random.default_rng(0)
    gyr = rng.integers(-1, 2, (n, 3)).astype(np.int16)
    acc = rng.integers(-1, 2, (n, 3)).astype(np.int16)
    acc[:, 2] += 4096  # 1 g at +-8 g
    mag = np.tile(np.array([0, 200, -400], np.int16), (n, 1))
    f = core.Filter("eskf", rate, "fixed", settings={"sample_rate": rate})
    assert f.run_counts(gyr, acc, mag).saturations == 0


def test_inputs_beyond_every_sensor_range_are_clamped_and_flagged():
    """Item 10: the documented scales (accelerometer up to 0.5 m/s^2 per LSB, the HMC5883L's
    coarsest gain 0.435 uT per LSB) with counts outside the HMC5883L's register range
    overflowed the group sums; values beyond 1024 m/s^2 or uT are clamped and the sensor
    is treated as clipped."""
    profile = core.SensorProfile(name="huge", acc_lsb_per_g=20.0, mag_lsb_per_gauss=230.0)
    n = 3000
    rng = np.random.default_rng(3)
    gyr = rng.integers(-50, 50, (n, 3)).astype(np.int16)
    acc = rng.choice(np.array([-32768, 32767, 8], np.int16), (n, 3))
    mag = rng.choice(np.array([-32768, 32767, -4096, 300], np.int16), (n, 3))
    for arithmetic in ("fixed", "float"):
        out = core.Filter("eskf", RATE, arithmetic, profile=profile).run_counts(gyr, acc, mag)
        assert np.all(np.isfinite(out.quat))
        np.testing.assert_allclose(np.linalg.norm(out.quat, axis=1), 1.0, atol=1e-6)
        if arithmetic == "fixed":
            assert out.saturations == 0


def test_slow_states_follow_the_float_twin_at_five_kilohertz():
    """Fixed vs float at 5 kHz: a step of the earth-frame low-pass (time constant 3 s) or of
    the field reference (30 s) is a fraction of a Q16 LSB there; rounded away, those slow
    states stopped short of the twin's, and the groups' truncated means pulled them towards
    zero: 0.38 deg apart within 30 s. Kept with 30 more fraction bits and rounded means."""
    rate = 5000.0
    data = sim.simulate(sim.random_motion(30, rate, seed=0), sim.SensorSuite.default(), seed=0)
    runs = _fixed_and_float(data, rate, {"sample_rate": rate})
    assert _max_difference_deg(runs) < 0.01


@pytest.mark.parametrize("arithmetic", ["fixed", "float"])
def test_gravity_alone_gives_no_heading_information(arithmetic):
    """Item 11: without a magnetometer nothing observes the heading, so its variance can
    only grow. With P turned by the step's rotation alone, P's heading direction lagged
    the estimated vertical after each tilt correction, and the gravity updates shrank the
    heading variance from 0.1^2 to 0.083^2 rad^2 in 30 s (heading NEES 7-20 instead of 1 in
    tools/eval_consistency.py)."""
    data = sim.simulate(sim.static(30, RATE), sim.SensorSuite.default(), seed=3)
    settings = {"acc_noise": 0.02, "acc_lowpass": 0.0, "init_attitude_std": 0.1}
    f = core.Filter("eskf", RATE, arithmetic, settings=settings)
    out = f.run_counts(data.gyr_counts, data.acc_counts, np.zeros_like(data.mag_counts))
    up = Q.rotate_inverse(Q.normalize(out.quat[-1:]), np.array([0.0, 0.0, 1.0]))[0]
    heading_var = up @ f.covariance()[:3, :3] @ up
    assert heading_var >= 0.1 ** 2
