"""The advisory's files in the session folder, written line by line and flushed, so a crash loses nothing.

- ``advisory.csv`` (generator): every generated buffer.
- ``playback.csv`` (player): every buffer that started playing, with the DAC time of its first sample.
- ``advisory_events.csv`` (both processes, appended): status changes, restarts, device problems, bad messages.

Times: ``wall_time`` is Unix time (s); ``*_mono`` are CLOCK_MONOTONIC seconds, shared by all processes on the
device, so the generator's and the player's rows can be joined and latencies computed.
"""

from __future__ import annotations

import csv
import math
import os
import time
from pathlib import Path

from seesys.errors import SeesysError

ADVISORY_CSV = "advisory.csv"
PLAYBACK_CSV = "playback.csv"
EVENTS_CSV = "advisory_events.csv"

ADVISORY_COLUMNS = ("wall_time", "time_mono", "condition", "status", "trigger", "input_value", "n_pulses",
                    "played_pulses", "buffer_id", "arrival_mono", "play_at_mono")
PLAYBACK_COLUMNS = ("wall_time", "buffer_id", "time_mono", "trigger", "n_pulses", "played_pulses", "arrival_mono",
                    "received_mono", "play_at_mono", "dac_mono", "stream_sample")
EVENT_COLUMNS = ("wall_time", "time_mono", "process", "event", "detail")


class CsvLog:
    """An appending CSV file with a header, flushed after every row."""

    def __init__(self, path: Path, columns: tuple[str, ...]):
        self.path = path
        self.columns = columns
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            try:
                # Exclusive creation: of two processes starting together, only one writes the header. O_APPEND
                # on both sides, so that their rows never overwrite each other.
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
                new = True
            except FileExistsError:
                fd = os.open(path, os.O_WRONLY | os.O_APPEND)
                new = False
            self._file = open(fd, "a", newline="", buffering=1)
        except OSError as e:
            raise SeesysError(f"cannot write the log {path}: {e}") from None
        self._writer = csv.writer(self._file)
        if new:
            self._writer.writerow(columns)

    def write(self, *values: object) -> None:
        self._writer.writerow([_cell(v) for v in values])
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def _cell(v: object) -> object:
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return v


class EventLog:
    """``advisory_events.csv``, shared by the generator and the player (each row is one appended write)."""

    def __init__(self, folder: Path, process: str):
        self._log = CsvLog(folder / EVENTS_CSV, EVENT_COLUMNS)
        self._process = f"{process}[{os.getpid()}]"

    def event(self, event: str, detail: str = "") -> None:
        self._log.write(time.time(), time.monotonic(), self._process, event, detail)

    def close(self) -> None:
        self._log.close()
