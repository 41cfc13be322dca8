"""Stream samples into a board in injection mode and compare every answer on the fly."""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imulink import core, protocol, sim
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.board.link import COMMAND_TIMEOUT_MAX_S, DEFAULT_BAUD, CommandTimeout, Link, LinkError
from imulink.core.counts import BROAD_PROFILE, SensorDataError, SensorProfile, si_to_counts
from imulink.hil.board_setup import check_profile, leave_injection_mode, read_calibration, read_settings
from imulink.hil.common import ESTIMATE_FRAC_BITS, SETTLE_S, HilError
from imulink.hil.comparison import MIN_VERIFIED, EstimateCheck, Verdict
from imulink.hil.replica import FirmwareFilter
from imulink.hil.report import accuracy_json
from imulink.io.broad import BroadError, load_broad
from imulink.io.recording import Estimates, load_recording
from imulink.progress import StatusLine


@dataclass
class InjectionInput:
    """Samples to inject: int16 counts (N,3), their rate and sensor profile; optionally
    the filter and raw settings to run them with (a recording's) and the truth."""

    description: str
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    rate_hz: float
    profile: SensorProfile
    filter_name: str | None = None
    raw_settings: dict[str, int] | None = None
    truth: np.ndarray | None = None
    #: what of a damaged recording is missing from these samples (None: nothing)
    damage: str | None = None


def load_injection_input(spec: str) -> InjectionInput:
    """`sim:SCENARIO[:DURATION_S[:RATE_HZ[:SEED]]]` (default 60 s at 100 Hz, seed 0),
    a BROAD .mat file (converted to counts with BROAD_PROFILE) or a recording."""
    if spec.startswith("sim:"):
        return _simulated_input(spec)
    path = Path(spec)
    if not path.exists():
        raise HilError(f"input {spec!r} not found (give a recording, a BROAD .mat file or sim:SCENARIO:SECONDS)")
    if path.suffix.lower() == ".mat":
        return _load_broad(path)
    recording = load_recording(path)
    if not len(recording.samples):
        raise HilError(f"{path} holds no samples")
    filter_id = recording.active_filter
    if filter_id is None:
        raise HilError(f"{path} does not say which filter the board ran (no ESTIMATE, no STATUS)")
    name, raw_settings = recording.filter_settings(filter_id)
    s = recording.samples
    return InjectionInput(f"recording {path.name} ({len(s)} samples)", s.gyr, s.acc, s.mag,
                          raw_settings["sample_rate"] / 2.0**16, recording.profile, name, raw_settings,
                          damage=_recording_damage(recording))


def _recording_damage(recording) -> str | None:
    """What of a recording's samples is missing, in words, or None when nothing is: damaged
    spans and a truncated tail of the file, and SAMPLE indices missing from its filter runs."""
    s = recording.samples
    missing = 0
    for segment in np.unique(s.segment).tolist():
        index = s.index[s.segment == segment]
        missing += int(index.max()) + 1 - len(index)  # a run counts from index 0
    parts = []
    if recording.damaged:
        parts.append(f"{len(recording.damaged)} damaged span(s) of the file skipped "
                     f"({sum(length for _, length in recording.damaged)} bytes)")
    if recording.truncated_bytes:
        parts.append(f"a truncated tail of {recording.truncated_bytes} bytes ignored")
    if missing:
        parts.append(f"{missing} sample(s) missing from its filter run(s)")
    if not parts:
        return None
    return (f"{'; '.join(parts)}: the samples that remain are injected one after the other, a stream the "
            "board never recorded")


def _simulated_input(spec: str) -> InjectionInput:
    usage = f"use sim:SCENARIO[:DURATION_S[:RATE_HZ[:SEED]]] with SCENARIO one of {', '.join(sim.SCENARIOS)}"
    parts = spec.split(":")[1:]
    if not 1 <= len(parts) <= 4 or parts[0] not in sim.SCENARIOS:
        raise HilError(f"bad simulated input {spec!r}: {usage}")
    try:
        duration = float(parts[1]) if len(parts) > 1 else 60.0
        rate = float(parts[2]) if len(parts) > 2 else 100.0
        seed = int(parts[3]) if len(parts) > 3 else 0
    except ValueError:
        raise HilError(f"bad simulated input {spec!r}: duration and rate must be numbers, seed an integer") from None
    try:
        run = sim.make_scenario(parts[0], duration, rate, seed)
    except sim.ScenarioError as exc:
        raise HilError(f"bad simulated input {spec!r}: {exc}") from None
    return InjectionInput(f"simulated {parts[0]} ({duration:g} s at {rate:g} Hz, seed {seed})", run.gyr_counts,
                          run.acc_counts, run.mag_counts, rate, run.profile, truth=run.quat_true)


