"""The processes a study session runs (device, advisory, mocap logger, estimate replay): ``seesys`` commands in
child processes whose output goes to the attempt's ``logs/<name>.log``, and which die with the runner.

Dying with the runner matters for crash safety: if ``seesys study run`` is killed (SIGKILL included), the kernel
sends each child SIGTERM (Linux ``PR_SET_PDEATHSIG``), so no device or logger keeps writing into a session the
operator believes stopped, and none holds a ZeroMQ endpoint the next session needs.
"""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from seesys.processes import die_with_parent

LOGS = "logs"


def seesys_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "seesys", *args]


@dataclass
class Child:
    name: str
    process: subprocess.Popen
    log: Path

    @classmethod
    def start(cls, name: str, args: list[str], folder: Path, env: dict[str, str] | None = None) -> Child:
        logs = folder / LOGS
        logs.mkdir(exist_ok=True)
        log = logs / f"{name}.log"
        with log.open("ab") as out:
            # A session of its own: the operator's Ctrl-C goes to the runner only (which stops the device
            # cleanly), and a child that does not stop can be killed with the processes it started.
            process = subprocess.Popen(seesys_command(*args), stdout=out, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, env=env or os.environ.copy(),
                                       preexec_fn=functools.partial(die_with_parent, os.getpid(), signal.SIGTERM),
                                       start_new_session=True)
        return cls(name, process, log)

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
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(self.process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            return self.process.wait()

    def last_line(self) -> str:
        try:
            lines = self.log.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return lines[-1] if lines else ""
