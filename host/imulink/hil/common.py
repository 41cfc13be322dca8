"""What every HIL job shares: its error, the settling time of accuracy statistics, filter names
and the Q formats of an ESTIMATE's fields."""
from __future__ import annotations

from imulink import core
from imulink.errors import ImulinkError

#: Seconds excluded from accuracy statistics (alignment and convergence).
SETTLE_S = 10.0
FILTER_NAMES = {filter_id: name for name, (filter_id, _) in core.BOARD_FILTERS.items()}


def name_of_filter(filter_id: int) -> str:
    """The name of a filter id a board reports (the number itself for one this host does not know)."""
    return FILTER_NAMES.get(filter_id, str(filter_id))
ESTIMATE_FRAC_BITS = {"quat": core.QUAT_FRAC_BITS, "euler": core.EULER_FRAC_BITS, "gyro_bias": core.RATE_FRAC_BITS}


class HilError(ImulinkError):
    """A HIL job that cannot go on (a board that cannot be configured, a bad input)."""
