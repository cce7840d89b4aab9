"""When the advisory emits a buffer, and with how many pulses: the 3 Hz cadence over a moving average.

This is the generator's logic with the clock passed in, so that the live generator (driven by the monotonic
clock and ZeroMQ arrivals) and the offline renderer (driven by the timestamps of an estimate log) are the same
code.

- Every input sample (an estimate in metres, or a rotation speed in °/s) is kept with its arrival time.
- The *moving average* at time t is the mean of the samples that arrived in (t − window, t]. When that window is
  empty but the newest sample is younger than ``stale_after_s`` (a slow estimator), the newest sample stands in.
- A *tick* every 1 / cadence_hz seconds emits a buffer with N = rule(moving average): the paper's 3 Hz.
- A *change*: when a new sample changes N from what the last buffer holds, a buffer is emitted at once and the
  cadence restarts from there, so the listener hears a change within the audio latency instead of up to a
  whole period later. A change back to the N that the previous change replaced, within one period, is left to the
  next tick: a mean hovering at a threshold then does not restart the pulse train on every estimate.
- *No information*: no sample for longer than ``stale_after_s`` (since the newest sample, or since the start when
  none came) → N = 0 and status ``no_information``, for which the generator plays its "no information" cue
  instead of Equation 2's silence (which means "error below α"); the first new sample makes the status ``live``
  again. Before any sample, within ``stale_after_s`` of the start, the status is ``waiting``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

WAITING = "waiting"
LIVE = "live"
NO_INFORMATION = "no_information"
TICK = "tick"
CHANGE = "change"
# A tick whose buffer carries the generator's "no information" cue (advisory.generator).
CUE = "cue"


@dataclass(frozen=True)
class Decision:
    """One buffer to emit."""

    time: float  # the moment the buffer stands for: the tick time, or the arrival of the changing sample
    trigger: str  # TICK or CHANGE
    status: str  # LIVE, NO_INFORMATION or WAITING
    value: float  # the moving average the rule was applied to; NaN when there is no live input
    n_pulses: int
    arrival: float  # arrival time of the newest sample taken into account; NaN when none


class PulseScheduler:
    """The generator's state: recent samples, the next tick, the N of the last buffer."""

    def __init__(self, rule: Callable[[float], int], window_s: float, cadence_s: float, stale_after_s: float,
                 start: float):
        self._rule = rule
        self._window = window_s
        self._cadence = cadence_s
        self._stale_after = stale_after_s
        self._samples: deque[tuple[float, float]] = deque()
        self._last_n = 0
        self._n_before_change: int | None = None
        self._last_change = -math.inf
        self.next_tick = start
        self._start = start
        self.status = WAITING

    def _prune(self, t: float) -> None:
        # Keep the newest sample even when it is old: it stands in for an empty window until it goes stale.
        while len(self._samples) > 1 and self._samples[0][0] <= t - self._window:
            self._samples.popleft()

    def _average(self, t: float) -> tuple[float, float]:
        """(moving average, newest arrival) at time t, or (NaN, NaN) with no live input."""
        self._prune(t)
        if not self._samples:
            return math.nan, math.nan
        newest_arrival, newest_value = self._samples[-1]
        if t - newest_arrival > self._stale_after:
            return math.nan, newest_arrival
        in_window = [v for a, v in self._samples if a > t - self._window]
        mean = sum(in_window) / len(in_window) if in_window else newest_value
        return mean, newest_arrival

    def _decide(self, t: float, trigger: str) -> Decision:
        value, arrival = self._average(t)
        if math.isnan(value):
            waited = self._samples or t - self._start > self._stale_after
            status, n = (NO_INFORMATION if waited else WAITING), 0
        else:
            status, n = LIVE, self._rule(value)
        self.status = status
        return Decision(t, trigger, status, value, n, arrival)

    def _emitted(self, d: Decision) -> Decision:
        if d.trigger == CHANGE:
            self._n_before_change = self._last_n
            self._last_change = d.time
        self._last_n = d.n_pulses
        self.next_tick = d.time + self._cadence
        return d

    def add(self, t: float, value: float) -> Decision | None:
        """A sample arrived at time t; returns a CHANGE buffer to emit now, or None."""
        self._samples.append((t, value))
        d = self._decide(t, CHANGE)
        if d.n_pulses == self._last_n:
            return None
        flip_back = d.n_pulses == self._n_before_change and t - self._last_change < self._cadence
        return None if flip_back else self._emitted(d)

    def tick(self, t: float) -> Decision:
        """The cadence is due (t ≥ next_tick): the TICK buffer for the scheduled tick time.

        The decision stands for the scheduled time, not for when the caller woke up, so the cadence does not drift;
        a caller that fell more than a period behind resumes from t.
        """
        scheduled = self.next_tick if t - self.next_tick < self._cadence else t
        return self._emitted(self._decide(scheduled, TICK))
