"""The live bit-exact check of the monitor: the board's estimates against the host build
of the same C, as they arrive.

It follows the stream with :class:`imulink.protocol.follower.StreamFollower`, as the
recording loader does: the active filter, its raw settings (the board's SETTING answers to
GET_SETTING) and its calibration (CALIBRATION frames; none seen: the identity, as after
start-up), where a filter run begins and whether it is complete. The SET_SETTING and
SELECT_FILTER commands the monitor sent are registered with :meth:`LiveCheck.expect`
before their ACK is processed, so their values are known where the ACK restarts the
filter. Each run's samples go through the fixed-point build (what the board must compute)
and the float twin, batch by batch (up to the last sample whose ESTIMATE arrived: the nav
filter's barometer readings, fixes and markers come between a SAMPLE and its ESTIMATE and
go in with it), and every ESTIMATE of a complete run is compared with the fixed build:
quaternion, gyro bias and Euler angles, bit for bit (imulink.hil.comparison.EstimateCheck).
(`imulink compare` on a recording also checks the ESKF covariance and the saturation count,
which need the filter stepped one sample at a time.) A run with a lost sample, or one whose
settings the monitor does not know, is not verifiable; its estimates are counted as such, up
to the board's next checkpoint of its filter state (CHECKPOINT, every second when the monitor
commands the board): the fixed build resumes from it. The float twin cannot (a checkpoint is
the fixed build's state), so a resumed run has no fixed-vs-float angle.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import islice
from typing import Any

import numpy as np

from imulink import core, protocol
from imulink.analysis.attitude import angle_difference
from imulink.core.calibration import SENSORS, Calibration, CalibrationError, calibration_from_frames
from imulink.core.counts import SensorProfile
from imulink.hil.comparison import BATCH_COMPARED, EstimateCheck
from imulink.hil.replica import FirmwareFilter
from imulink.protocol.follower import StreamFollower
from imulink.protocol.recovery import CheckpointParts

_SET_SETTING = protocol.COMMAND_IDS["SET_SETTING"]
#: What the nav filter takes besides the samples: message name -> run_nav_counts' argument.
_NAV_EVENTS = {"BARO": "baro", "GNSS": "gnss", "MARKER": "marker"}
#: Host results kept for estimates that have not arrived yet (an ESTIMATE follows its SAMPLE at once).
_KEEP_RESULTS = 4096


@dataclass
class CheckSummary:
    """What the live check has seen so far."""

    identical: int = 0
    different: int = 0
    unverifiable: int = 0
    first_difference: str | None = None
    fixed_float_max_deg: float = 0.0
    resumed: int = 0  # runs verified on from a checkpoint of the board's state after a lost sample
    recovered: int = 0  # samples lost on the way and sent again (a recording's; the live stream has none)

    @property
    def verdict(self) -> str:
        if self.different:
            return "NO"
        return "yes so far" if self.identical else "nothing verified yet"


class _Run:
    """One filter run from sample index 0 with known settings: both host builds, stepped in batches."""

    def __init__(self, filter_name: str, raw_settings: dict[str, int], profile: SensorProfile,
                 calibration: Calibration | None, checkpoint: bytes | None = None):
        reference = FirmwareFilter(filter_name, raw_settings, profile, calibration)
        self.setup = (filter_name, raw_settings, profile, calibration)  # for a run resumed from a checkpoint
        self.twin = checkpoint is None  # the float twin saw the run from its start
        if checkpoint is not None:
            reference.core.restore(checkpoint)  # ValueError: not a state of this filter
        self.filter_id = reference.filter_id
        self.fixed = reference.core
        self.float = core.Filter(filter_name, reference.si_settings["sample_rate"], "float", reference.si_settings,
                                 profile, calibration)
        self.nav = filter_name == "nav"
        self.pending: list[tuple[int, tuple, tuple, tuple]] = []
        self.events: list[tuple[str, dict]] = []  # the nav filter's BARO, GNSS, MARKER fields, in order
        self.results: dict[int, tuple] = {}  # index -> (Q30 quat, Q24 bias, Q29 euler, float quat)

    def add(self, fields: dict) -> None:
        """The next SAMPLE of the run (the follower has checked that none was lost)."""
        self.pending.append((fields["index"], fields["gyr"], fields["acc"], fields["mag"]))

    def add_event(self, name: str, fields: dict) -> None:
        """A BARO, GNSS or MARKER frame: the nav filter took it after its sample."""
        if self.nav:
            self.events.append((name, fields))

    def _nav_inputs(self, first: int, last: int) -> dict:
        """run_nav_counts' arguments for the events of samples first..last (positions from first)."""
        inputs: dict[str, list[Any]] = {"baro_after": [], "baro_pa": [], "gnss_after": [], "gnss": [],
                                        "marker_after": [], "markers": []}
        kept = []
        for name, fields in self.events:
            if fields["index"] > last:
                kept.append((name, fields))
            elif fields["index"] >= first:
                kind = _NAV_EVENTS[name]
                inputs[f"{kind}_after"].append(fields["index"] - first)
                if kind == "baro":
                    inputs["baro_pa"].append(fields["pressure_pa"])
                else:
                    inputs["gnss" if kind == "gnss" else "markers"].append(fields)
        self.events = kept
        return inputs

    def step(self, last: int) -> None:
        """Run the pending samples up to index `last` (the last ESTIMATE that arrived)."""
        ready = [p for p in self.pending if p[0] <= last]
        if not ready:
            return
        self.pending = self.pending[len(ready):]
        index = [p[0] for p in ready]
        counts = [np.array([p[k] for p in ready], np.int16) for k in (1, 2, 3)]
        fixed: core.RunResult | core.NavBoardRun
        twin: core.RunResult | core.NavBoardRun
        if self.nav:
            inputs = self._nav_inputs(index[0], index[-1])
            fixed, twin = self.fixed.run_nav_counts(*counts, **inputs), self.float.run_nav_counts(*counts, **inputs)
        else:
            fixed, twin = self.fixed.run_counts(*counts), self.float.run_counts(*counts)
        raw = fixed.raw
        assert raw is not None  # self.fixed is the fixed build (FirmwareFilter's core)
        quat, bias, euler = (raw[k].tolist() for k in ("quat", "gyro_bias", "euler"))
        float_quat = twin.quat if self.twin else np.full((len(index), 4), np.nan)
        for k, i in enumerate(index):
            self.results[i] = (quat[k], bias[k], euler[k], float_quat[k])
        for i in list(islice(self.results, max(0, len(self.results) - _KEEP_RESULTS))):
            del self.results[i]  # the oldest: a dict keeps the order the indices came in


