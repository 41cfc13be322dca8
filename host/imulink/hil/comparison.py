"""Re-run a recording on the host (fixed build and float twin) and compare every
verifiable estimate bit for bit."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imulink import core, protocol
from imulink.analysis.attitude import angle_difference, wrap_deg
from imulink.core.counts import SensorProfile
from imulink.hil.common import ESTIMATE_FRAC_BITS
from imulink.hil.replica import FirmwareFilter
from imulink.hil.report import board_json, link_json
from imulink.io.recording import Estimates, Recording, RecordingError, matching_rows, sample_rows
from imulink.sim.navigation import local_offsets

#: ESTIMATE fields the host computes (Estimates.COMPARED) and the shape of one sample's value.
_ESTIMATE_SHAPES = {"filter_id": (), "quat": (4,), "gyro_bias": (3,), "euler": (3,), "cov_mantissa": (9,),
                    "cov_exponent": (9,), "saturations": (), "weights": (2,)}


@dataclass
class HostRun:
    """The host's computation for each recorded sample (arrays aligned with
    recording.samples). fixed: the fixed-point build's ESTIMATE fields (raw integers);
    float_quat / float_euler / float_gyro_bias: the float twin (SI, rad and rad/s);
    verifiable: the host saw exactly what the board saw up to the sample (its segment
    complete from index 0 up to it, or from a checkpoint of the board's state); states:
    what became of the board's checkpoints."""

    fixed: dict[str, np.ndarray]
    float_quat: np.ndarray
    float_euler: np.ndarray
    float_gyro_bias: np.ndarray
    verifiable: np.ndarray
    #: where the nav filter ran: the NAV_STATE fields of the fixed build (name -> array over
    #: the recorded samples; rows of other filters zero), and the float twin's position
    #: (lat, lon deg, height m; NaN elsewhere and before its first fix)
    nav: dict[str, np.ndarray] | None = None
    nav_rows: np.ndarray | None = None
    float_position: np.ndarray | None = None
    states: StateChecks = field(default_factory=lambda: StateChecks())
    #: rows whose float twin saw every sample of the segment up to them (the twin cannot
    #: resume from a checkpoint, which is the fixed build's state): fixed vs float is measured there
    twin_complete: np.ndarray | None = None


@dataclass
class StateChecks:
    """What became of the board's checkpoints (CHECKPOINT: its filter's whole state after a
    sample). received: those whose every part arrived. verified: equal byte for byte to the
    host's state where the host reached them without a gap; different: (segment, index) of
    those that were not. resumed: used to resume verification after a sample lost for good.
    unusable: (segment, index, why) of those the host could not restore."""

    received: int = 0
    verified: int = 0
    different: list[tuple[int, int]] = field(default_factory=list)
    resumed: int = 0
    unusable: list[tuple[int, int, str]] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"received": self.received, "verified": self.verified, "resumed_from": self.resumed,
                "different": [{"segment": s, "sample_index": i} for s, i in self.different],
                "unusable": [{"segment": s, "sample_index": i, "why": why} for s, i, why in self.unusable]}


def _events_after(table, segment: int, sample_index: np.ndarray) -> np.ndarray:
    """Per row of `table` (BARO, GNSS, MARKER), the position in `sample_index` (a segment's
    recorded samples) of the sample it came after; -1 for another segment or a lost sample."""
    where = np.full(len(table), -1, np.int64)
    mine = np.flatnonzero(table.segment == segment)
    at = np.searchsorted(sample_index, table.index[mine])
    found = (at < len(sample_index)) & (sample_index[np.minimum(at, len(sample_index) - 1)] == table.index[mine])
    where[mine[found]] = at[found]
    return where


def nav_inputs(recording: Recording, segment: int, sample_index: np.ndarray) -> dict:
    """What the board's nav filter took besides the samples of a segment, for
    core.Filter.run_nav_counts: its barometer readings, receiver's fixes and markers, each
    at the position of its sample among `sample_index` (the segment's recorded indices)."""
    baro, gnss, markers = recording.baro, recording.gnss, recording.markers
    b = _events_after(baro, segment, sample_index)
    g = _events_after(gnss, segment, sample_index)
    m = _events_after(markers, segment, sample_index)
    gnss_fields = [name for name, _, _ in protocol.message_fields("GNSS") if name not in ("timestamp_us", "index")]
    fixes = [{name: (getattr(gnss, name)[k].tolist()) for name in gnss_fields} for k in np.flatnonzero(g >= 0)]
    marker_rows = markers.rows()
    return {"baro_after": b[b >= 0], "baro_pa": baro.pressure_pa[b >= 0], "gnss_after": g[g >= 0], "gnss": fixes,
            "marker_after": m[m >= 0], "markers": [marker_rows[k] for k in np.flatnonzero(m >= 0)]}


