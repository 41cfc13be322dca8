"""The main job without hardware: an emulated board's simulated run recorded and proven
bit-exact, with its accuracy against the simulated truth."""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imulink import protocol
from imulink.analysis.attitude import attitude_errors, rmse
from imulink.board.emulator import EmulatedBoard
from imulink.hil.common import ESTIMATE_FRAC_BITS, SETTLE_S
from imulink.hil.comparison import MIN_VERIFIED, Comparison, compare, comparison_json, nav_state_position
from imulink.hil.recorder import RecordResult, record
from imulink.hil.report import accuracy_json
from imulink.io.files import check_writable_target
from imulink.io.recording import Recording, load_recording, sample_rows
from imulink.progress import StatusLine
from imulink.sim.navigation import local_offsets


@dataclass
class DemoReport:
    address: str
    target: str
    record: RecordResult
    recording: Recording
    comparison: Comparison
    accuracy: dict
    duration_s: float
    kept: bool  # whether the recording file was kept (demo(output=...))
    #: the nav filter's position against the truth (RMS m, m/s after SETTLE_S, from the
    #: board's NAV_STATE once it has a position); None for the attitude filters
    nav_accuracy: dict | None = None

    def format(self) -> str:
        r, c, rec = self.record, self.comparison, self.recording
        assert rec.hello is not None  # record() connected: the board's HELLO is in the recording
        lost = rec.counters["lost_frames"]
        lines = [
            f"emulated board: {self.address} ({rec.hello['board']}, {self.target} target, filter {r.filter_name})",
            f"recorded: {r.samples} samples, {r.estimates} estimates, {rec.counters['frames']} frames in "
            f"{r.duration_s:.2f} s ({rec.counters['frames'] / max(r.duration_s, 1e-9):.0f} frames/s); "
            f"lost frames {lost}, CRC errors {rec.counters['crc_errors']}",
            str(c.verdict),
        ]
        if c.first_difference is not None:
            lines.append(f"first difference: {c.first_difference}")
        if c.fixed_vs_float:
            ff = c.fixed_vs_float
            lines.append(f"fixed vs float twin: attitude max {ff['angle_max_deg']:.5f} deg, "
                         f"RMS {ff['angle_rms_deg']:.5f} deg")
        if c.fixed_vs_float.get("position_max_m") is not None:
            lines.append(f"fixed vs float twin: position max {c.fixed_vs_float['position_max_m']:.4f} m")
        if self.accuracy:
            a = self.accuracy
            lines.append(f"accuracy vs simulated truth (RMS after {SETTLE_S:g} s): total {a['total']:.3f} deg, "
                         f"heading {a['heading']:.3f} deg, inclination {a['inclination']:.3f} deg")
        if self.nav_accuracy:
            n = self.nav_accuracy
            lines.append(f"navigation vs simulated truth (RMS after {SETTLE_S:g} s, {n['samples']} samples): "
                         f"horizontal {n['horizontal_m']:.2f} m, vertical {n['vertical_m']:.2f} m, "
                         f"velocity {n['velocity_m_s']:.3f} m/s; GNSS fixes rejected {n['rejected']}")
        lines.append(f"recording: {rec.path}" if self.kept else "recording: not kept (--output FILE keeps it)")
        lines.append(f"demo took {self.duration_s:.1f} s")
        return "\n".join(lines)

    def to_json(self) -> dict:
        """What `imulink demo --json` prints: the record summary and the comparison (as
        `record --json` and `compare --json` give them), the accuracy, the kept file."""
        record, comparison = self.record.to_json(), comparison_json(self.recording, self.comparison)
        if not self.kept:  # the temporary file is gone
            record["recording"] = comparison["recording"] = None
        return {"emulated_board": {"address": self.address, "target": self.target}, "record": record,
                "compare": comparison, "verdict": comparison["verdict"], "accuracy": accuracy_json(self.accuracy),
                "navigation_accuracy": self.nav_accuracy,
                "recording": str(self.recording.path) if self.kept else None, "duration_s": self.duration_s}


