"""The processes a supervisor runs (``seesys run`` and ``seesys study run``: device, estimator, advisory, mocap
logger, estimate replay; ``seesys study simulate``: a simulated session each): ``seesys`` commands in child
processes whose output goes to the session's ``logs/<name>.log`` and which die with their supervisor; and the readers
of the logs those children grow.

Dying with the supervisor matters for crash safety: if it is killed (SIGKILL included), the kernel sends each child
SIGTERM (Linux ``PR_SET_PDEATHSIG``), so no device or logger keeps writing into a session the operator believes
stopped, and none holds a ZeroMQ endpoint the next session needs.
"""

from __future__ import annotations

import contextlib
import csv
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from seesys.io.processes import dying_with_parent

LOGS = "logs"


def seesys_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "seesys", *args]


@dataclass
class Child:
    name: str
    process: subprocess.Popen
    log: Path | None  # None: its output goes to this process's own

    @classmethod
    def start(
        cls, name: str, args: list[str], folder: Path, env: dict[str, str] | None = None, log: bool = True
    ) -> Child:
        """``seesys ARGS`` as a child named ``name``, its output appended to ``folder/logs/<name>.log`` (``log``
        false: to this process's own output)."""
        path = None
        if log:
            (folder / LOGS).mkdir(exist_ok=True)
            path = folder / LOGS / f"{name}.log"
        with path.open("ab") if path is not None else contextlib.nullcontext() as out:
            # A session of its own: the operator's Ctrl-C goes to the supervisor only (which stops the device
            # cleanly), and a child that does not stop can be killed with the processes it started.
            process = subprocess.Popen(
                dying_with_parent(seesys_command(*args), signal.SIGTERM),
                stdout=out,
                stderr=subprocess.STDOUT if out else None,
                stdin=subprocess.DEVNULL,
                env=env or os.environ.copy(),
                start_new_session=True,
            )
        return cls(name, process, path)

    @property
    def running(self) -> bool:
        return self.process.poll() is None

    def signal(self, sig: int) -> None:
        if self.running:
            self.process.send_signal(sig)

    def stop(self, timeout_s: float) -> int:
        """SIGTERM, then, after ``timeout_s``, SIGKILL to the child and every process it started; returns the
        exit status."""
        self.signal(signal.SIGTERM)
        return self.wait_or_kill(timeout_s)

    def wait_or_kill(self, timeout_s: float) -> int:
        """The exit status, after :meth:`kill` if the child has not exited within ``timeout_s``."""
        try:
            return self.process.wait(max(0.0, timeout_s))
        except subprocess.TimeoutExpired:
            return self.kill()

    def kill(self) -> int:
        """SIGKILL to the child and every process it started; returns the exit status."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)
        return self.process.wait()

    def interrupt(self, timeout_s: float) -> int:
        """SIGINT (a device ends its source and closes its files), and :meth:`stop` if it has not exited after
        ``timeout_s``; returns the exit status."""
        self.signal(signal.SIGINT)
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return self.stop(timeout_s)

    def last_line(self) -> str:
        """The last line of the child's log ("" without one)."""
        if self.log is None:
            return ""
        try:
            lines = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return lines[-1] if lines else ""


def last_line(path: Path) -> str:
    """The last complete line of a growing CSV log ("" when none, or when it is the header)."""
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            lines = f.read().decode(errors="replace").split("\n")
    except OSError:
        return ""
    complete = lines[:-1]  # the part after the last newline may be half-written
    return complete[-1] if complete and not complete[-1].startswith(("frame_index", "wall_time")) else ""


class LogTail:
    """The complete lines a growing log gained since the last call (a half-written last line waits for its end),
    reading only what was added."""

    def __init__(self, path: Path):
        self.path = path
        self._offset = 0
        self._partial = b""

    def new_lines(self) -> list[str]:
        try:
            with self.path.open("rb") as f:
                f.seek(self._offset)
                added = f.read()
        except OSError:
            return []
        self._offset += len(added)
        lines = (self._partial + added).split(b"\n")
        self._partial = lines.pop()
        return [line.decode(errors="replace") for line in lines]


class CsvTail(LogTail):
    """The complete rows a growing CSV log (header first) gained since the last call, as dicts by column."""

    def __init__(self, path: Path):
        super().__init__(path)
        self.columns: list[str] | None = None

    def new_rows(self) -> list[dict[str, str]]:
        rows = []
        for values in csv.reader(self.new_lines()):
            if self.columns is None:
                self.columns = values
            elif len(values) == len(self.columns):
                rows.append(dict(zip(self.columns, values)))
        return rows


class RowCounter:
    """Complete data rows of a growing log (lines after the header), reading only what was added since the
    last call."""

    def __init__(self, path: Path):
        self.path = path
        self._tail = LogTail(path)
        self._lines = 0

    def __call__(self) -> int:
        self._lines += len(self._tail.new_lines())
        return max(0, self._lines - 1)