def _load_broad(path: Path) -> InjectionInput:
    try:
        trial = load_broad(path)
    except BroadError as exc:
        raise HilError(str(exc)) from None
    try:
        g, a, m = si_to_counts(trial.gyr, trial.acc, trial.mag, BROAD_PROFILE)
    except SensorDataError as exc:
        raise HilError(f"{path}: {exc}") from None
    return InjectionInput(f"BROAD trial {path.stem} ({len(g)} samples at {trial.rate_hz:g} Hz)", g, a, m,
                          trial.rate_hz, BROAD_PROFILE, truth=trial.quat_ref)


@dataclass
class InjectResult:
    description: str
    samples: int
    answered: int
    identical: int
    answers_lost: int
    filter_restarts: int
    first_difference: dict | None  # sample_index, field, board, host (raw integers)
    filter_name: str
    duration_s: float
    accuracy: dict | None  # RMS errors in deg (total, heading, inclination) over `samples` answered samples
    min_verified: float = MIN_VERIFIED  # the least share of the samples answered and verified for a pass
    input_damage: str | None = None  # what of a damaged input recording is missing (InjectionInput.damage)

    @property
    def bit_exact(self) -> bool:
        return self.answered > 0 and self.identical == self.answered

    @property
    def verdict(self) -> Verdict:
        return Verdict(self.samples, self.answered, self.identical, what="injected samples",
                       min_verified=self.min_verified)

    def to_json(self) -> dict:
        """What `imulink inject --json` prints: the facts of :func:`format_inject`."""
        return {"input": self.description, "filter": self.filter_name, "samples": self.samples,
                "answered": self.answered, "unanswered": self.samples - self.answered,
                "answers_lost": self.answers_lost, "filter_restarts": self.filter_restarts,
                "duration_s": self.duration_s, "samples_per_s": self.samples / max(self.duration_s, 1e-9),
                "verdict": self.verdict.to_json(), "first_difference": self.first_difference,
                "accuracy": accuracy_json(self.accuracy), "input_damage": self.input_damage}


def format_inject(result: InjectResult) -> str:
    """The human report of `imulink inject`."""
    unanswered = result.samples - result.answered
    lines = [f"input: {result.description}"]
    if result.input_damage:
        lines.append(f"DAMAGED INPUT: {result.input_damage}")
    lines.append(f"injected {result.samples} samples into {result.filter_name} in {result.duration_s:.1f} s "
                 f"({result.samples / max(result.duration_s, 1e-9):.0f} samples/s): {result.answered} answered, "
                 f"{unanswered} unanswered"
                 + (f" ({result.answers_lost} answers lost on the way, {result.filter_restarts} samples without any "
                    "reply, after each of which the filter was restarted)" if unanswered else ""))
    lines.append(str(result.verdict))
    if result.first_difference:
        d = result.first_difference
        lines.append(f"first difference: sample {d['sample_index']}: {d['field']}: board {d['board']}, "
                     f"host {d['host']}")
    if result.accuracy:
        a = result.accuracy
        lines.append(f"accuracy vs truth (RMS after {SETTLE_S:g} s, over the {a['samples']} answered samples): "
                     f"total {a['total']:.3f} deg, heading {a['heading']:.3f} deg, "
                     f"inclination {a['inclination']:.3f} deg")
    return "\n".join(lines)


def _configure_for_injection(link: Link, source: InjectionInput, filter_name: str | None,
                             given=None) -> tuple[str, dict, dict]:
    """Select the filter and set the settings the injection runs with; returns the
    filter name, the raw settings in force, and the original values changed (to restore)."""
    leave_injection_mode(link)
    wanted_filter = filter_name or (given.filter_name if given is not None else None) or source.filter_name
    if wanted_filter is not None and wanted_filter != core.FILTER_NAMES.get(read_settings(link)[0]):
        link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[wanted_filter][0])
    filter_id, settings = read_settings(link)
    name = core.FILTER_NAMES[filter_id]
    fields = core.settings_fields(name)
    current = {fields[i].name: settings[i]["value"] for i in range(len(fields))}
    wanted = dict(source.raw_settings) if source.raw_settings and name == source.filter_name else {}
    if given is not None:  # a settings file's values, over a recording's
        wanted.update(given.raw())
    wanted["sample_rate"] = core.to_fixed(source.rate_hz, 16, "sample_rate")
    changed = {}
    for index, f in enumerate(fields):
        if f.name in wanted and wanted[f.name] != current[f.name]:
            try:
                link.command("SET_SETTING", index=index, value=wanted[f.name])
            except protocol.CommandError as exc:
                raise HilError(f"the board refuses {f.name} = {wanted[f.name] / 2.0**f.frac_bits:g} {f.unit} "
                               f"({exc.reason})") from None
            changed[index] = current[f.name]
            current[f.name] = wanted[f.name]
    return name, current, changed


