#!/usr/bin/env python3
"""The monitor's screenshot in the documentation (docs/monitor.png), taken against the
emulated board: `imulink monitor --emulate` (the native firmware, ESKF at 200 Hz, the
simulated "random" trajectory), rendered after --seconds and written as a PNG.

The window runs in a real X server (Xvfb, from tools/install-system-packages.sh) when
there is one, else with Qt's offscreen platform; either way with a settings directory of
its own, so the shot shows the default layout rather than the user's.

    .venv/bin/python tools/monitor_screenshot.py [--output docs/monitor.png] [--seconds 12]
    .venv/bin/python tools/monitor_screenshot.py --nav     # docs/monitor_nav.png: the nav filter
                                                           # on the simulated car drive, after 40 s
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def start_xvfb() -> tuple[subprocess.Popen, str] | None:
    """An Xvfb server on a free display number, or None when there is no Xvfb."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        return None
    read_end, write_end = os.pipe()
    # -displayfd: Xvfb picks a free display and writes its number when it is ready
    server = subprocess.Popen([xvfb, "-displayfd", str(write_end), "-screen", "0", "1600x1000x24", "-nolisten", "tcp"],
                              pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_end)
    with os.fdopen(read_end) as ready:
        display = ready.readline().strip()
    if not display:
        server.terminate()
        return None
    return server, f":{display}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output", help="PNG to write (default: docs/monitor.png, with --nav docs/monitor_nav.png)")
    parser.add_argument("--seconds", type=float, help="how long the board streams before the shot (default: 12 s, "
                                                      "with --nav 40 s)")
    parser.add_argument("--nav", action="store_true", help="the nav filter on the car drive (GNSS, barometer) at "
                                                           "100 Hz, its track and height shown")
    parser.add_argument("--offscreen", action="store_true", help="Qt's offscreen platform even where Xvfb is")
    args = parser.parse_args()
    args.output = args.output or str(ROOT / "docs" / ("monitor_nav.png" if args.nav else "monitor.png"))
    args.seconds = args.seconds if args.seconds is not None else (40.0 if args.nav else 12.0)
    board = (["--filter", "nav", "--rate", "100", "--scenario", "car"] if args.nav
             else ["--filter", "eskf", "--rate", "200", "--scenario", "random"])

    xvfb = None if args.offscreen else start_xvfb()
    with tempfile.TemporaryDirectory(prefix="imulink-shot-") as config:
        env = dict(os.environ, XDG_CONFIG_HOME=config)
        if xvfb is not None:
            env.update(DISPLAY=xvfb[1], QT_QPA_PLATFORM="xcb")
        else:
            env["QT_QPA_PLATFORM"] = "offscreen"
        command = [sys.executable, "-m", "imulink.cli", "monitor", "--emulate", *board, "--duration", "120",
                   "--seed", "3", "--screenshot", args.output, "--exit-after", str(args.seconds)]
        started = time.monotonic()
        try:
            status = subprocess.run(command, env=env, cwd=ROOT).returncode
        finally:
            if xvfb is not None:
                xvfb[0].terminate()
                xvfb[0].wait()
    where = f"Xvfb {xvfb[1]}" if xvfb is not None else "offscreen"
    print(f"{args.output}: {'written' if status == 0 else f'FAILED (exit status {status})'} ({where}, "
          f"{time.monotonic() - started:.1f} s)")
    return status


if __name__ == "__main__":
    sys.exit(main())
