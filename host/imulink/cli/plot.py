"""`imulink plot`."""
from __future__ import annotations

from imulink import hil
from imulink.analysis import plotting
from imulink.cli.common import one_line_errors
from imulink.io.files import check_output, write_replacing
from imulink.io.recording import load_recording


@one_line_errors
def run(args) -> int:
    plotting.plot_format(args.output)  # before the work: a figure that cannot be written is known at once
    plotting.check_plotting()
    check_output(args.output, inputs=[args.file])
    recording = load_recording(args.file)
    run = hil.host_run(recording)
    comparison = hil.compare(recording, run)
    columns = hil.replay_columns(recording, run, comparison)
    verdict = hil.format_comparison(recording, comparison).splitlines()
    line = next((text for text in verdict if text.startswith("bit-exact")), verdict[-1])
    write_replacing(args.output, lambda path: plotting.plot_recording(recording, columns, line, path),
                    inputs=[args.file])
    print(f"plot: {args.output} ({len(recording.samples)} samples; {line})")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "plot", help="a recording as a figure (PNG or SVG): sensors, attitudes, differences, events",
        description="Draw a recording to one figure, without a display: the raw sensors in SI units; the Euler "
                    "angles of the board, the host fixed build and the float twin; the board-vs-host and "
                    "fixed-vs-float differences; the gyro-bias estimate; with filter restarts (dashed lines), lost "
                    "samples (red ticks), estimates the host could not verify (grey) or that differ (red dots) "
                    "marked, and the bit-exact verdict in the title. The format follows the name (.png, .svg); "
                    "needs matplotlib: pip install 'imulink[plot]'.")
    p.add_argument("file", metavar="FILE", help="recording written by `imulink record` or `imulink demo`")
    p.add_argument("--output", "-o", required=True, metavar="FILE.png|FILE.svg", help="the figure to write")
    p.set_defaults(func=run)

