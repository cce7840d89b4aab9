"""The advisory's files in the session folder, written line by line and flushed, so a crash loses nothing.

- ``advisory.csv`` (generator): every generated buffer.
- ``playback.csv`` (player): every buffer that started playing, with the DAC time of its first sample.
- ``advisory_events.csv`` (both processes, appended): status changes, restarts, device problems, bad messages.

Times: ``wall_time`` is Unix time (s); ``*_mono`` are CLOCK_MONOTONIC seconds, shared by all processes on the
device, so the generator's and the player's rows can be joined and latencies computed.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from seesys.core.session_layout import EVENT_COLUMNS, EVENTS_CSV
from seesys.io.logfiles import CsvLog


class EventLog:
    """``advisory_events.csv``, shared by the generator and the player (each row is one appended write)."""

    def __init__(self, folder: Path, process: str):
        self._log = CsvLog(folder / EVENTS_CSV, EVENT_COLUMNS)
        self._process = f"{process}[{os.getpid()}]"

    def event(self, event: str, detail: str = "") -> None:
        self._log.write(time.time(), time.monotonic(), self._process, event, detail)

    def close(self) -> None:
        self._log.close()
