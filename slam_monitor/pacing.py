"""Feeding frames to ORB-SLAM3 at camera rate, and no faster than its mapping thread keeps up with.

Monocular ORB-SLAM3 needs its local-mapping thread to keep pace with tracking (new keyframes, new map points):
fed faster than the camera rate, or at camera rate on a CPU shared with other work, the mapping falls behind and
tracking is lost. :class:`FramePacer` therefore

1. spaces consecutive frames by at least their timestamp difference, measured from the previous feed (so a
   slow frame is not followed by a burst of catch-up frames), and
2. when ``wait_for_mapping`` is set, also waits, at most ``max_mapping_wait_s``, until ORB-SLAM3's background
   threads are idle: over ``idle_window_s`` they ran for less than ``idle_busy_fraction`` of it
   (``/proc/self/task/<tid>/schedstat``, Linux). On a quiet machine mapping is idle by the
   time the next frame is due, so this costs nothing; on a busy one it slows an offline run down instead of
   losing track.

Live cameras and real-time playback are paced by their own clock and are not paced here.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from slam_monitor.orbslam_settings import PacingConfig

TASKS = Path("/proc/self/task")
NS_PER_S = 1e9


def thread_ids() -> set[str]:
    """Ids of this process's threads (empty where ``/proc`` has no task list)."""
    try:
        return set(os.listdir(TASKS))
    except OSError:
        return set()


class ThreadDemand:
    """Nanoseconds a set of this process's threads spent running on a CPU.

    Run time, not time runnable: an idle ORB-SLAM3 thread wakes every few milliseconds to poll its queue, and on
    a busy machine each wake-up waits in the run queue, which would make it look busy. A thread with work gets
    its fair share of a CPU and runs for most of any window; a polling one runs for microseconds.
    """

    def __init__(self, ids: set[str]):
        self.ids = sorted(ids)

    def total_ns(self) -> int | None:
        """The sum over the live threads, or ``None`` when the kernel does not report it."""
        total = 0
        for tid in self.ids:
            try:
                running = (TASKS / tid / "schedstat").read_text().split()[0]
            except FileNotFoundError:
                continue  # the thread has ended
            except (OSError, ValueError):
                return None
            total += int(running)
        return total


class FramePacer:
    """Holds each frame back until it is due (see the module docstring); ``wait`` before each track call."""

    def __init__(self, config: PacingConfig, enabled: bool, background: ThreadDemand | None):
        self.config = config
        self.enabled = enabled
        self._background = background if config.wait_for_mapping and background and background.ids else None
        self._previous: tuple[float, float] | None = None  # (wall time fed, frame timestamp)
        self.mapping_wait_s = 0.0  # total time spent waiting beyond the camera rate, for the session record

    def _sleep_until(self, moment: float) -> None:
        delay = moment - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    def _background_idle(self) -> bool:
        before = self._background.total_ns()
        time.sleep(self.config.idle_window_s)
        after = self._background.total_ns()
        if before is None or after is None:
            self._background = None  # not measurable here: pace by the camera rate alone
            return True
        return after - before < self.config.idle_busy_fraction * self.config.idle_window_s * NS_PER_S

    def wait(self, timestamp: float) -> None:
        if not self.enabled:
            return
        if self._previous is not None:
            due = self._previous[0] + (timestamp - self._previous[1])
            if self._background is None:
                self._sleep_until(due)
            else:
                # the idle check's window ends when the frame is due, so a quiet machine keeps the camera rate
                self._sleep_until(due - self.config.idle_window_s)
                give_up = due + self.config.max_mapping_wait_s
                while not self._background_idle() and time.perf_counter() < give_up:
                    pass
                self._sleep_until(due)
                self.mapping_wait_s += max(0.0, time.perf_counter() - due)
        self._previous = (time.perf_counter(), timestamp)
