"""Process plumbing shared by the generator, the player and the supervisor."""

from __future__ import annotations

import signal
import sys
import threading


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT, so a process ends its loop and closes its logs instead of dying."""
    stop = threading.Event()
    # The handler runs in the main thread between two bytecodes, possibly while that thread is inside
    # stop.wait() holding the event's internal lock; setting the event there would deadlock on that lock, so a
    # short-lived thread sets it instead.
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: threading.Thread(target=stop.set, daemon=True).start())
    return stop


def advisory_command(*args: str) -> list[str]:
    """The command line of ``seesys advisory ARGS`` with this interpreter."""
    return [sys.executable, "-m", "seesys", "advisory", *args]
