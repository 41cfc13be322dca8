"""Magnetometer readings collected live from a board, for `imulink calibrate mag PORT`.

The user turns the board slowly in every direction while it streams; the collector keeps
the SAMPLE frames' raw magnetometer counts (the board sends them before its calibration,
so an old calibration on the board does not bend the new one) and shows which of the 26
directions of :func:`imulink.analysis.calibration.coverage` the field has taken so far. It stops
when every direction is covered, after `max_duration_s`, or on Ctrl-C; the fit itself is
:func:`imulink.analysis.calibration.mag_ellipsoid`, the same as for a recording.

While collecting, the directions are those of the readings so far corrected by their own
ellipsoid fit, so that the coverage shown is the one the final report will give.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from imulink import hil, protocol
from imulink.analysis.calibration import (
    MAX_AXIS_RATIO,
    MIN_FIELD_NORM_UT,
    MIN_MAG_SAMPLES,
    axis_ratio,
    coverage,
    fit_ellipsoid,
    symmetric_sqrt,
)
from imulink.board.link import Link, LinkError
from imulink.core.calibration import CalibrationError
from imulink.core.counts import SensorProfile
from imulink.io.sensor_input import SensorRecord, unwrap_us

if TYPE_CHECKING:  # the modules below load on use: `imulink --help` reads DEFAULT_MAX_DURATION_S
    from imulink.analysis.calibration import Coverage
    from imulink.io.sensor_input import SensorRecord
    from imulink.progress import StatusLine

#: Longest collection by default, s.
DEFAULT_MAX_DURATION_S = 180.0
#: How often the coverage is computed (and the stop conditions looked at), s.
CHECK_INTERVAL_S = 0.25
#: The stream is silent for this long: the board is gone or hangs.
SILENCE_S = 3.0


@dataclass
class MagCollection:
    """What the board sent: counts (N,3) raw magnetometer counts, time_s (N,) the board's
    sample times from the first, why the collection ended, and the sensor profile the
    board states."""

    url: str
    counts: np.ndarray
    time_s: np.ndarray
    stop_reason: str
    profile: SensorProfile

    def record(self) -> SensorRecord:
        """The readings as a SensorRecord (uT) for :func:`imulink.analysis.calibration.mag_ellipsoid`."""
        return SensorRecord(f"{self.url} (live, {len(self.counts)} samples)", self.time_s, None, None,
                            self.counts * self.profile.mag_scale, profile=self.profile)


def live_coverage(counts: np.ndarray, profile: SensorProfile) -> Coverage | None:
    """Coverage of the directions the readings so far take, corrected as the final fit will
    correct them (the ellipsoid fit of :mod:`imulink.analysis.calibration` on the readings so far;
    about the midpoint of each axis's range while they fit no ellipsoid yet). None while
    some axis spans less than twice MIN_FIELD_NORM_UT: the board has not turned enough for
    the directions to mean anything (an axis turned both ways along the earth's field spans
    50 uT or more; a still board's noise about one point would "cover" every direction)."""
    if len(counts) == 0:
        return None
    low, high = counts.min(axis=0), counts.max(axis=0)
    if np.any((high - low) * profile.mag_scale < 2.0 * MIN_FIELD_NORM_UT):
        return None
    centred = counts - (low + high) / 2.0
    try:
        centre, shape = fit_ellipsoid(counts)
    except CalibrationError:
        pass
    else:
        if axis_ratio(shape) <= MAX_AXIS_RATIO:  # an ellipsoid mag_ellipsoid would accept
            centred = (counts - centre) @ symmetric_sqrt(shape)
    return coverage(centred[np.any(centred != 0, axis=1)])


def status_line(elapsed_s: float, samples: int, found: Coverage | None) -> str:
    """The progress line: how far the coverage is and what is missing."""
    head = f"turning {elapsed_s:5.1f} s, {samples} samples: "
    if found is None:
        return head + "turn the board slowly through every direction (the field has hardly changed yet)"
    text = head + f"{found.covered} of {len(found.counts)} directions"
    if found.missing:
        shown = sorted(found.missing, key=len)[:8]  # the axes first: a fit refuses without them
        text += "; missing " + ", ".join(shown) + (f" and {len(found.missing) - len(shown)} more"
                                                   if len(found.missing) > len(shown) else "")
    return text


def collect_mag(url: str, profile: SensorProfile | None = None, *, baud: int,
                max_duration_s: float = DEFAULT_MAX_DURATION_S,
                progress: StatusLine | None = None) -> MagCollection:
    """Stream the board at `url` and keep its magnetometer counts until all 26 directions
    are covered (with at least MIN_MAG_SAMPLES samples), `max_duration_s` has passed, or
    Ctrl-C. The board's stream is stopped at the end; its filter and settings are not
    changed. LinkError for a port that is not a board, HilError for one that goes silent or
    states another sensor profile than `profile` (None: the board's, whatever it is)."""
    readings: list[tuple[int, int, int]] = []
    stamps: list[int] = []
    with Link(url, baud) as link:
        hello, *_ = hil.snapshot(link, None, profile=profile)
        profile = hil.board_profile(hello)
        start_ack = link.command("START_STREAM").ack
        streaming = False  # frames before the START_STREAM ACK belong to the snapshot
        started = last_heard = next_check = time.monotonic()
        stop_reason = None
        try:
            while stop_reason is None:
                received = link.receive(timeout=0.1)
                now = time.monotonic()
                if received:
                    last_heard = now
                elif now - last_heard > SILENCE_S:
                    raise hil.HilError(f"{url} sent nothing for {SILENCE_S:g} s: the board stopped streaming or hangs")
                for item in received:
                    message = item.message
                    if streaming and message.name == "SAMPLE":
                        readings.append(message.fields["mag"])
                        stamps.append(message.fields["timestamp_us"])
                    elif streaming and message.name == "STATUS" and not message.fields["streaming"]:
                        stop_reason = "the board stopped streaming"
                    streaming = streaming or message is start_ack
                if now < next_check and stop_reason is None:
                    continue
                next_check = now + CHECK_INTERVAL_S
                found = live_coverage(np.array(readings, np.float64).reshape(-1, 3), profile)
                if progress is not None:
                    progress.update(status_line(now - started, len(readings), found))
                if stop_reason is not None:
                    pass
                elif found is not None and not found.missing and len(readings) >= MIN_MAG_SAMPLES:
                    stop_reason = "every direction covered"
                elif now - started >= max_duration_s:
                    stop_reason = f"{max_duration_s:g} s passed"
        except KeyboardInterrupt:
            stop_reason = "stopped by Ctrl-C"
        finally:
            if progress is not None:
                progress.done()
        try:  # the readings are complete either way, and the board may be gone
            link.command("STOP_STREAM", attempts=2)
        except (LinkError, protocol.ProtocolError):
            pass
    counts = np.array(readings, np.float64).reshape(-1, 3)
    time_s = unwrap_us(np.asarray(stamps)) if stamps else np.zeros(0)
    return MagCollection(url, counts, time_s, stop_reason, profile)
