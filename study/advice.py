"""What the advice cost and how right it was, per session: mean speed, false alarms and misses.

- **Mean speed**: the reference trajectory's path length over the task, divided by its duration. The reference is
  sampled every ``speed_sample_s`` first, so that motion-capture jitter (millimetres at 100 Hz) does not add
  length. An advisory that only slows everyone down shows here and in time on task.
- **Warning share**: the share of the task's buffers (from the first error pair to the task's end) that played
  pulses: how much an advisory sounded, which a ``yoked`` or a rate-matched ``motion`` control matches.
- **False alarms and misses**: each advisory buffer of the task (``advisory.csv``: one per 1/3 s, and one per
  change) against the true error of the moment it stands for, the mean of the tracking error's pairs (RPE, the study's
  error, which is the pose-error label the estimates were trained on, monocular included:
  ``seesys.core.labels.stretch_errors``) that ended in the buffer's window. A buffer *warned* when it played pulses. The
  false-alarm rate is the share of buffers with a true error below α (silence is right: Equation 2's "error below α")
  that warned; the miss rate is the share of buffers with a true error of at least ``advice_high_error_m`` that were
  silent. In the ``none`` condition nothing is played: it misses every high error, which is the baseline. Buffers whose
  window holds no pair (tracking lost, before initialisation) count in neither.

The advisory's clock is mapped to the camera's with the session's estimate log (``receipt_time`` against
``timestamp``), as the analysis's plots do; a simulated session has one clock for both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from seesys.core.trajectory import Poses


@dataclass(frozen=True)
class AdviceOutcome:
    """Buffer counts of one session: true error low (below α) and of those warned; high and of those silent; and
    every buffer of the task and of those warned (whether or not a pair judged it)."""

    low: int = 0
    low_warned: int = 0
    high: int = 0
    high_silent: int = 0
    buffers: int = 0
    warned: int = 0

    def __add__(self, other: AdviceOutcome) -> AdviceOutcome:
        return AdviceOutcome(
            self.low + other.low,
            self.low_warned + other.low_warned,
            self.high + other.high,
            self.high_silent + other.high_silent,
            self.buffers + other.buffers,
            self.warned + other.warned,
        )

    @property
    def warning_share(self) -> float:
        """The share of the task's buffers that played pulses: how much an advisory sounded."""
        return self.warned / self.buffers if self.buffers else float("nan")

    @property
    def false_alarm_rate(self) -> float:
        return self.low_warned / self.low if self.low else float("nan")

    @property
    def miss_rate(self) -> float:
        return self.high_silent / self.high if self.high else float("nan")


def path_speed(reference: Poses, start_s: float, end_s: float, sample_s: float) -> tuple[float, float]:
    """(path length in metres, duration in seconds) of ``reference`` between ``start_s`` and ``end_s``, sampled
    every ``sample_s``."""
    times = reference.timestamps
    inside = (times >= start_s) & (times <= end_s)
    if inside.sum() < 2:
        return 0.0, 0.0
    t = times[inside]
    grid = np.arange(t[0], t[-1] + 1e-9, sample_s)
    if grid[-1] < t[-1]:
        grid = np.append(grid, t[-1])
    positions = np.column_stack([np.interp(grid, t, reference.positions[inside, k]) for k in range(3)])
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()), float(t[-1] - t[0])


def advice_outcome(
    advisory: pd.DataFrame,
    pair_times: np.ndarray,
    pair_errors_m: np.ndarray,
    clock_offset_s: float,
    window_s: float,
    alpha_m: float,
    high_error_m: float,
    task_end_s: float | None = None,
) -> AdviceOutcome:
    """Count the buffers of ``advisory`` (its ``wall_time`` and ``played_pulses``; ``clock_offset_s`` added to get
    the camera clock) against the error pairs ending in each buffer's last ``window_s``."""
    if advisory.empty or pair_times.size == 0:
        return AdviceOutcome()
    order = np.argsort(pair_times)
    times, errors = pair_times[order], pair_errors_m[order]
    cumulative = np.concatenate([[0.0], np.cumsum(errors)])
    at = advisory["wall_time"].to_numpy(float) + clock_offset_s
    warned = advisory["played_pulses"].to_numpy(float) > 0
    keep = (at >= times[0]) & (at <= (times[-1] if task_end_s is None else min(task_end_s, times[-1])) + window_s)
    at, warned = at[keep], warned[keep]
    sounded = int(warned.sum())
    hi = np.searchsorted(times, at, side="right")
    lo = np.searchsorted(times, at - window_s, side="right")
    counts = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        true = (cumulative[hi] - cumulative[lo]) / counts
    seen = counts > 0
    low = seen & (true < alpha_m)
    high = seen & (true >= high_error_m)
    return AdviceOutcome(
        int(low.sum()), int((low & warned).sum()), int(high.sum()), int((high & ~warned).sum()), len(at), sounded
    )
