"""Following a board's stream: which filter runs, with which settings and calibration, and
where each filter run (a segment) begins and whether it is still complete.

One reading of the stream for every user: the recording loader (which places each frame in
its segment), the recorder (which restarts the board's filter after a lost SAMPLE) and the
live monitor's check (which runs the host build beside the board).

A filter run begins at sample index 0: after the ACK of a command that restarts the filter
(protocol.RESTARTING_COMMANDS), after a HELLO with sequence number 0 (the board started up
or was reset), or where the sample index goes backwards (a restart whose ACK was lost). A run
is complete while every SAMPLE from index 0 has arrived (live, or sent again after it was lost
on the way: :meth:`StreamFollower.recover`): the host can reproduce its estimates only then.
"""
from __future__ import annotations

from imulink import protocol

#: Frames that belong to one sample of a filter run (their `index` is the sample's).
RUN_FRAMES = frozenset({"SAMPLE", "ESTIMATE", "BARO", "GNSS", "NAV_STATE", "MARKER", "CHECKPOINT"})
#: Lost SAMPLEs listed one by one for recovery; a longer gap (a board whose stream was joined
#: late) leaves its run incomplete for good.
MAX_LISTED_GAP = 1 << 16
_RESTARTING_IDS = frozenset(protocol.COMMAND_IDS[name] for name in protocol.RESTARTING_COMMANDS)


class StreamFollower:
    """Feed it every decoded message in arrival order (:meth:`follow`).

    segment: the current filter run's number (0 for the first).
    complete: every SAMPLE of the current run has arrived, from index 0 on.
    missing_samples: the indices of the current run's SAMPLEs that have not arrived (lost on
      the way, until they are recovered).
    filter_id: the active filter as the board last reported it (STATUS, SETTING, ESTIMATE);
      None before any report.
    settings: filter id -> setting index -> SETTING fields, the last reported.
    calibration: (sensor code, axis) -> CALIBRATION fields, the last reported.
    settings_since_reset / calibration_since_reset: the same, reported since the board last
      started (what it holds now; a reset brings back defaults this host has not seen).
    hello / status: the first HELLO and STATUS.
    restarted_by: why the current run began: "start", "command" (a restarting command's ACK;
      its fields in `restart_ack`), "reset" (HELLO with sequence number 0) or "index" (the
      sample index went backwards).
    """

    def __init__(self) -> None:
        self.segment = 0
        self.filter_id: int | None = None
        self.settings: dict[int, dict[int, dict]] = {}
        self.calibration: dict[tuple[int, int], dict] = {}
        self.settings_since_reset: dict[int, dict[int, dict]] = {}
        self.calibration_since_reset: dict[tuple[int, int], dict] = {}
        self.hello: dict | None = None
        self.status: dict | None = None
        self.restarted_by = "start"
        self.restart_ack: dict | None = None
        self._last_index: int | None = None  # the last run frame's index in this run; None: none yet
        self._next_sample = 0  # the index after the last SAMPLE of this run
        self.missing_samples: set[int] = set()
        self._recovered_ahead: set[int] = set()  # recovered SAMPLEs not passed by a live one yet
        self._beyond_recovery = False  # a gap too long to list: the run stays incomplete

    @property
    def complete(self) -> bool:
        return not self.missing_samples and not self._beyond_recovery

    def follow(self, message: protocol.Message) -> int | None:
        """Take the next message; the segment of a run frame (RUN_FRAMES), None for others."""
        name, fields = message.name, message.fields
        if name in RUN_FRAMES:
            return self._place(name, fields)
        if name == "ACK" and fields["command"] in _RESTARTING_IDS:
            self.restart_ack = fields
            self._restart("command")
        elif name == "HELLO":
            self.hello = self.hello or fields
            if message.seq == 0:
                self.settings_since_reset.clear()
                self.calibration_since_reset.clear()
                self._restart("reset")
        elif name == "STATUS":
            self.status = self.status or fields
            self.filter_id = fields["active_filter"]
        elif name == "SETTING":
            self.filter_id = fields["filter_id"]
            for settings in (self.settings, self.settings_since_reset):
                settings.setdefault(fields["filter_id"], {})[fields["index"]] = fields
        elif name == "CALIBRATION":
            for calibration in (self.calibration, self.calibration_since_reset):
                calibration[fields["sensor"], fields["axis"]] = fields
        return None

    def note_setting(self, filter_id: int, index: int, value: int) -> None:
        """A setting's raw value that this client set (its SET_SETTING was ACKed): known without
        a SETTING frame."""
        for table in (self.settings, self.settings_since_reset):
            reported = table.setdefault(filter_id, {}).get(index, {})
            table[filter_id][index] = {**reported, "filter_id": filter_id, "index": index, "value": value}

    def note_filter(self, filter_id: int) -> None:
        """The active filter that this client selected (its SELECT_FILTER was ACKed)."""
        self.filter_id = filter_id

    def _restart(self, why: str) -> None:
        """A new filter run begins with the next run frame (none came since the last restart: the same run)."""
        if self._last_index is not None:
            self.segment += 1
            self._last_index = None
        self.restarted_by = why
        self._next_sample = 0
        self.missing_samples = set()
        self._recovered_ahead = set()
        self._beyond_recovery = False

    def resume_at(self, index: int) -> None:
        """A checkpoint of the board's filter state after sample `index` of this run arrived
        whole: the host resumes verification there, so the SAMPLEs lost before it no longer
        make the run incomplete."""
        self.missing_samples = {i for i in self.missing_samples if i > index}

    def recover(self, message: protocol.Message) -> None:
        """A frame of this run that was lost on the way and sent again (RESENT), arriving
        after the live frames that followed it: a SAMPLE fills its gap."""
        if message.name != "SAMPLE":
            return
        index = message.fields["index"]
        if index >= self._next_sample:
            self._recovered_ahead.add(index)  # it came back before a later SAMPLE showed it missing
        self.missing_samples.discard(index)

    def _place(self, name: str, fields: dict) -> int:
        index = fields["index"]
        if self._last_index is not None and index < self._last_index:
            self._restart("index")
        self._last_index = index
        if name == "SAMPLE":
            if index < self._next_sample:
                self._beyond_recovery = True  # a SAMPLE again: this run is not what the host can reproduce
            elif index - self._next_sample > MAX_LISTED_GAP:
                self._beyond_recovery = True
            else:  # SAMPLEs were lost: the rest of this run cannot be reproduced unless they come again
                self.missing_samples.update(set(range(self._next_sample, index)) - self._recovered_ahead)
            if self._recovered_ahead:
                self._recovered_ahead = {i for i in self._recovered_ahead if i > index}
            self._next_sample = max(self._next_sample, index + 1)
        elif name == "ESTIMATE":
            self.filter_id = fields["filter_id"]
        return self.segment
