"""Real data: two BROAD trials through the fixed build (skipped without ../shared/data/broad).

The full table (seven trials, three filters, both builds) is tools/eval_broad.py's,
in docs/accuracy.md; here a regression guard on the two shortest-to-explain cases.
"""
from pathlib import Path

import numpy as np
import pytest

from imulink import core, counts
from imulink.analysis import angle_difference, attitude_errors, rmse

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad"
TRIALS = {"02_undisturbed_slow_rotation_B": 2.0, "16_undisturbed_fast_translation_B": 1.5}

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="BROAD data not present beside the repository")


def load(name):
    from scipy.io import loadmat

    d = loadmat(DATA / f"{name}.mat")
    return (d["imu_gyr"], d["imu_acc"], d["imu_mag"], d["opt_quat"], d["movement"].ravel().astype(bool),
            float(np.ravel(d["sampling_rate"])[0]))


@pytest.mark.parametrize("name", sorted(TRIALS))
def test_eskf_on_broad(name):
    gyr, acc, mag, ref, movement, rate = load(name)
    fixed = core.run("eskf", gyr, acc, mag, rate, "fixed", profile=counts.BROAD_PROFILE)
    twin = core.run("eskf", gyr, acc, mag, rate, "float", profile=counts.BROAD_PROFILE)
    keep = movement & np.all(np.isfinite(ref), axis=1)
    err = rmse(attitude_errors(fixed.quat[keep], ref[keep]))
    assert err["total"] < TRIALS[name]
    assert angle_difference(fixed.quat, twin.quat).max() < 0.05
    assert fixed.saturations == 0
