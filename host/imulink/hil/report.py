"""Progress on stderr and the link and accuracy parts of every HIL report."""
from __future__ import annotations

import sys
import time

from imulink import protocol
from imulink.hil.common import SETTLE_S


class Progress:
    """One status line on stderr: rewritten in place on a terminal, a plain line every
    `interval_s` seconds otherwise."""

    def __init__(self, stream=None, interval_s: float = 5.0):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.interval_s = 0.25 if self.tty else interval_s
        self._last = 0.0
        self._shown = False

    def due(self) -> bool:
        """Whether an update would be shown now (so the caller can skip building it)."""
        return time.monotonic() - self._last >= self.interval_s

    def update(self, text: str, force: bool = False) -> None:
        if not force and not self.due():
            return
        self._last = time.monotonic()
        if self.tty:
            self.stream.write("\r\x1b[K" + text)
            self._shown = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line of its own (a board LOG, a warning) that does not clobber the status line."""
        if self._shown:
            self.stream.write("\r\x1b[K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def done(self) -> None:
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False


def link_summary(counters: dict) -> str:
    """Link counters in one phrase."""
    return (f"{counters['frames']} frames, {counters['bytes'] / 1e3:.0f} kB, "
            f"{counters['frame_rate']:.0f} frames/s, CRC errors {counters['crc_errors']}, "
            f"resyncs {counters['resyncs']}, lost {counters['lost_frames']}")


def link_json(counters: dict) -> dict:
    """Link counters for --json (the frame rate only where the live link measured it)."""
    out = {"frames": counters["frames"], "bytes": counters["bytes"], "crc_errors": counters["crc_errors"],
           "resyncs": counters["resyncs"], "lost_frames": counters["lost_frames"]}
    if "frame_rate" in counters:
        out["frame_rate_hz"] = counters["frame_rate"]
    return out


def accuracy_json(accuracy: dict | None) -> dict | None:
    """RMS attitude errors (deg) for --json, after SETTLE_S s; None without a truth."""
    if not accuracy:
        return None
    out = {"rms_total_deg": accuracy["total"], "rms_heading_deg": accuracy["heading"],
           "rms_inclination_deg": accuracy["inclination"], "settle_s": SETTLE_S}
    if "samples" in accuracy:
        out["samples"] = accuracy["samples"]
    return out


def board_json(hello: dict | None) -> dict | None:
    if not hello:
        return None
    return {"name": hello["board"], "firmware_version": f"{hello['firmware_major']}.{hello['firmware_minor']}."
                                                         f"{hello['firmware_patch']}",
            "schema_hash": f"0x{hello['schema_hash']:08X}"}


def board_log(progress: Progress | None, fields: dict) -> None:
    if progress is not None:
        level = {v: k for k, v in protocol.LOG_LEVELS.items()}.get(fields["level"], str(fields["level"]))
        progress.message(f"board: {level} {fields['text']}")
