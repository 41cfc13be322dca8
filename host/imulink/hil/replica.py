"""What the board should have computed: the host's run of the firmware's fixed-point core.

The firmware (firmware/app) configures a filter with raw settings, the integers of
SET_SETTING, and steps it one sample at a time; :class:`FirmwareFilter` does the same
through the host build of the same C (:mod:`imulink.core`), and assembles its ESTIMATE
with the board's function (imu_wire_estimate), so that its fields can be compared with
the board's bit for bit.
"""
from __future__ import annotations

import numpy as np

from imulink import core
from imulink.core.counts import DEFAULT_PROFILE, SensorProfile


class FirmwareFilter:
    """One filter of the fixed-point core, configured by raw settings (the integers of
    SET_SETTING) and the board's calibration (SET_CALIBRATION), and stepped one sample at
    a time, as the firmware runs it.

    Raises core.SettingsError when the core refuses the settings.
    """

    def __init__(self, filter_name: str, raw_settings: dict[str, int], profile: SensorProfile = DEFAULT_PROFILE,
                 calibration=None):
        self.filter_name = filter_name
        self.filter_id = core.BOARD_FILTERS[filter_name][0]
        self.fields = core.settings_fields(filter_name)
        self.raw_settings = dict(raw_settings)
        values = {f.name: raw_settings[f.name] / 2.0**f.frac_bits for f in self.fields}
        self.si_settings = values
        self.calibration = calibration  # the board's (an imulink.analysis.calibration.Calibration), None: identity
        self.core = core.Filter(filter_name, values["sample_rate"], "fixed", values, profile, calibration)
        self.saturations = 0
        #: the nav filter's NAV_STATE fields after the last step (None for the other filters)
        self.nav_state: dict | None = None

    @staticmethod
    def default_raw_settings(filter_name: str, rate_hz: float) -> dict[str, int]:
        """The core's default settings (with `rate_hz`) as raw fixed-point integers."""
        values = core.resolve_settings(filter_name, rate_hz, None)
        return {f.name: core.to_fixed(values[f.name], f.frac_bits, f.name) for f in core.settings_fields(filter_name)}

    def step(self, index: int, gyr, acc, mag) -> dict:
        """Run one sample (three int16 triples) and return the ESTIMATE fields for it (the nav
        filter's NAV_STATE fields then in :attr:`nav_state`)."""
        counts = (np.array([gyr], np.int16), np.array([acc], np.int16), np.array([mag], np.int16))
        if self.filter_name == "nav":
            result = self.core.run_nav_counts(*counts)
            assert result.nav_states is not None  # self.core is the fixed build
            self.nav_state = {name: values[0].tolist() for name, values in result.nav_states.items()}
            self.nav_state["index"] = index
        else:
            self.core.run_counts(*counts)
        estimate = self.core.estimate(index)
        self.saturations = estimate["saturations"]
        return estimate