def inject(url: str, source: InjectionInput, *, baud: int = DEFAULT_BAUD, filter_name: str | None = None,
           progress: StatusLine | None = None,
           settings=None, min_verified: float = MIN_VERIFIED) -> InjectResult:
    """Inject every sample of `source` into the board and compare each ESTIMATE with the
    host fixed-point build (with the board's calibration) on the fly.

    settings: an imulink.io.settings_file.FilterSettings: its filter and settings are used
    (over a recording's); changed settings are restored afterwards. min_verified: the
    least share of the samples answered and verified for the verdict to pass.

    An ESTIMATE lost on the way is counted (answers_lost). A sample whose ACK never
    comes may or may not have run on the board, so the filter is restarted on both
    sides (SET_INJECTION_MODE 1) and the comparison goes on from the next sample.
    The input's counts must be in the sensor profile the board states (HELLO), else HilError.
    """
    if settings is not None and filter_name not in (None, settings.filter_name):
        raise HilError(f"the settings file is for {settings.filter_name}, not {filter_name}")
    with Link(url, baud) as link:
        hello = link.connect()
        profile = check_profile(source.profile, hello, f"the input ({source.description})")
        link.command("STOP_STREAM")
        original_filter = link.query("GET_STATUS")["active_filter"]
        name, raw_settings, changed = _configure_for_injection(link, source, filter_name, settings)
        calibration = read_calibration(link)
        link.command("SET_INJECTION_MODE", enabled=1)

        def restore() -> None:  # leave the board as it was found
            link.command("SET_INJECTION_MODE", enabled=0)
            for index, value in changed.items():
                link.command("SET_SETTING", index=index, value=value)
            if original_filter != core.BOARD_FILTERS[name][0]:
                link.command("SELECT_FILTER", filter_id=original_filter)

        try:
            result = _inject_samples(link, source, name, raw_settings, profile, calibration, progress)
            result.min_verified = min_verified
        except LinkError:
            raise  # the link failed or the board stopped answering: nothing to restore, and that is the error
        except BaseException:  # Ctrl-C, a bad input: restored if the board answers; the first error is the one said
            with contextlib.suppress(LinkError):
                restore()
            raise
        restore()
    return result


def _inject_samples(link: Link, source: InjectionInput, name: str, raw_settings: dict, profile: SensorProfile,
                    calibration, progress: StatusLine | None) -> InjectResult:
    reference = FirmwareFilter(name, raw_settings, profile, calibration)
    n = len(source.gyr)
    answered = lost = restarts = 0
    check = EstimateCheck(("index",) + Estimates.COMPARED)
    board_quat = np.full((n, 4), np.nan)
    started = time.monotonic()
    gyr, acc, mag = source.gyr.tolist(), source.acc.tolist(), source.mag.tolist()
    for k in range(n):
        try:
            # Not retried (a sample must run once), so its ACK gets the link's longest wait: an
            # emulated board on a busy host can stall past the usual COMMAND_TIMEOUT_S.
            reply = link.command("INJECT_SAMPLE", timeout=COMMAND_TIMEOUT_MAX_S,
                                 timestamp_us=round(k * 1e6 / source.rate_hz) & 0xFFFFFFFF,
                                 index=k, gyr=gyr[k], acc=acc[k], mag=mag[k], temperature=0)
        except CommandTimeout:  # did the sample run on the board? Unknown: restart the filter on both sides
            try:
                link.command("SET_INJECTION_MODE", enabled=1)
            except CommandTimeout as exc:
                raise CommandTimeout(f"the board stopped answering at sample {k + 1} of {n}: no answer to it, nor to "
                                     f"the filter's restart ({exc})") from None
            reference = FirmwareFilter(name, raw_settings, profile, calibration)
            restarts += 1
            continue
        expected = reference.step(k, gyr[k], acc[k], mag[k])
        # the nav filter's NAV_STATE came after the ESTIMATE, before the ACK: already received
        state = next((r.message.fields for r in link.receive(0) if r.message.name == "NAV_STATE"
                      and r.message.fields["index"] == k), None) if reference.nav_state is not None else None
        if reply.data is None or (reference.nav_state is not None and state is None):
            lost += 1
            continue
        answered += 1
        got = reply.data.fields
        board_quat[k] = np.array(got["quat"]) / 2.0**ESTIMATE_FRAC_BITS["quat"]
        check.check(k, 0, k, got, expected, state, reference.nav_state)
        if progress is not None:
            progress.update(f"injecting: {k + 1}/{n} samples, {check.identical}/{answered} identical, "
                            f"{(k + 1) / (time.monotonic() - started):.0f} samples/s")
    if progress is not None:
        progress.done()
    accuracy = None
    if source.truth is not None:
        usable = ~np.isnan(board_quat[:, 0]) & ~np.isnan(source.truth[:, 0])  # answered, and a truth to compare
        usable[:int(SETTLE_S * source.rate_hz)] = False
        if usable.any():
            accuracy = {**rmse(attitude_errors(board_quat[usable], source.truth[usable])), "samples": int(usable.sum())}
    first = None if check.first is None else {"sample_index": check.first.index, "field": check.first.field,
                                              "board": check.first.board, "host": check.first.host}
    return InjectResult(source.description, n, answered, check.identical, lost, restarts, first, name,
                        time.monotonic() - started, accuracy, input_damage=source.damage)
