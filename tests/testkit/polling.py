"""Waiting on a condition in tests: the one polling loop, with a generous deadline because the machine may be
shared and loaded. Tests synchronise on what happened (a log row, a message, a process state), never on sleeps."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(
    condition: Callable[[], object],
    timeout_s: float = 120,
    what: str | Callable[[], str] = "condition",
    interval_s: float = 0.02,
) -> object:
    """Poll ``condition`` every ``interval_s`` until it returns something true, and return that; fail the test
    after ``timeout_s``, saying what did not happen (``what``, or what it returns, read at the timeout)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what() if callable(what) else what}")
        time.sleep(interval_s)  # the polling interval, not a synchronisation