class LiveCheck:
    """Feed it every received message in order (:meth:`feed`); it returns, per ESTIMATE,
    the fixed-vs-float angle (deg) or NaN when the estimate cannot be verified."""

    def __init__(self, profile: SensorProfile):
        self.profile = profile
        self.follower = StreamFollower()
        self.estimates = EstimateCheck(BATCH_COMPARED)
        self.fixed_float_max_deg = 0.0
        self._expected: dict[int, tuple[str, int, int]] = {}  # command_seq -> ("filter", id, 0) | ("setting", i, v)
        self._run: _Run | None = None
        self._lost_run: _Run | None = None  # the current run's, after a lost sample: resumes at a checkpoint
        self._checkpoint_parts = CheckpointParts()
        self.resumed = 0  # runs resumed from a checkpoint
        self._arrived: list[tuple[int, dict]] = []  # (segment, ESTIMATE fields) not compared yet
        self._seen = 0  # estimates compared or skipped so far

    @property
    def filter_id(self) -> int | None:
        return self.follower.filter_id

    @property
    def summary(self) -> CheckSummary:
        e, first = self.estimates, self.estimates.first
        text = None if first is None else (f"sample index {first.index}: {first.field}: board {first.board}, "
                                           f"host {first.host}")
        return CheckSummary(e.identical, e.different, e.unverifiable, text, self.fixed_float_max_deg, self.resumed)

    def expect(self, ack: protocol.Message, change: tuple[str, int, int]) -> None:
        """A command the monitor sent and the board ACKed changes the filter (``("filter", id, 0)``)
        or a setting of the active filter (``("setting", index, raw value)``) where its ACK stands
        in the stream."""
        self._expected[ack.fields["command_seq"]] = change

    def feed(self, messages) -> list[float]:
        """Process messages in arrival order; the fixed-vs-float angle of each ESTIMATE (NaN: unverifiable,
        or verified in a run resumed from a checkpoint, which the float twin cannot follow)."""
        angles: list[float] = []
        for message in messages:
            name, fields = message.name, message.fields
            run_before = self._run
            segment_before = self.follower.segment
            segment = self.follower.follow(message)
            restart_ack = self.follower.restart_ack
            if name == "ACK" and restart_ack is fields:
                self._restart(self._expected.pop(restart_ack["command_seq"], None), restart_ack["command"])
            elif name == "HELLO" and self.follower.restarted_by == "reset" and message.seq == 0:
                self._run = self._lost_run = None  # the board started again: default settings, unknown to us
            elif segment is not None and self.follower.segment != segment_before:
                self._run = self._lost_run = None  # a run began unannounced (its ACK was lost): settings unknown
            if segment is not None and self.follower.segment != segment_before:
                self._lost_run = None
            if name == "SAMPLE" and self._run is not None:
                if self.follower.complete:
                    self._run.add(fields)
                else:  # a sample was lost: nothing after it can be reproduced, up to a checkpoint
                    self._run, self._lost_run = None, self._run
            elif name == "CHECKPOINT" and self._lost_run is not None:
                self._resume(fields)
            elif name == "ESTIMATE" and segment is not None:  # (an ESTIMATE always has its run)
                self._arrived.append((segment, fields))
            elif name in _NAV_EVENTS and self._run is not None:
                self._run.add_event(name, fields)
            if self._run is not run_before:  # the estimates that came before belong to the run before
                angles += self._compare(run_before)
        return angles + self._compare(self._run)

    def _resume(self, fields: dict) -> None:
        """A CHECKPOINT part after a lost sample: once the checkpoint is whole, the fixed build
        resumes from it (the samples lost before it no longer count)."""
        lost = self._lost_run
        assert lost is not None
        state = self._checkpoint_parts.add(fields, key=(self.follower.segment,))
        if state is None or fields["filter_id"] != lost.filter_id:
            return
        try:
            self._run = _Run(*lost.setup, checkpoint=state)
        except ValueError:  # a state of another size: not this host build's filter
            return
        self._lost_run = None
        self.resumed += 1
        self.follower.resume_at(fields["index"])

    def _restart(self, change: tuple[str, int, int] | None, command: int) -> None:
        """A restarting command's ACK: a new run with what is known of the settings."""
        self._run = self._lost_run = None
        if change is None and command == _SET_SETTING:
            return  # another client changed a setting: its value is not known here
        follower = self.follower
        if change is not None and change[0] == "filter":
            follower.note_filter(change[1])
        elif change is not None and follower.filter_id is not None:
            follower.note_setting(follower.filter_id, change[1], change[2])
        filter_id = follower.filter_id
        name = core.FILTER_NAMES.get(filter_id) if filter_id is not None else None
        if filter_id is None or name is None:
            return
        known = self.settings_of(filter_id)
        fields = core.settings_fields(name)
        if all(i in known for i in range(len(fields))):
            try:
                self._run = _Run(name, {f.name: known[i] for i, f in enumerate(fields)}, self.profile,
                                 self.calibration())
            except (core.SettingsError, CalibrationError):
                self._run = None

    def calibration(self) -> Calibration | None:
        """The board's calibration as its CALIBRATION frames report it; None (the identity) when it
        sent none. CalibrationError when only part of it arrived: the run cannot be reproduced."""
        reported = self.follower.calibration_since_reset
        if not reported:
            return None
        sensors = calibration_from_frames(list(reported.values()))
        if set(sensors) != set(SENSORS):
            raise CalibrationError("only part of the board's calibration was received")
        return Calibration(self.profile, sensors)

    def _compare(self, run: _Run | None) -> list[float]:
        """Compare the estimates that arrived with `run`'s results; their fixed-vs-float angles."""
        if run is not None and self._arrived:
            run.step(max(fields["index"] for _, fields in self._arrived))
        angles = np.full(len(self._arrived), np.nan)
        verified, board_quat, float_quat = [], [], []
        for k, (segment, fields) in enumerate(self._arrived):
            position, self._seen = self._seen, self._seen + 1
            host = run.results.get(fields["index"]) if run is not None else None
            if run is None or host is None or fields["filter_id"] != run.filter_id:
                self.estimates.skip()
                continue
            expected = dict(zip(BATCH_COMPARED, host[:3]))
            self.estimates.check(position, segment, fields["index"], fields, expected)
            verified.append(k)
            board_quat.append(fields["quat"])
            float_quat.append(host[3])
        if verified:
            angles[verified] = angle_difference(np.array(board_quat) / 2.0**core.QUAT_FRAC_BITS, np.array(float_quat))
            if not np.isnan(angles[verified]).all():  # (NaN in a run resumed from a checkpoint: no twin)
                self.fixed_float_max_deg = max(self.fixed_float_max_deg, float(np.nanmax(angles[verified])))
        self._arrived = []
        return angles.tolist()

    def settings_of(self, filter_id: int) -> dict[int, int]:
        """The raw values of a filter's settings known since the board last started, by index."""
        return {index: fields["value"] for index, fields in self.follower.settings_since_reset.get(filter_id,
                                                                                                    {}).items()}
