"""Hardware in the loop: record a board, replay and compare a recording against the host
build of the same C, inject samples into a board, and the no-hardware demo.

- :mod:`recorder`: snapshot the board (HELLO, STATUS, every setting of the active filter),
  restart its filter, stream, and write every received byte to a recording. A lost SAMPLE
  makes the rest of a filter run impossible to reproduce, so the recorder asks the board to
  send lost frames again (``resend``: RESEND, the board keeps its input frames of about the
  last second at 1 kHz), and restarts the board's filter after a SAMPLE lost for good
  (``resync``): a new segment begins that can be verified again.
- :mod:`comparison`: re-run the recorded samples through the fixed-point build (what the
  board must have computed) and the float twin, with the recorded settings and sensor
  profile, and check every board estimate that can be verified (its segment's samples
  complete from index 0 up to it) bit for bit.
- :mod:`export`: the replay as CSV or NumPy arrays.
- :mod:`injection`: stream samples (a recording, a simulation, a BROAD .mat file) into a
  board in injection mode and compare every answer on the fly.
- :mod:`demo_job`: an emulated board (the firmware as a native process or the ARM image in
  QEMU, fed by the simulator), a recording of its simulated run, the comparison, and the
  accuracy against the simulated truth.
- :mod:`replica`: the board's filter run on the host (the fixed build), sample by sample.
"""
from imulink.hil.board_setup import (
    apply_settings,
    board_profile,
    check_profile,
    read_calibration,
    read_settings,
    set_calibration,
    setting_range,
    setting_range_text,
)
from imulink.hil.common import SETTLE_S, HilError
from imulink.hil.comparison import (
    MIN_VERIFIED,
    Comparison,
    Difference,
    HostRun,
    Verdict,
    compare,
    comparison_json,
    fixed_outputs,
    format_comparison,
    host_run,
    nav_inputs,
    nav_state_position,
)
from imulink.hil.demo_job import DemoReport, demo
from imulink.hil.export import export_csv, export_npz, replay_columns
from imulink.hil.injection import InjectionInput, InjectResult, format_inject, inject, load_injection_input
from imulink.hil.recorder import (
    CHECKPOINT_S,
    INTERRUPTED,
    RECONNECT_S,
    RECORD_COMMAND_ATTEMPTS,
    REOPEN_INTERVAL_S,
    SILENCE_MIN_S,
    SILENCE_PERIODS,
    RecordResult,
    default_silence_timeout,
    record,
    snapshot,
)
from imulink.hil.report import accuracy_json, link_json, link_summary

__all__ = [
    "accuracy_json",
    "apply_settings",
    "board_profile",
    "check_profile",
    "compare",
    "Comparison",
    "comparison_json",
    "default_silence_timeout",
    "demo",
    "DemoReport",
    "Difference",
    "export_csv",
    "export_npz",
    "fixed_outputs",
    "format_comparison",
    "format_inject",
    "HilError",
    "host_run",
    "HostRun",
    "inject",
    "InjectionInput",
    "InjectResult",
    "INTERRUPTED",
    "link_json",
    "link_summary",
    "load_injection_input",
    "MIN_VERIFIED",
    "nav_inputs",
    "nav_state_position",
    "read_calibration",
    "read_settings",
    "RECONNECT_S",
    "CHECKPOINT_S",
    "record",
    "RECORD_COMMAND_ATTEMPTS",
    "RecordResult",
    "REOPEN_INTERVAL_S",
    "replay_columns",
    "set_calibration",
    "setting_range",
    "setting_range_text",
    "SETTLE_S",
    "SILENCE_MIN_S",
    "SILENCE_PERIODS",
    "snapshot",
    "Verdict",
]
