"""Real data: two BROAD trials through the fixed build (skipped without the BROAD data: tests/conftest.py).

The full table (seven trials, three filters, both builds) is tools/eval_broad.py's,
in docs/accuracy.md; here a regression guard on the two shortest-to-explain cases.
"""

import numpy as np
import pytest

from imulink import core
from imulink.analysis.attitude import angle_difference, attitude_errors, rmse
from imulink.core import counts

TRIALS = {"02_undisturbed_slow_rotation_B": 2.0, "16_undisturbed_fast_translation_B": 1.5}

def load(directory, name):
    from scipy.io import loadmat

    d = loadmat(directory / f"{name}.mat")
    return (d["imu_gyr"], d["imu_acc"], d["imu_mag"], d["opt_quat"], d["movement"].ravel().astype(bool),
            float(np.ravel(d["sampling_rate"])[0]))


@pytest.mark.parametrize("name", sorted(TRIALS))
def test_eskf_on_broad(broad_dir, name):
    gyr, acc, mag, ref, movement, rate = load(broad_dir, name)
    fixed = core.run("eskf", gyr, acc, mag, rate, "fixed", profile=counts.BROAD_PROFILE)
    twin = core.run("eskf", gyr, acc, mag, rate, "float", profile=counts.BROAD_PROFILE)
    keep = movement & np.all(np.isfinite(ref), axis=1)
    err = rmse(attitude_errors(fixed.quat[keep], ref[keep]))
    assert err["total"] < TRIALS[name]
    assert angle_difference(fixed.quat, twin.quat).max() < 0.05
    assert fixed.saturations == 0
