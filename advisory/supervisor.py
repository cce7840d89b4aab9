"""``seesys advisory run``: start the generator and the player as two processes and keep them running.

The player is left out in the silent ``none`` condition. The audio device is checked before anything starts, so a
missing one is a clear error at once. A process that exits is logged in ``advisory_events.csv`` and restarted
after ``restart_delay_s``; the other one carries on (the hand-off reconnects by itself). Only a process that fails
with a SEESys error (status 2: configuration, device, endpoint) the first time it starts stops the run.
"""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

from advisory.audio_device import check_output_device
from advisory.conditions import Condition
from advisory.config import AdvisoryConfig
from advisory.logs import EventLog
from advisory.process import advisory_command
from seesys.core.errors import SeesysError

_SEESYS_ERROR_EXIT = 2
_STOP_TIMEOUT_S = 5.0


def process_commands(condition: Condition, out: Path) -> dict[str, list[str]]:
    """The command line of each process of a condition."""
    commands = {"generator": advisory_command("generator", "--condition", condition.value, "--out", str(out))}
    if condition.audible:
        commands["player"] = advisory_command("player", "--out", str(out))
    return commands


def supervise(cfg: AdvisoryConfig, condition: Condition, out: Path, stop: threading.Event) -> None:
    if condition.audible:
        check_output_device(cfg.audio)
    commands = process_commands(condition, out)
    events = EventLog(out, "supervisor")
    events.event("started", f"condition={condition.value}")
    processes = {name: subprocess.Popen(command) for name, command in commands.items()}
    restarted: set[str] = set()
    try:
        while not stop.wait(0.2):
            for name, proc in list(processes.items()):
                code = proc.poll()
                if code is None:
                    continue
                if code == _SEESYS_ERROR_EXIT and name not in restarted:
                    raise SeesysError(f"the advisory {name} could not start (its error is printed above)")
                events.event(f"{name} exited", f"status {code}; restarting in {cfg.supervisor.restart_delay_s} s")
                if stop.wait(cfg.supervisor.restart_delay_s):
                    break
                processes[name] = subprocess.Popen(commands[name])
                restarted.add(name)
                events.event(f"{name} restarted", f"pid {processes[name].pid}")
    finally:
        for proc in processes.values():
            proc.terminate()
        deadline = time.monotonic() + _STOP_TIMEOUT_S
        for proc in processes.values():
            try:
                proc.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
        events.event("stopped")
        events.close()
