"""BROAD trials (Laidig et al. 2021): MATLAB 5 files of real IMU data with an optical
reference, read with scipy.io.loadmat.

One reader for every user of the files (``imulink inject``, ``imulink allan`` and
tools/eval_broad.py), so that each gets the same checks and the same one-line errors.
Fields: ``imu_gyr`` (N,3) rad/s, ``imu_acc`` (N,3) m/s^2, ``imu_mag`` (N,3) uT,
``sampling_rate`` Hz, and optionally ``opt_quat`` (N,4) (w first, sensor-to-earth, ENU,
NaN where the optical system lost the body) and ``movement`` (N,) (false at rest).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imulink.errors import ImulinkError
from imulink.io.files import FileError, check_regular_file

#: The environment variable that names the directory of the BROAD trials (tests, tools/).
DATA_DIR_VARIABLE = "IMULINK_BROAD_DIR"

#: Largest .mat file read (BROAD trials are a few MB).
MAX_MAT_BYTES = 256 << 20

_WHAT = "a BROAD trial (.mat with imu_gyr, imu_acc, imu_mag as N x 3 arrays and sampling_rate)"


def data_dir() -> Path:
    """Where the BROAD trials are looked for: $IMULINK_BROAD_DIR, else shared/data/broad beside
    the repository this package was installed from (it need not exist)."""
    if os.environ.get(DATA_DIR_VARIABLE):
        return Path(os.environ[DATA_DIR_VARIABLE])
    return Path(__file__).resolve().parents[4] / "shared" / "data" / "broad"


class BroadError(ImulinkError):
    """A file that is not a readable BROAD trial; the message names it and why."""


@dataclass
class BroadTrial:
    """One trial, in SI units as stored (nothing converted, nothing checked for NaN)."""

    name: str
    gyr: np.ndarray  # (N,3) rad/s
    acc: np.ndarray  # (N,3) m/s^2
    mag: np.ndarray  # (N,3) uT
    rate_hz: float
    quat_ref: np.ndarray | None = None  # (N,4) or None when the file has no opt_quat
    movement: np.ndarray | None = None  # (N,) bool or None when the file has no movement

    def __len__(self) -> int:
        return self.gyr.shape[0]


def load_broad(path) -> BroadTrial:
    """Read a BROAD trial; BroadError (one line) unless it is a regular .mat file of at
    most MAX_MAT_BYTES with the fields above, of consistent lengths, at least 2 samples
    and a positive finite sample rate."""
    from scipy.io import loadmat

    path = Path(path)
    try:
        check_regular_file(path, MAX_MAT_BYTES)
    except FileError as exc:
        raise BroadError(str(exc)) from None
    try:
        data = loadmat(str(path))
    except Exception as exc:  # scipy raises many kinds (ValueError, TypeError, MatReadError, ...) for a bad file
        raise BroadError(f"{path} is not a readable .mat file ({type(exc).__name__}: {exc})") from None
    try:
        gyr, acc, mag = (np.ascontiguousarray(data[k], np.float64) for k in ("imu_gyr", "imu_acc", "imu_mag"))
        rate = float(np.asarray(data["sampling_rate"], np.float64).ravel()[0])
        quat = np.ascontiguousarray(data["opt_quat"], np.float64) if "opt_quat" in data else None
        movement = np.asarray(data["movement"]).ravel().astype(bool) if "movement" in data else None
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise BroadError(f"{path} is not {_WHAT}: {type(exc).__name__}: {exc}") from None
    n = len(gyr)
    if (n < 2 or any(a.shape != (n, 3) for a in (gyr, acc, mag)) or (quat is not None and quat.shape != (n, 4))
            or (movement is not None and movement.shape != (n,))):
        shapes = ", ".join(f"{k} {np.shape(data[k])}" for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
                           if k in data)
        raise BroadError(f"{path} is not {_WHAT}: the arrays are {shapes}")
    if not 0 < rate < math.inf:
        raise BroadError(f"{path}: sampling_rate {rate!r} is not a positive number of Hz")
    return BroadTrial(path.stem, gyr, acc, mag, rate, quat, movement)
