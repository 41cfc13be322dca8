"""Accuracy against simulated truth and fixed-vs-float agreement (short versions).

The one-hour agreement run, the BROAD evaluation and the tables of static noise
are tools (tools/agreement.py, tools/eval_broad.py, tools/eval_sim.py) with their
results in docs/accuracy.md. The ESKF's own experiments are in test_eskf.py.
"""
import numpy as np
import pytest

from imulink import core, sim
from imulink.analysis import scenarios
from imulink.analysis.attitude import angle_difference, quat_to_euler, wrap_deg

RATE = scenarios.RATE_HZ


def test_quat_to_euler_matches_the_core_convention():
    data = sim.make_scenario("random", 20, RATE, seed=4)
    out = core.run("eecf", data.gyr, data.acc, data.mag, RATE, "float")
    # The core's own Euler output and the independent numpy conversion agree.
    assert np.max(np.abs(wrap_deg(np.degrees(out.euler) - np.degrees(quat_to_euler(out.quat))))) < 1e-6


@pytest.mark.parametrize("name", ["eecf", "kf1d"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_static_after_alignment(name, seed):
    """[seed 000]'s band: roll/pitch within +-0.2 deg after alignment (first 10 s
    excluded); heading +-0.1 deg as a standard deviation (the magnetometer and gyro
    noise of the simulated sensors allow no tighter peak, docs/accuracy.md)."""
    err = scenarios.static_errors(name, seed)
    assert np.max(np.abs(err[:, :2])) < 0.2
    assert err[:, 2].std() < 0.12
    assert abs(err[:, 2].mean()) < 0.1


@pytest.mark.parametrize("name", sorted(core.FILTERS))
def test_turntable_heading_tracks_the_table(name):
    err = scenarios.turntable_heading_errors(name, seed=5)
    assert np.sqrt(np.mean(err**2)) < 0.5
    assert np.max(np.abs(err)) < 1.5


@pytest.mark.parametrize("name", sorted(core.FILTERS))
def test_fixed_matches_float_twin_on_random_motion(name):
    """Short version of tools/agreement.py (which runs one simulated hour)."""
    data = sim.make_scenario("random", 600, RATE, seed=7)
    fixed = core.run(name, data.gyr, data.acc, data.mag, RATE, "fixed")
    twin = core.run(name, data.gyr, data.acc, data.mag, RATE, "float")
    diff = angle_difference(fixed.quat, twin.quat)
    assert diff.max() < 0.05
    assert fixed.saturations == 0


@pytest.mark.parametrize("name, bound", [("eskf", 3.5), ("eecf", 2.5), ("kf1d", 7.0)])
def test_accuracy_on_motion_with_rests(name, bound):
    """A regression guard on simulated motion with rests (1 m/s^2 of linear
    acceleration while moving), default settings (tuned for motion on real data)."""
    data = sim.make_scenario("rests", 300, RATE, seed=8)
    out = core.run(name, data.gyr, data.acc, data.mag, RATE, "fixed")
    err = angle_difference(out.quat, data.quat_true)[int(10 * RATE):]
    assert np.sqrt(np.mean(err**2)) < bound
