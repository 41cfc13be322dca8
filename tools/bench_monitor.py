#!/usr/bin/env python3
"""Benchmark of `imulink monitor` (a measurement, not a test); results in docs/monitor.md.

Against the emulated board streaming in real time at --rate (default 1 kHz, the ESKF, so
that every plot has data), with every curve visible, Qt offscreen:

- the cost of one frame: the window's redraw (reading the ring buffers, giving every
  curve its data, the panels) and the paint it causes, measured as one redraw() plus the
  processEvents() that paints it, for each time span: the CPU time of the GUI thread
  (the cost, whatever else the machine runs) and the wall time (what it took here, with
  the link's threads and other processes competing); median and 95th percentile in ms
  (the target is 16 ms: a frame at 60 Hz; the window draws at 30 Hz);
- the monitor process's CPU share (user + system time of this process, the link's reader
  thread and the worker included, over wall time; the emulated board is another process)
  while it shows the 1 kHz stream with its timer at 30 frames/s, and while idle: the board
  connected with its stream stopped.

    .venv/bin/python tools/bench_monitor.py [--rate 1000] [--seconds 10]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time

import numpy as np

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def cpu_share(app, seconds: float) -> float:
    """This process's CPU time over wall time while the Qt event loop runs for `seconds`."""
    start_cpu, start = time.process_time(), time.monotonic()
    while time.monotonic() - start < seconds:
        app.processEvents()
        time.sleep(0.002)
    return (time.process_time() - start_cpu) / (time.monotonic() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=1000.0, help="sample rate of the emulated board, Hz")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds per measurement")
    parser.add_argument("--frames", type=int, default=150, help="frames timed per time span")
    args = parser.parse_args()
    os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="imulink-bench-")  # the default layout

    from imulink.board.emulator import EmulatedBoard
    from imulink.monitor.qt import QtWidgets
    from imulink.monitor.sources import LiveSource
    from imulink.monitor.window import FRAME_HZ, SPANS_S, MonitorWindow

    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication([])
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, Python "
          f"{platform.python_version()}, Qt platform {app.platformName()}")
    with EmulatedBoard(front="tcp", duration_s=600.0, rate_hz=args.rate, realtime=True,
                       filter_name="eskf") as board:
        window = MonitorWindow(LiveSource(board.address), "benchmark")
        window.show()
        source = window.source
        while source.samples.appended < max(SPANS_S) * args.rate:  # fill the longest span
            app.processEvents()
            time.sleep(0.01)
            if source.health().state == "disconnected":
                print(f"the board is gone: {source.health().detail}", file=sys.stderr)
                return 2
        print(f"input: {args.rate:g} Hz, ESKF, {len(window.curves)} curves in {len(window.plots)} plots, all visible")
        window.timer.stop()
        for span in SPANS_S:
            window.span_box.setCurrentIndex(window.span_box.findData(span))
            wall, cpu = [], []
            for _ in range(args.frames):
                started, started_cpu = time.perf_counter(), time.thread_time()
                window.redraw()
                app.processEvents()
                wall.append(time.perf_counter() - started)
                cpu.append(time.thread_time() - started_cpu)
                time.sleep(1 / FRAME_HZ)  # data arrive between frames, as with the window's timer
            wall, cpu = np.array(wall) * 1e3, np.array(cpu) * 1e3
            print(f"frame, span {span:4g} s ({int(span * args.rate):5d} samples per curve): CPU median "
                  f"{np.median(cpu):5.1f} ms, 95th percentile {np.percentile(cpu, 95):5.1f} ms; wall median "
                  f"{np.median(wall):5.1f} ms, 95th percentile {np.percentile(wall, 95):5.1f} ms")
        window.span_box.setCurrentIndex(window.span_box.findData(10.0))
        window.timer.start(int(1000 / FRAME_HZ))
        streaming = cpu_share(app, args.seconds)
        source.request("stop_stream")
        cpu_share(app, 1.0)  # the stop travels
        idle = cpu_share(app, args.seconds)
        print(f"CPU share of the monitor process, {FRAME_HZ} frames/s, span 10 s: {100 * streaming:.0f} % of one core "
              f"showing the {args.rate:g} Hz stream, {100 * idle:.1f} % idle (stream stopped)")
        window.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