def demo(*, target: str = "native", transport: str = "tcp", scenario: str = "rests", duration_s: float = 60.0,
         rate_hz: float = 100.0, seed: int = 0, filter_name: str = "eskf", output=None, force: bool = False,
         progress: StatusLine | None = None, min_verified: float = MIN_VERIFIED) -> DemoReport:
    """Record an emulated board's simulated run (as fast as the link goes) and verify it.

    `target` is "native" (the firmware as a native process), "qemu" (the ARM image in
    QEMU) or "stm32f407" (the reference image on the virtual board). `scenario` is one of
    emulator.SCENARIOS: NAV_SCENARIO feeds the board a
    receiver's fixes and the barometer too, and the nav filter's accuracy is reported.
    `output` keeps the recording (an existing file only with `force`); without it the
    recording lives in a temporary directory that is removed at the end.
    """
    started = time.monotonic()
    if output is not None:
        check_writable_target(output, replace=force)  # before the board is started
    with tempfile.TemporaryDirectory(prefix="imulink-demo-") as scratch, \
            EmulatedBoard(target, front=transport, scenario=scenario, duration_s=duration_s, rate_hz=rate_hz,
                          seed=seed, filter_name=filter_name, realtime=target == "stm32f407") as board:
        path = Path(output) if output is not None else Path(scratch) / "demo.imulog"
        address = board.address
        assert address is not None  # set by the board's start (the with statement)
        # a simulated feed ends by itself (native, QEMU); the virtual reference board's chips do not:
        # it runs in real time and is recorded for the run's length
        result = record(address, path, force=force, progress=progress,
                        duration_s=None if board.feed_ends else duration_s)
        recording = load_recording(path)
        samples = recording.samples
        truth = board.truth(samples.gyr, samples.acc, samples.mag)
        fed = board.positions(samples.gyr, samples.acc, samples.mag)
    comparison = compare(recording, min_verified=min_verified)
    accuracy = {}
    verified = comparison.verified
    if verified.any():
        rows = comparison.sample_row[verified]
        quat = recording.estimates.quat[verified] / 2.0**ESTIMATE_FRAC_BITS["quat"]
        settled = rows >= SETTLE_S * rate_hz  # the first samples of the run: alignment and convergence
        usable = settled & ~np.isnan(truth[rows, 0])
        accuracy = rmse(attitude_errors(quat[usable], truth[rows][usable]))
    nav_accuracy = None
    if board.trajectory is not None and filter_name == "nav":
        nav_accuracy = _nav_accuracy(recording, fed, board.trajectory, rate_hz)
    return DemoReport(address, target, result, recording, comparison, accuracy, time.monotonic() - started,
                      kept=output is not None, nav_accuracy=nav_accuracy)


def _nav_accuracy(recording: Recording, fed: np.ndarray, traj, rate_hz: float) -> dict | None:
    """The board's navigation (its NAV_STATE frames) against the simulated truth: RMS
    horizontal and vertical position (m) and velocity (m/s) error after SETTLE_S, where
    the board had a position; the gated fixes. `fed`: the simulated sample of each recorded
    sample (EmulatedBoard.positions)."""
    states = recording.nav_states.fields
    sample = sample_rows(recording, recording.nav_states.segment, recording.nav_states.index)
    at = np.where(sample >= 0, fed[np.maximum(sample, 0)], -1)  # the simulated sample of each NAV_STATE
    usable = (at >= SETTLE_S * rate_hz) & (states["mode"] == 2)
    if not usable.any():
        return None
    k = at[usable]
    e = local_offsets(*nav_state_position(states, usable), traj.lat_deg[k], traj.lon_deg[k], traj.height_m[k])
    velocity = states["vel"][usable] / 2.0**protocol.frac_bits("NAV_STATE", "vel") - traj.vel_enu[k]
    return {"horizontal_m": float(np.sqrt(np.mean(np.sum(e[:, :2] ** 2, axis=1)))),
            "vertical_m": float(np.sqrt(np.mean(e[:, 2] ** 2))),
            "velocity_m_s": float(np.sqrt(np.mean(np.sum(velocity**2, axis=1)))),
            "rejected": int(states["rejected"][usable][-1]), "samples": int(usable.sum())}