def _consecutive_runs(index: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) positions of each run of consecutive sample indices."""
    breaks = (np.flatnonzero(np.diff(index) != 1) + 1).tolist()
    return list(zip([0] + breaks, breaks + [len(index)]))


class _Replay:
    """The board's filter run on the host over sample rows of one segment, from its start or
    from a checkpoint, checking the host's state against the board's checkpoints on the way."""

    def __init__(self, recording: Recording, segment: int, name: str, raw_settings: dict, calibration,
                 states: StateChecks):
        self.recording, self.segment, self.name = recording, segment, name
        self.raw_settings, self.calibration, self.states = raw_settings, calibration, states

    def reference(self, checkpoint: bytes | None = None) -> FirmwareFilter:
        """A fresh reference filter, at the state of `checkpoint` (ValueError: not this filter's)."""
        reference = FirmwareFilter(self.name, self.raw_settings, self.recording.profile, self.calibration)
        if checkpoint is not None:
            reference.core.restore(checkpoint)
        return reference

    def run(self, reference: FirmwareFilter, rows: np.ndarray,
            check: dict[int, bytes]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]:
        """Run `rows` (consecutive in the stream) and compare the state after each sample index
        in `check` with the board's. Returns the ESTIMATE fields and (nav) NAV_STATE fields per row."""
        samples = self.recording.samples
        index = samples.index[rows]
        cuts = (np.flatnonzero(np.isin(index, list(check))) + 1).tolist()
        estimates, nav_states = [], []
        for start, stop in zip([0] + cuts, cuts + [len(rows)]):
            if start == stop:
                continue
            part = rows[start:stop]
            counts = samples.gyr[part], samples.acc[part], samples.mag[part]
            if self.name == "nav":
                board = reference.core.run_nav_counts(*counts, **nav_inputs(self.recording, self.segment,
                                                                           samples.index[part]))
                assert board.estimates is not None and board.nav_states is not None  # the fixed build
                estimates.append(board.estimates)
                nav_states.append(board.nav_states)
            else:
                estimates.append(reference.core.run_estimates(*counts))
            last = int(samples.index[part[-1]])
            if last in check:
                if reference.core.state() == check[last]:
                    self.states.verified += 1
                else:
                    self.states.different.append((self.segment, last))
        joined = {key: np.concatenate([e[key] for e in estimates]) for key in _ESTIMATE_SHAPES}
        nav = {key: np.concatenate([n[key] for n in nav_states]) for key in nav_states[0]} if nav_states else None
        return joined, nav


def host_run(recording: Recording) -> HostRun:
    """Re-run the recorded samples through both builds of the filter the board ran (the
    nav filter with the barometer readings, fixes and markers the board gave it).

    A segment is verifiable from its start up to its first lost sample; after it, from the
    first checkpoint of the board's state (CHECKPOINT) from which the samples are complete,
    up to the next lost one. Where the host reaches a checkpoint without a gap, its own state
    must equal the board's byte for byte (HostRun.states)."""
    samples = recording.samples
    n = len(samples)
    fixed = {name: np.zeros((n,) + shape, np.int64) for name, shape in _ESTIMATE_SHAPES.items()}
    float_quat, float_euler, float_bias = np.full((n, 4), np.nan), np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    verifiable = np.zeros(n, bool)
    nav: dict[str, np.ndarray] | None = None
    nav_rows: np.ndarray | None = None
    float_position: np.ndarray | None = None
    states = StateChecks()
    twin_complete = np.zeros(n, bool)
    for segment in np.unique(samples.segment).tolist():
        rows = np.flatnonzero(samples.segment == segment)
        filter_id = _segment_filter(recording, segment)
        name, raw_settings = recording.filter_settings(filter_id, segment)
        counts = samples.gyr[rows], samples.acc[rows], samples.mag[rows]
        calibration = recording.calibration(segment)
        replay = _Replay(recording, segment, name, raw_settings, calibration, states)
        checkpoints = {}
        for checkpoint in recording.checkpoints:
            if checkpoint.segment == segment:
                states.received += 1
                if checkpoint.filter_id == filter_id:
                    checkpoints[checkpoint.index] = checkpoint.state
                else:
                    states.unusable.append((segment, checkpoint.index, f"a state of filter {checkpoint.filter_id}, "
                                                                       f"the run's is {filter_id}"))
        index = samples.index[rows]
        runs = _consecutive_runs(index)
        # from the start: every row (the host's values also where they cannot be verified), the
        # checkpoints checked up to the first lost sample
        complete_to = runs[0][1] if len(rows) and index[0] == 0 else 0
        reached = {c: state for c, state in checkpoints.items() if complete_to and c <= index[complete_to - 1]}
        from_start = replay.reference()
        board_fields, board_nav = replay.run(from_start, rows, reached)
        verifiable[rows[:complete_to]] = twin_complete[rows[:complete_to]] = True
        for start, stop in runs:  # after each gap: from the first checkpoint the samples then complete
            first, last = int(index[start]), int(index[stop - 1])
            if start < complete_to:
                continue
            for c in sorted(c for c in checkpoints if first - 1 <= c < last):
                try:
                    reference = replay.reference(checkpoints[c])
                except ValueError as exc:
                    states.unusable.append((segment, c, str(exc)))
                    continue
                begin = start + (c + 1 - first)
                part = rows[begin:stop]
                part_fields, part_nav = replay.run(reference, part, {d: state for d, state in checkpoints.items()
                                                                     if c < d <= last})
                states.resumed += 1
                verifiable[part] = True
                for key in _ESTIMATE_SHAPES:  # the run through the gap is replaced
                    board_fields[key][begin:stop] = part_fields[key]
                if board_nav is not None and part_nav is not None:
                    for key in board_nav:
                        board_nav[key][begin:stop] = part_nav[key]
                break
        for key in _ESTIMATE_SHAPES:
            fixed[key][rows] = board_fields[key]
        si_settings = from_start.si_settings
        twin = core.Filter(name, si_settings["sample_rate"], "float", si_settings, recording.profile, calibration)
        if name == "nav":
            assert board_nav is not None  # the fixed build's run of the nav filter
            if nav is None or nav_rows is None or float_position is None:  # the first nav segment: all three None
                nav = {key: np.zeros((n,) + values.shape[1:], np.int64) for key, values in board_nav.items()}
                nav_rows, float_position = np.zeros(n, bool), np.full((n, 3), np.nan)
            for key, values in board_nav.items():
                nav[key][rows] = values
            nav["index"][rows] = samples.index[rows]
            nav_rows[rows] = True
            twin_nav = twin.run_nav_counts(*counts, **nav_inputs(recording, segment, samples.index[rows]))
            anchored = board_nav["mode"] == 2
            float_position[rows[anchored]] = np.c_[twin_nav.lat_deg, twin_nav.lon_deg, twin_nav.height_m][anchored]
            result: core.RunResult | core.NavBoardRun = twin_nav
        else:
            result = twin.run_counts(*counts)
        float_quat[rows], float_euler[rows], float_bias[rows] = result.quat, result.euler, result.gyro_bias
    return HostRun(fixed, float_quat, float_euler, float_bias, verifiable, nav, nav_rows, float_position, states,
                   twin_complete)


def fixed_outputs(filter_name: str, raw_settings: dict[str, int], profile: SensorProfile, gyr, acc, mag,
                  calibration=None) -> dict:
    """The ESTIMATE fields (arrays, one row per sample) the firmware computes for a filter
    run from its start over these counts (with the board's calibration: None is identity),
    assembled by the core's imu_wire_estimate as the board assembles them, in one batch."""
    estimates = FirmwareFilter(filter_name, raw_settings, profile, calibration).core.run_estimates(gyr, acc, mag)
    return {name: estimates[name] for name in _ESTIMATE_SHAPES}


def _segment_filter(recording: Recording, segment: int) -> int:
    ids = recording.estimates.filter_id[recording.estimates.segment == segment]
    if len(ids):
        return int(ids[0])
    if recording.active_filter is None:
        raise RecordingError(f"{recording.path}: no STATUS or ESTIMATE says which filter the board ran")
    return recording.active_filter


#: Default least share of a run that must be verified for a bit-exact "yes" (--min-verified):
#: a few hundred identical estimates out of thousands prove little about the rest.
MIN_VERIFIED = 0.99


@dataclass(frozen=True)
class Verdict:
    """Bit-exact or not, and how much of the run that covers: `verified` of `total` (the
    recorded estimates, or the injected samples: `what`) were checked against the host
    fixed-point build and `identical` of those were equal. It passes only when something
    was verified, all of it identical, at least `min_verified` of the total, and the
    recording is not `damaged`."""

    total: int
    verified: int
    identical: int
    what: str = "recorded estimates"
    damaged: bool = False
    min_verified: float = MIN_VERIFIED
    states_different: int = 0  # the board's checkpoints that differ from the host's state

    @property
    def coverage(self) -> float:
        """The share of the total that was verified (0 when there is nothing)."""
        return self.verified / self.total if self.total else 0.0

    @property
    def different(self) -> int:
        return self.verified - self.identical

    @property
    def passed(self) -> bool:
        return (self.verified > 0 and not self.different and not self.damaged and not self.states_different
                and self.coverage >= self.min_verified)

    def __str__(self) -> str:
        """The verdict line: "bit-exact: yes (542 of 550 recorded estimates verified, all identical)"."""
        covered = f"{self.verified} of {self.total} {self.what} verified"
        if self.different:
            return f"bit-exact: NO ({self.different} of the {self.verified} verified differ; {covered})"
        if self.states_different:
            return (f"bit-exact: NO ({self.states_different} checkpoint(s) of the board's filter state differ from "
                    f"the host's; {covered})")
        if not self.verified:
            return f"bit-exact: no estimate to verify ({covered})"
        if self.damaged:
            return f"bit-exact: not proven: the recording is damaged ({covered}, all identical)"
        if self.coverage < self.min_verified:
            shown = math.floor(self.coverage * 1000) / 10  # never rounded up to the minimum
            return (f"bit-exact: not proven: only {covered} ({shown:g} %, below the minimum "
                    f"{self.min_verified * 100:g} % of --min-verified), all identical")
        return f"bit-exact: yes ({covered}, all identical)"

    def to_json(self) -> dict:
        return {"passed": self.passed, "line": str(self), "counted": self.what, "total": self.total,
                "verified": self.verified, "identical": self.identical, "different": self.different,
                "verified_fraction": self.coverage, "min_verified_fraction": self.min_verified,
                "damaged": self.damaged, "checkpoints_different": self.states_different}


@dataclass
class Difference:
    """The first estimate that differs from the host: where, which field, both values."""

    estimate: int  # position among the recorded estimates
    segment: int
    index: int
    field: str
    board: object
    host: object

    def __str__(self) -> str:
        return (f"estimate #{self.estimate} (segment {self.segment}, sample index {self.index}): {self.field}: "
                f"board {self.board}, host {self.host}")

    def to_json(self) -> dict:
        return {"estimate": self.estimate, "segment": self.segment, "sample_index": self.index,
                "field": self.field, "board": self.board, "host": self.host}


#: The ESTIMATE fields a batch run of the host build gives (the covariance and the
#: saturation count need the filter stepped one sample at a time).
BATCH_COMPARED = ("quat", "gyro_bias", "euler")


def _values(value):
    return list(value) if isinstance(value, (list, tuple, np.ndarray)) else value


def _first_different_field(board: dict, host: dict, names) -> str | None:
    """The first of `names` whose value differs between the board's fields and the host's."""
    return next((name for name in names if _values(board[name]) != _values(host[name])), None)


def _first_different_nav_field(board: dict, host: dict) -> str | None:
    """The first NAV_STATE field in which the board's differs from the host's, as "nav_state.<name>"."""
    field = _first_different_field(board, host, [name for name, _, _ in protocol.message_fields("NAV_STATE")])
    return None if field is None else f"nav_state.{field}"


class EstimateCheck:
    """Board estimates checked one at a time against the host's, as they arrive (inject and
    the live monitor; `compare` checks a whole recording at once on the same fields): how
    many were identical, different or could not be verified, and the first difference.

    compared: the ESTIMATE fields checked (Estimates.COMPARED, or BATCH_COMPARED where the
    host ran a batch)."""

    def __init__(self, compared: tuple[str, ...] = Estimates.COMPARED):
        self.compared = compared
        self.identical = self.different = self.unverifiable = 0
        self.first: Difference | None = None

    def skip(self) -> None:
        """An estimate that cannot be verified (its run lost a sample, or its settings are unknown)."""
        self.unverifiable += 1

    def check(self, estimate: int, segment: int, index: int, board: dict, host: dict,
              board_state: dict | None = None, host_state: dict | None = None) -> bool:
        """Whether the board's ESTIMATE fields (and its NAV_STATE, when given) equal the host's;
        the first that does not is kept as `first`. estimate: its position among those seen;
        segment, index: its filter run and sample index."""
        field = _first_different_field(board, host, self.compared)
        if field is not None:
            values = board[field], host[field]
        elif board_state is not None and host_state is not None:
            field = _first_different_nav_field(board_state, host_state)
            if field is not None:
                name = field.split(".", 1)[1]
                values = board_state[name], host_state[name]
        if field is None:
            self.identical += 1
            return True
        self.different += 1
        if self.first is None:
            self.first = Difference(estimate, segment, index, field, np.asarray(values[0]).tolist(),
                                    np.asarray(values[1]).tolist())
        return False


@dataclass
class Comparison:
    """Bit-exactness of a recording's estimates and the fixed-vs-float agreement.

    Per estimate (arrays aligned with recording.estimates): sample_row, the row of its
    SAMPLE in recording.samples (-1 when that SAMPLE was lost); verified, whether the
    host could reproduce it (its filter run complete up to it); identical, verified and
    equal in every field. fixed_vs_float: over the verified estimates, the rotation angle
    between the board's quaternion and the float twin's (deg: max, mean, rms), the
    largest Euler angle difference (deg) and gyro bias difference (deg/s). damaged: the
    recording's damaged spans; what they held was not compared, so a damaged recording
    is never bit-exact. leftover: per estimate, whether it came from a stream the board
    was already sending before the recording began (not part of the recorded run).
    min_verified: the least share of the recorded estimates to verify for a pass.
    """

    sample_row: np.ndarray
    verified: np.ndarray
    identical: np.ndarray
    first_difference: Difference | None
    fixed_vs_float: dict
    damaged: list[tuple[int, int]]
    leftover: np.ndarray
    min_verified: float = MIN_VERIFIED
    states: StateChecks = field(default_factory=StateChecks)  # the board's checkpoints (HostRun.states)

    @property
    def estimates(self) -> int:
        return len(self.verified)

    @property
    def verified_count(self) -> int:
        return int(self.verified.sum())

    @property
    def identical_count(self) -> int:
        return int(self.identical.sum())

    @property
    def recorded_count(self) -> int:
        """The estimates of the recorded run (all but the leftovers of an earlier stream)."""
        return int((~self.leftover).sum())

    @property
    def bit_exact(self) -> bool:
        """Every verified estimate identical (at least one) and the file undamaged, however
        few were verified: :attr:`verdict` also weighs the coverage."""
        return (self.verified_count > 0 and self.identical_count == self.verified_count and not self.damaged
                and not self.states.different)

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.recorded_count, self.verified_count, self.identical_count, damaged=bool(self.damaged),
                       min_verified=self.min_verified, states_different=len(self.states.different))


