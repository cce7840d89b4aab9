"""Process plumbing shared by the generator, the player and the supervisor."""

from __future__ import annotations

import signal
import sys
import threading


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT, so a process ends its loop and closes its logs instead of dying."""
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def advisory_command(*args: str) -> list[str]:
    """The command line of ``seesys advisory ARGS`` with this interpreter."""
    return [sys.executable, "-m", "seesys", "advisory", *args]
