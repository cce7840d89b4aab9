"""Crash-safe study files: whole files replaced atomically, logs appended one flushed line at a time.

A SIGKILL can stop the process between any two system calls. A file replaced with ``os.replace`` is then either
the old or the new version; a log line written by one ``write`` of a line-buffered file is either there or not.
Readers therefore never see a half-written JSON file, and a log loses at most the line being written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from seesys.core.errors import SeesysError


def write_text_atomically(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` (a temporary file beside it, then a rename)."""
    path = Path(path)
    temporary = path.with_name(path.name + ".tmp")
    with temporary.open("w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(temporary, path)


def write_json_atomically(path: Path, data: Any) -> None:
    write_text_atomically(path, json.dumps(data, indent=2, default=str) + "\n")


def open_log(path: Path, header: str) -> TextIO:
    """Open a line log for appending (line-buffered: every line is one write); a new file gets ``header``.

    Appending keeps whatever an earlier, interrupted run of the same session wrote.
    """
    path = Path(path)
    fresh = not path.exists() or path.stat().st_size == 0
    log = path.open("a", buffering=1, encoding="utf-8")
    if fresh:
        log.write(header + "\n")
    return log


def read_csv_log(path: Path, **read_csv_args: Any) -> pd.DataFrame:
    """A CSV log as a table, without a last line left unterminated by a crash (and without malformed rows)."""
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    if not text.strip():
        raise pd.errors.EmptyDataError(f"{path} is empty")
    return pd.read_csv(io.StringIO(text), on_bad_lines="skip", **read_csv_args)


def read_csv_table(path: Path, columns: tuple[str, ...]) -> pd.DataFrame:
    """A CSV file as a table; raises :class:`SeesysError` for a file that is missing, unreadable or without one of
    ``columns``."""
    try:
        table = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise SeesysError(f"cannot read {path}: {e}") from None
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise SeesysError(f"{path} has no column(s) {', '.join(missing)}")
    return table


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
