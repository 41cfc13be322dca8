"""Accuracy against simulated truth and fixed-vs-float agreement (short versions).

The one-hour agreement run and the BROAD evaluation are tools (tools/agreement.py,
tools/eval_broad.py) with their results in docs/accuracy.md.
"""
import numpy as np
import pytest

from imulink import core, sim
from imulink.analysis import angle_difference, quat_to_euler, wrap_deg

RATE = 100.0


@pytest.fixture(scope="module")
def static_runs():
    out = {}
    for seed in (1, 2, 3):
        data = sim.make_scenario("static", 120, RATE, seed=seed)
        out[seed] = (data, {f: core.run(f, data.gyr, data.acc, data.mag, RATE, "fixed") for f in core.FILTERS})
    return out


def euler_errors_deg(estimate_quat, true_quat):
    est = np.degrees(quat_to_euler(estimate_quat))
    ref = np.degrees(quat_to_euler(true_quat))
    return wrap_deg(est - ref)


def test_quat_to_euler_matches_the_core_convention():
    data = sim.make_scenario("random", 20, RATE, seed=4)
    out = core.run("eecf", data.gyr, data.acc, data.mag, RATE, "float")
    # The core's own Euler output and the independent numpy conversion agree.
    assert np.max(np.abs(wrap_deg(np.degrees(out.euler) - np.degrees(quat_to_euler(out.quat))))) < 1e-6


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_eecf_static_within_seed_000_bounds(static_runs, seed):
    """Seed 000: static roll/pitch within +-0.2 deg, heading within +-0.1 deg, after
    alignment and convergence (first 10 s excluded)."""
    data, runs = static_runs[seed]
    err = euler_errors_deg(runs["eecf"].quat, data.quat_true)[int(10 * RATE):]
    assert np.max(np.abs(err[:, 0])) < 0.2
    assert np.max(np.abs(err[:, 1])) < 0.2
    assert np.max(np.abs(err[:, 2])) < 0.1


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kf1d_static_error_small(static_runs, seed):
    data, runs = static_runs[seed]
    err = euler_errors_deg(runs["kf1d"].quat, data.quat_true)[int(10 * RATE):]
    assert np.max(np.abs(err)) < 1.0


def test_turntable_heading_tracks_the_table():
    data = sim.make_scenario("turntable", 60, RATE, seed=5)
    for name in core.FILTERS:
        out = core.run(name, data.gyr, data.acc, data.mag, RATE, "fixed")
        err = euler_errors_deg(out.quat, data.quat_true)[int(15 * RATE):]
        assert np.sqrt(np.mean(err[:, 2] ** 2)) < 1.0, name
        assert np.max(np.abs(err[:, 2])) < 3.0, name


def test_gyro_bias_estimate_converges_on_random_motion():
    data = sim.make_scenario("rests", 600, RATE, seed=6)
    out = core.run("eecf", data.gyr, data.acc, data.mag, RATE, "fixed")
    final_err = np.degrees(np.abs(out.gyro_bias[-1] - data.gyro_bias_true[-1]))
    assert np.all(final_err < 0.1), final_err  # deg/s


@pytest.mark.parametrize("name", sorted(core.FILTERS))
def test_fixed_matches_float_twin_on_random_motion(name):
    """Short version of tools/agreement.py (which runs one simulated hour)."""
    data = sim.make_scenario("random", 600, RATE, seed=7)
    fixed = core.run(name, data.gyr, data.acc, data.mag, RATE, "fixed")
    twin = core.run(name, data.gyr, data.acc, data.mag, RATE, "float")
    diff = angle_difference(fixed.quat, twin.quat)
    assert diff.max() < 0.05
    assert fixed.saturations == 0


@pytest.mark.parametrize("name", sorted(core.FILTERS))
def test_accuracy_on_random_motion(name):
    data = sim.make_scenario("rests", 300, RATE, seed=8)
    out = core.run(name, data.gyr, data.acc, data.mag, RATE, "fixed")
    err = angle_difference(out.quat, data.quat_true)[int(10 * RATE):]
    assert np.sqrt(np.mean(err**2)) < 5.0
