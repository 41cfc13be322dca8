"""What every HIL job shares: its error, the settling time of accuracy statistics and the Q
formats of an ESTIMATE's fields."""
from __future__ import annotations

from imulink import core
from imulink.errors import ImulinkError

#: Seconds excluded from accuracy statistics (alignment and convergence).
SETTLE_S = 10.0
#: Q formats of the ESTIMATE fields that hold angles and rates.
ESTIMATE_FRAC_BITS = {"quat": core.QUAT_FRAC_BITS, "euler": core.EULER_FRAC_BITS, "gyro_bias": core.RATE_FRAC_BITS}


class HilError(ImulinkError):
    """A HIL job that cannot go on (a board that cannot be configured, a bad input)."""
