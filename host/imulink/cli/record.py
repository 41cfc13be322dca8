"""`imulink record`."""
from __future__ import annotations

from imulink import hil
from imulink.cli.common import (
    EXIT_INTERRUPTED,
    in_range,
    json_argument,
    one_line_errors,
    port_arguments,
    positive_float,
    print_json,
    profile_list,
    profile_named,
    settings_argument,
    settings_from_file,
)
from imulink.progress import StatusLine

_reconnect_wait = in_range(float, 0.0, 86400.0, "must be a number of seconds from 0 to 86400")
_checkpoint_interval = in_range(float, 0.0, 3600.0, "must be a number of seconds from 0 to 3600")


@one_line_errors
def run(args) -> int:
    result = hil.record(args.port, args.output, duration_s=args.duration, baud=args.baud, profile=args.profile,
                        resync=not args.no_resync, silence_timeout_s=args.silence_timeout, force=args.force,
                        progress=StatusLine(), settings=settings_from_file(args), reconnect_s=args.reconnect,
                        listen=args.listen, resend=not args.no_resend, checkpoint_s=args.checkpoint)
    if args.json:
        print_json(result.to_json())
        return EXIT_INTERRUPTED if result.interrupted else 0
    print(f"recorded {result.samples} samples and {result.estimates} estimates of {result.filter_name} in "
          f"{result.duration_s:.1f} s to {result.path} ({result.stop_reason}); "
          f"{hil.link_summary(result.counters)}"
          + _recovery_summary(result.recovery)
          + (f"; filter restarts after lost samples: {result.filter_restarts}" if result.filter_restarts else "")
          + (f"; {result.checkpoints} checkpoints of the filter state" if result.checkpoints else "")
          + (f"; the board came back {result.reconnects} time(s), each a new segment" if result.reconnects else ""))
    return EXIT_INTERRUPTED if result.interrupted else 0


def _recovery_summary(recovery: dict) -> str:
    """What became of the frames lost on the way ('' when none were)."""
    if not recovery.get("lost"):
        return ""
    samples = recovery["recovered_messages"].get("SAMPLE", 0)
    lost_for_good = recovery["gone"] + recovery["unanswered"] + recovery["outstanding"]
    return (f"; lost on the way {recovery['lost']} frames: {recovery['recovered']} recovered ({samples} samples), "
            f"{recovery['not_kept']} outputs the board does not keep, {lost_for_good} lost for good")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "record", help="record a board's stream to a file",
        description="Connect (GET_VERSION -> HELLO, schema hash checked), write the board's HELLO, STATUS and "
                    "every setting of its active filter into the recording, restart the filter so the "
                    "recording starts at sample 0, then stream and capture every received byte with its host "
                    "time until --duration, the end of the board's stream, or Ctrl-C (exit status 130). The file "
                    "is append-only and flushed as it grows: after a crash, a disconnect, a silent board or a "
                    "full disk everything received before is kept, and the command ends with one line saying "
                    "so (exit status 2). The file takes its name only once the board has answered. Frames lost "
                    "on the way are asked for again (RESEND; the board keeps its input frames of about the last "
                    "second at 1 kHz) and go into the file, marked as recovered (unless --no-resend). The board "
                    "sends its filter's whole state every second (--checkpoint): after a SAMPLE lost for good, "
                    "verification resumes there; a board without checkpoints has its filter restarted instead "
                    "(unless --no-resync), so that the rest of the recording can still be verified bit for bit.")
    port_arguments(p)
    p.add_argument("--output", "-o", required=True, help="recording file to write (e.g. run.imulog); an existing "
                                                          "file is refused unless --force")
    p.add_argument("--force", action="store_true", help="replace an existing output file (once the board has "
                                                        "answered: a wrong port leaves it untouched)")
    p.add_argument("--duration", type=positive_float, help="seconds to record (default: until the stream ends "
                                                           "or Ctrl-C)")
    p.add_argument("--silence-timeout", type=positive_float, metavar="S",
                   help=f"seconds without a frame after which the board counts as silent: the recording ends "
                        f"with an error (default: {hil.SILENCE_MIN_S:g} s or {hil.SILENCE_PERIODS} sample periods "
                        "at the board's rate, whichever is longer)")
    p.add_argument("--profile", type=profile_named, default=None,
                   help=f"refuse a board that states another sensor profile than this one, before a file is "
                        f"written (default: whatever the board states; profiles: {profile_list()})")
    p.add_argument("--no-resync", action="store_true", help="never restart the filter after a lost sample")
    p.add_argument("--checkpoint", type=_checkpoint_interval, default=hil.CHECKPOINT_S, metavar="S",
                   help=f"the board sends its filter's whole state every S seconds of samples (CHECKPOINT), from "
                        f"which verification resumes after a sample lost for good, instead of a filter restart "
                        f"(default: {hil.CHECKPOINT_S:g}; 0: none)")
    p.add_argument("--no-resend", action="store_true",
                   help="never ask the board again for frames lost on the way (a lost sample is then lost for "
                        "good: verification resumes at the next checkpoint)")
    p.add_argument("--listen", action="store_true",
                   help="record a board that another client commands (the TCP front of imulink emulate or imulink "
                        "proxy takes several clients: the first commands, the others listen) without sending it "
                        "anything; estimates verify from the next filter run that starts at sample 0")
    p.add_argument("--reconnect", type=_reconnect_wait, default=hil.RECONNECT_S, metavar="S",
                   help=f"wait up to S seconds for a board that went away (its port failed: a USB re-enumeration) "
                        f"or started again (a reset) to come back, then go on in a new segment of the same file "
                        f"(default: {hil.RECONNECT_S:g}; 0: end the recording)")
    json_argument(p, "the summary")
    settings_argument(p, "the board gets them (its filter made active) before recording")
    p.set_defaults(func=run)

