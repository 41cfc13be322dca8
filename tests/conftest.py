"""Fixtures shared by the whole suite."""
from pathlib import Path

import pytest

from imulink.io.broad import DATA_DIR_VARIABLE, data_dir


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    """The directory of the BROAD trials (real IMU data with optical truth); the test is skipped
    without it (set $IMULINK_BROAD_DIR, or keep shared/data/broad beside the repository)."""
    directory = data_dir()
    if not directory.is_dir():
        pytest.skip(f"BROAD data not present: {directory} (set ${DATA_DIR_VARIABLE})")
    return directory
