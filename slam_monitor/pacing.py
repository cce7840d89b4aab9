"""Feeding frames to ORB-SLAM3 at camera rate, and no faster than its mapping thread keeps up with.

Monocular ORB-SLAM3 needs its local-mapping thread to keep pace with tracking (new keyframes, new map points):
fed faster than the camera rate, or at camera rate on a CPU shared with other work, the mapping falls behind and
tracking is lost. :class:`FramePacer` therefore

1. spaces consecutive frames by at least their timestamp difference, measured from the previous feed (so a
   slow frame is not followed by a burst of catch-up frames), and
2. when ``wait_for_mapping`` is set and the CPU is contended (ORB-SLAM3's background threads spent at least
   ``contention_fraction`` of the time since the last feed runnable but waiting for a CPU), also waits, at
   most ``max_mapping_wait_s``, until those threads are idle: over ``idle_window_s`` they ran for less than
   ``idle_busy_fraction`` of it. Both come from ``/proc/self/task/<tid>/schedstat`` (Linux; elsewhere only
   step 1 applies). On a machine with a free core nothing changes; on a busy one an offline run slows down
   instead of losing track.

Live cameras and real-time playback are paced by their own clock and are not paced here.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
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


@dataclass(frozen=True)
class CpuTimes:
    running_ns: int
    queued_ns: int  # runnable but waiting for a CPU


class ThreadDemand:
    """CPU time of a set of this process's threads: running, and runnable but waiting for a CPU (queued)."""

    def __init__(self, ids: set[str]):
        self.ids = sorted(ids)

    def sample(self) -> CpuTimes | None:
        """The sums over the live threads, or ``None`` when the kernel does not report them."""
        running = queued = 0
        for tid in self.ids:
            try:
                fields = (TASKS / tid / "schedstat").read_text().split()
            except FileNotFoundError:
                continue  # the thread has ended
            except OSError:
                return None
            running += int(fields[0])
            queued += int(fields[1])
        return CpuTimes(running, queued)


class FramePacer:
    """Holds each frame back until it is due (see the module docstring); ``wait`` before each track call."""

    def __init__(self, config: PacingConfig, enabled: bool, background: ThreadDemand | None):
        self.config = config
        self.enabled = enabled
        self._background = background if config.wait_for_mapping and background and background.ids else None
        self._previous: tuple[float, float] | None = None  # (wall time fed, frame timestamp)
        self._fed_sample: CpuTimes | None = None
        self.mapping_wait_s = 0.0  # total time spent waiting beyond the camera rate, for the session record

    def _sleep_until(self, moment: float) -> None:
        delay = moment - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    def _sample(self) -> CpuTimes | None:
        if self._background is None:
            return None
        sample = self._background.sample()
        if sample is None:
            self._background = None  # not measurable here: pace by the camera rate alone
        return sample

    def _contended(self) -> bool:
        """Whether the background threads waited for a CPU for a noticeable part of the time since the last feed."""
        now = self._sample()
        if now is None or self._fed_sample is None or self._previous is None:
            return False
        elapsed_ns = (time.perf_counter() - self._previous[0]) * NS_PER_S
        return now.queued_ns - self._fed_sample.queued_ns >= self.config.contention_fraction * elapsed_ns

    def _background_idle(self) -> bool:
        """Whether the background threads ran for less than ``idle_busy_fraction`` of the next window.

        Run time, not queued time: an idle ORB-SLAM3 thread wakes every few milliseconds to poll its queue and,
        on a busy machine, waits in the run queue each time; a thread with work runs for a good part of any
        window, a polling one for microseconds.
        """
        before = self._sample()
        time.sleep(self.config.idle_window_s)
        after = self._sample() if before is not None else None
        if before is None or after is None:
            return True
        busy_ns = after.running_ns - before.running_ns
        return busy_ns < self.config.idle_busy_fraction * self.config.idle_window_s * NS_PER_S

    def wait(self, timestamp: float) -> None:
        if not self.enabled:
            return
        if self._previous is not None:
            due = self._previous[0] + (timestamp - self._previous[1])
            if self._background is None:
                self._sleep_until(due)
            else:
                # the idle check's window ends when the frame is due, so the camera rate is kept when all is idle
                self._sleep_until(due - self.config.idle_window_s)
                if self._contended():
                    give_up = due + self.config.max_mapping_wait_s
                    while not self._background_idle() and time.perf_counter() < give_up:
                        pass
                self._sleep_until(due)
                self.mapping_wait_s += max(0.0, time.perf_counter() - due)
        self._previous = (time.perf_counter(), timestamp)
        if self._background is not None:
            self._fed_sample = self._sample()
