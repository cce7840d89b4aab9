"""Turns at a device's pace, for the benchmarks that time work as a device does it: one every period, asleep in
between (imported by the benchmark scripts beside it)."""

from __future__ import annotations

import time
from collections.abc import Iterator


def paced(count: int, period_s: float) -> Iterator[int]:
    """``count`` turns, one every ``period_s``: sleeps until each is due (a turn that ran late is not followed by a
    burst: the next is due one period after the last was due, or at once)."""
    due = time.perf_counter()
    for k in range(count):
        due += period_s
        wait = due - time.perf_counter()
        if wait > 0:  # a turn already due (a period of 0: back to back) goes at once, without a sleep call
            time.sleep(wait)
        yield k
