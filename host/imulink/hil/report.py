"""The link and accuracy parts of every HIL report, and the board's LOG lines."""
from __future__ import annotations

from imulink import protocol
from imulink.hil.common import SETTLE_S
from imulink.progress import StatusLine


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


def board_log(progress: StatusLine | None, fields: dict) -> None:
    if progress is not None:
        level = {v: k for k, v in protocol.LOG_LEVELS.items()}.get(fields["level"], str(fields["level"]))
        progress.message(f"board: {level} {fields['text']}")