def _sample_rows(recording: Recording) -> np.ndarray:
    """Per estimate, the row of the SAMPLE with the same segment and index (-1: lost)."""
    return sample_rows(recording, recording.estimates.segment, recording.estimates.index)


def _nav_state_rows(recording: Recording) -> np.ndarray:
    """Per estimate, the row of the NAV_STATE with the same segment and index (-1: none)."""
    states, estimates = recording.nav_states, recording.estimates
    return matching_rows(estimates.segment, estimates.index, states.segment, states.index)


def nav_state_position(fields: dict, rows=slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude (deg) and height (m) of NAV_STATE fields (Q29 rad, mm) at `rows`."""
    lat_q, lon_q = protocol.frac_bits("NAV_STATE", "lat"), protocol.frac_bits("NAV_STATE", "lon")
    return (np.degrees(fields["lat"][rows] / 2.0**lat_q), np.degrees(fields["lon"][rows] / 2.0**lon_q),
            fields["height_mm"][rows] / 1000.0)


def compare(recording: Recording, run: HostRun | None = None, min_verified: float = MIN_VERIFIED) -> Comparison:
    """Compare every verifiable board estimate with the host fixed-point build, bit for bit;
    its verdict passes with at least `min_verified` of the recorded estimates verified."""
    run = run or host_run(recording)
    estimates = recording.estimates
    sample_row = _sample_rows(recording)
    verified = sample_row >= 0
    verified[verified] = run.verifiable[sample_row[verified]]
    # a stream left over from before the recording is not part of it (even where a checkpoint would verify it)
    verified &= ~np.asarray(estimates.leftover, bool)
    state_row = _nav_state_rows(recording)
    host_nav, nav_rows = run.nav, run.nav_rows  # both set where the nav filter ran (host_run), else None
    positions, rows = np.flatnonzero(verified), sample_row[verified]
    # the nav filter's NAV_STATE is compared with its ESTIMATE where it arrived (an output: never sent again)
    with_state = (np.flatnonzero(nav_rows[rows] & (state_row[positions] >= 0)) if nav_rows is not None
                  else np.zeros(0, np.int64))

    def board_and_host(name: str):
        """A compared field's values at the verified estimates: the board's and the host's
        (NAV_STATE fields, "nav_state.<name>", only where the nav filter ran)."""
        if not name.startswith("nav_state."):
            return getattr(estimates, name)[positions], run.fixed[name][rows]
        field = name.split(".", 1)[1]
        assert host_nav is not None  # nav_state fields are compared only then
        return (recording.nav_states.fields[field][state_row[positions[with_state]]],
                host_nav[field][rows[with_state]])

    compared = list(Estimates.COMPARED)
    if host_nav is not None:
        compared += [f"nav_state.{name}" for name, _, _ in protocol.message_fields("NAV_STATE")]
    equal = np.ones(len(positions), bool)
    for name in compared:
        board, host = board_and_host(name)
        same = board == host if board.ndim == 1 else np.all(board == host, axis=1)
        if name.startswith("nav_state."):
            equal[with_state] &= same
        else:
            equal &= same
    identical = np.zeros(len(verified), bool)
    identical[positions] = equal
    first = None
    if not equal.all():
        k = int(np.flatnonzero(~equal)[0])
        position, row = int(positions[k]), int(rows[k])
        for name in compared:
            if name.startswith("nav_state.") and state_row[position] < 0:
                continue  # its NAV_STATE was lost: nothing of it to compare
            if name.startswith("nav_state."):
                field = name.split(".", 1)[1]
                assert host_nav is not None  # nav_state fields are compared only with it
                board_value = recording.nav_states.fields[field][state_row[position]]
                host_value = host_nav[field][row]
            else:
                board_value, host_value = getattr(estimates, name)[position], run.fixed[name][row]
            if np.any(board_value != host_value):
                first = Difference(position, int(estimates.segment[position]), int(estimates.index[position]), name,
                                   board_value.tolist(), host_value.tolist())
                break
    twin = run.twin_complete[rows] if run.twin_complete is not None else np.ones(len(rows), bool)
    twin_positions, twin_rows = positions[twin], rows[twin]
    fixed_vs_float = _fixed_vs_float(estimates, twin_positions, run.float_quat[twin_rows], run.float_euler[twin_rows],
                                     run.float_gyro_bias[twin_rows])
    if run.nav is not None and len(twin_positions):
        fixed_vs_float.update(_position_fixed_vs_float(recording, run, state_row[twin_positions], twin_rows))
    return Comparison(sample_row, verified, identical, first, fixed_vs_float, recording.damaged,
                      np.asarray(estimates.leftover, bool), min_verified, run.states)


def _position_fixed_vs_float(recording: Recording, run: HostRun, state_rows: np.ndarray, rows: np.ndarray) -> dict:
    """The largest distance (m) between the board's nav position (its NAV_STATE) and the
    float twin's, over the verified samples where both have a position."""
    states = recording.nav_states.fields
    float_position = run.float_position
    assert float_position is not None  # host_run sets it with run.nav, which compare checks first
    usable = (state_rows >= 0) & ~np.isnan(float_position[rows, 0])
    usable[usable] &= states["mode"][state_rows[usable]] == 2
    if not usable.any():
        return {}
    board = state_rows[usable]
    twin = float_position[rows[usable]]
    d = local_offsets(*nav_state_position(states, board), twin[:, 0], twin[:, 1], twin[:, 2])
    return {"position_max_m": float(np.linalg.norm(d, axis=1).max())}


def _fixed_vs_float(estimates: Estimates, positions, float_quat, float_euler, float_bias) -> dict:
    """Attitude agreement of the board (fixed build) and the float twin over the verified estimates."""
    if not len(positions):
        return {}
    quat = estimates.quat[positions] / 2.0**ESTIMATE_FRAC_BITS["quat"]
    angle = angle_difference(quat, float_quat)
    euler = np.degrees(estimates.euler[positions] / 2.0**ESTIMATE_FRAC_BITS["euler"])
    bias = estimates.gyro_bias[positions] / 2.0**ESTIMATE_FRAC_BITS["gyro_bias"]
    return {"angle_max_deg": float(angle.max()), "angle_mean_deg": float(angle.mean()),
            "angle_rms_deg": float(np.sqrt(np.mean(angle**2))),
            "euler_max_deg": float(np.abs(wrap_deg(euler - np.degrees(float_euler))).max()),
            "gyro_bias_max_deg_s": float(np.degrees(np.abs(bias - float_bias)).max())}


def unverifiable_spans(recording: Recording, comparison: Comparison) -> list[dict]:
    """Where the unverifiable estimates lie: each run of consecutive ones within a segment
    (filter run), as segment, first and last sample index and the count of estimates."""
    estimates, unverifiable = recording.estimates, ~comparison.verified
    spans: list[dict] = []
    for position in np.flatnonzero(unverifiable).tolist():
        segment, index = int(estimates.segment[position]), int(estimates.index[position])
        last = spans[-1] if spans else None
        if last is not None and last["segment"] == segment and last["_position"] == position - 1:
            last.update(last_index=index, estimates=last["estimates"] + 1, _position=position)
        else:
            spans.append({"segment": segment, "first_index": index, "last_index": index, "estimates": 1,
                          "_position": position})
    return [{key: value for key, value in span.items() if key != "_position"} for span in spans]


def verified_through_recovery(recording: Recording, comparison: Comparison) -> int:
    """Verified estimates that depend on a recovered sample (one lost on the way and sent
    again, RESENT): at or after it in its filter run. Without recovery they would be unverifiable."""
    samples = recording.samples
    first_recovered: dict[int, int] = {}
    for segment, index in zip(samples.segment[samples.recovered].tolist(), samples.index[samples.recovered].tolist()):
        first_recovered[segment] = min(index, first_recovered.get(segment, index))
    if not first_recovered:
        return 0
    estimates = recording.estimates
    after = np.array([index >= first_recovered.get(segment, index + 1)
                      for segment, index in zip(estimates.segment.tolist(), estimates.index.tolist())], bool)
    return int((after & comparison.verified).sum())


def _recovered_text(recording: Recording) -> str:
    frames = sum(recording.recovered.values())
    kinds = ", ".join(f"{count} {name}" for name, count in sorted(recording.recovered.items()))
    return f"recovered: {frames} frames lost on the way and sent again by the board ({kinds})"


def _spans_text(spans: list[dict], shown: int = 5) -> str:
    text = ", ".join(f"segment {s['segment']} sample index {s['first_index']}-{s['last_index']} "
                     f"({s['estimates']} estimates)" for s in spans[:shown])
    return text + (f" and {len(spans) - shown} more" if len(spans) > shown else "")


def format_comparison(recording: Recording, comparison: Comparison) -> str:
    """The human report of `imulink compare`."""
    counters = recording.counters
    lines = [f"recording: {recording.path}"]
    if recording.hello:
        h = recording.hello
        lines.append(f"board: {h['board']} firmware {h['firmware_major']}.{h['firmware_minor']}."
                     f"{h['firmware_patch']}, sensor profile {recording.profile.name}")
    lines.append(f"link: {counters['frames']} frames, {counters['bytes']} bytes, CRC errors {counters['crc_errors']}, "
                 f"resyncs {counters['resyncs']}, lost frames {counters['lost_frames']}; "
                 f"{recording.segments} filter run(s)"
                 + (f"; ignored a truncated tail of {recording.truncated_bytes} bytes"
                    if recording.truncated_bytes else ""))
    if recording.recovered:
        lines.append(_recovered_text(recording))
    if recording.damaged:
        spans = ", ".join(f"{length} bytes at byte {offset}" for offset, length in recording.damaged[:5])
        more = f" and {len(recording.damaged) - 5} more" if len(recording.damaged) > 5 else ""
        lines.append(f"DAMAGED FILE: skipped {len(recording.damaged)} span(s) that are not valid records "
                     f"({spans}{more}); the frames they held are missing")
    c = comparison
    unverifiable = ~c.verified
    leftover = int((unverifiable & recording.estimates.leftover).sum())
    lost = int(unverifiable.sum()) - leftover
    reasons = [text for count, text in (
        (leftover, f"{leftover} left over from a stream the board was already sending when the recording began"),
        (lost, f"{lost} after a lost sample of their filter run")) if count]
    through_recovery = verified_through_recovery(recording, c)
    lines.append(f"estimates: {c.estimates} received, {c.verified_count} verifiable"
                 + (f" ({through_recovery} of them through recovered samples)" if through_recovery else "")
                 + f", {c.identical_count} identical, "
                 f"{c.verified_count - c.identical_count} different, {c.estimates - c.verified_count} unverifiable"
                 + (f" ({'; '.join(reasons)})" if reasons else ""))
    unverifiable_at = unverifiable_spans(recording, c)
    if unverifiable_at:
        lines.append(f"unverifiable: {_spans_text(unverifiable_at)}")
    if c.states.received:
        st = c.states
        lines.append(f"checkpoints: {st.received} received, {st.verified} identical to the host's state where it "
                     f"reached them, {len(st.different)} different, {st.resumed} used to resume verification"
                     + (f", {len(st.unusable)} unusable ({st.unusable[0][2]})" if st.unusable else ""))
        if st.different:
            lines.append("checkpoints that differ: " + ", ".join(f"segment {seg} sample index {i}"
                                                                 for seg, i in st.different[:5]))
    if c.first_difference is not None:
        lines.append(f"first difference: {c.first_difference}")
    lines.append(str(c.verdict))
    ff = comparison.fixed_vs_float
    if ff:
        lines.append(f"fixed vs float: attitude max {ff['angle_max_deg']:.5f} deg, RMS {ff['angle_rms_deg']:.5f} deg; "
                     f"Euler max {ff['euler_max_deg']:.5f} deg; gyro bias max {ff['gyro_bias_max_deg_s']:.2e} deg/s")
    return "\n".join(lines)


def comparison_json(recording: Recording, comparison: Comparison) -> dict:
    """What `imulink compare --json` prints: the facts of :func:`format_comparison`."""
    c = comparison
    unverifiable = ~c.verified
    leftover = int((unverifiable & c.leftover).sum())
    counters = recording.counters
    return {
        "recording": str(recording.path), "board": board_json(recording.hello),
        "sensor_profile": recording.profile.name,
        "link": {**link_json(counters), "filter_runs": recording.segments,
                 "truncated_tail_bytes": recording.truncated_bytes},
        "damaged_spans": [{"offset_bytes": offset, "length_bytes": length} for offset, length in recording.damaged],
        "recovered_frames": dict(recording.recovered),
        "checkpoints": c.states.to_json(),
        "estimates": {"received": c.estimates, "recorded": c.recorded_count, "verifiable": c.verified_count,
                      "verified_through_recovery": verified_through_recovery(recording, c),
                      "identical": c.identical_count, "different": c.verified_count - c.identical_count,
                      "unverifiable": c.estimates - c.verified_count, "unverifiable_left_over": leftover,
                      "unverifiable_after_lost_sample": int(unverifiable.sum()) - leftover,
                      "unverifiable_spans": unverifiable_spans(recording, c)},
        "first_difference": c.first_difference.to_json() if c.first_difference is not None else None,
        "verdict": c.verdict.to_json(),
        "fixed_vs_float": dict(c.fixed_vs_float) or None,
    }
