"""Figures written to files without a display: `imulink plot` (a recording) and
`imulink allan --plot`. matplotlib draws them (the optional `plot` extra: a file-writing
figure library that needs no Qt application, unlike pyqtgraph's exporters), imported only
here and only when a figure is drawn, through its Figure class (no pyplot: no backend
and no global state)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from imulink.analysis.attitude import angle_difference
from imulink.errors import ImulinkError
from imulink.io.recording import sample_times

FORMATS = ("png", "svg")
INSTALL = "pip install 'imulink[plot]'"


class PlotError(ImulinkError, ValueError):
    """A figure that cannot be drawn: an unknown format, matplotlib missing."""


def plot_format(path) -> str:
    """"png" or "svg" from the file name; PlotError otherwise."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        raise PlotError(f"cannot tell the plot format of {path}: name it .png or .svg")
    return suffix


def check_plotting() -> None:
    """PlotError (with the install command) unless matplotlib can be imported."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise PlotError(f"plotting needs matplotlib: {INSTALL}") from None


def _spans(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) row ranges where `mask` is true."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[0::2], edges[1::2]))


def plot_recording(recording, columns: dict[str, np.ndarray], verdict: str, path) -> None:
    """A recording as one figure (`path`, .png or .svg): the sensors in SI units, the
    board's, the host fixed build's and the float twin's Euler angles, the board-vs-host
    and fixed-vs-float differences, the gyro-bias estimate; with the events marked on
    every panel: filter restarts (a new run at sample index 0: dashed lines), lost samples
    (red ticks), samples lost on the way and recovered (orange ticks), board estimates the
    host could not verify (grey) or that differ (red dots). `columns` are hil.replay_columns
    of the recording; `verdict` the comparison's line, for the title."""
    fmt = plot_format(path)
    check_plotting()
    from matplotlib.figure import Figure


    t = sample_times(recording)
    segment, index = columns["segment"], columns["index"]
    restarts = t[1:][np.diff(segment) != 0]
    same_run = np.diff(segment) == 0
    lost = t[1:][same_run & (np.diff(index) > 1)]  # a sample index skipped within one run
    recovered = t[columns["recovered"] == 1]  # lost on the way and sent again by the board
    unverifiable = _spans(columns["verifiable"] == 0)
    different = columns["identical"] == 0
    colours = ("tab:red", "tab:green", "tab:blue")

    fig = Figure(figsize=(11.0, 15.0), layout="constrained")
    axes = fig.subplots(6, 1, sharex=True)
    for ax, (sensor, unit, scale, label) in zip(axes, (("gyr", "rad_s", np.degrees(1.0), "gyroscope (deg/s)"),
                                                      ("acc", "m_s2", 1.0, "accelerometer (m/s$^2$)"),
                                                      ("mag", "uT", 1.0, "magnetometer ($\\mu$T)"))):
        for k, axis in enumerate("xyz"):
            ax.plot(t, columns[f"{sensor}_{axis}_{unit}"] * scale, lw=0.6, color=colours[k], label=axis)
        ax.set_ylabel(label)
    ax = axes[3]
    for k, angle in enumerate(("roll", "pitch", "heading")):
        ax.plot(t, columns[f"board_{angle}_deg"], lw=1.2, color=colours[k], label=f"{angle}: board")
        ax.plot(t, columns[f"fixed_{angle}_deg"], lw=0.8, ls="--", color="k", alpha=0.6,
                label="host fixed build" if k == 0 else None)
        ax.plot(t, columns[f"float_{angle}_deg"], lw=0.8, ls=":", color="0.4",
                label="float twin" if k == 0 else None)
    ax.set_ylabel("Euler angles (deg)")
    ax = axes[4]
    ax.plot(t, columns["fixed_float_angle_deg"], lw=0.8, color="tab:purple", label="fixed vs float twin")
    board_vs_fixed = angle_difference(*(np.stack([columns[f"{source}_q{p}"] for p in "wxyz"], axis=1)
                                        for source in ("board", "fixed")))
    ax.plot(t, board_vs_fixed, lw=0.8, color="tab:orange", label="board vs host fixed build")
    if different.any():
        ax.plot(t[different], board_vs_fixed[different], "o", ms=3, color="red", label="estimate differs")
    for start, stop in unverifiable:
        ax.axvspan(t[start], t[min(stop, len(t) - 1)], color="0.85", lw=0,
                   label="not verifiable" if start == unverifiable[0][0] else None)
    ax.set_ylabel("difference (deg)")
    ax = axes[5]
    for k, axis in enumerate("xyz"):
        ax.plot(t, np.degrees(columns[f"board_gyro_bias_{axis}_rad_s"]), lw=1.0, color=colours[k], label=axis)
    ax.set_ylabel("gyro bias estimate (deg/s)")
    ax.set_xlabel("time (s): sample index at the board's sample rate")
    for ax in axes:
        for when in restarts:
            ax.axvline(when, ls="--", lw=0.8, color="k", alpha=0.6)
        if len(lost):
            ax.plot(lost, np.full(len(lost), 0.0), "|", ms=12, color="red", transform=ax.get_xaxis_transform(),
                    label="lost sample" if ax is axes[0] else None)
        if len(recovered):
            ax.plot(recovered, np.full(len(recovered), 0.0), "|", ms=8, color="tab:orange",
                    transform=ax.get_xaxis_transform(), label="recovered sample" if ax is axes[0] else None)
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(fontsize=7, loc="upper right", ncol=4)
    damage = f"; {len(recording.damaged)} damaged span(s)" if recording.damaged else ""
    fig.suptitle(f"{Path(recording.path).name}: {len(t)} samples, {len(restarts) + 1} filter run(s), "
                 f"{len(lost)} lost sample(s), {len(recovered)} recovered{damage}; restarts dashed\n{verdict}",
                 fontsize=9)
    fig.savefig(path, format=fmt, dpi=100)

