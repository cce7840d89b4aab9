"""When the advisory emits a buffer, and with how many pulses: the 3 Hz cadence over a moving average.

This is the generator's logic with the clock passed in, so that the live generator (driven by the monotonic
clock and ZeroMQ arrivals) and the offline renderer (driven by the timestamps of an estimate log) are the same
code.

- Every input sample (an estimate in metres, or a rotation speed in °/s) is kept with its arrival time.
- The *moving average* at time t is the mean of the samples that arrived in (t − window, t]. When that window is
  empty but the newest sample is younger than ``stale_after_s`` (a slow estimator), the newest sample stands in.
- A *tick* every 1 / cadence_hz seconds emits a buffer with N = rule(moving average): the paper's 3 Hz.
- *Head*: a sample may carry a model's ordinal-head probabilities P(error ≥ t_k) for Equation 2's class boundaries
  (the condition passes them only then, see ``advisory.conditions``). When every sample of the window carries them,
  they are averaged over the same window as the values and N is the head's class of the means
  (:func:`seesys.core.exceedance.head_class`); otherwise N = rule(moving average). Each decision says which rule
  gave its N (``pulses_from``).
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

import numpy as np

from seesys.core.exceedance import head_class

WAITING = "waiting"
LIVE = "live"
NO_INFORMATION = "no_information"
TICK = "tick"
CHANGE = "change"
# A tick whose buffer carries the generator's "no information" cue (advisory.generator).
CUE = "cue"
#: ``Decision.pulses_from`` of a decision made by the ordinal head's class; "" when there was no live input.
HEAD = "head"


@dataclass(frozen=True)
class Reading:
    """One input sample: the value the rule averages, and the head's probabilities for Equation 2's class
    boundaries (None: the sample carries none that the advisory may use)."""

    value: float
    head: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Decision:
    """One buffer to emit."""

    time: float  # the moment the buffer stands for: the tick time, or the arrival of the changing sample
    trigger: str  # TICK or CHANGE
    status: str  # LIVE, NO_INFORMATION or WAITING
    value: float  # the moving average the rule was applied to; NaN when there is no live input
    n_pulses: int
    arrival: float  # arrival time of the newest sample taken into account; NaN when none
    pulses_from: str = ""  # HEAD, or the rule's name (the scheduler's rule_name); "" without live input


class PulseScheduler:
    """The generator's state: recent samples, the next tick, the N of the last buffer. ``rule_name`` names
    ``rule`` in the decisions (``estimate``: Equation 2 of the mean estimate)."""

    def __init__(
        self,
        rule: Callable[[float], int],
        window_s: float,
        cadence_s: float,
        stale_after_s: float,
        start: float,
        rule_name: str = "estimate",
    ):
        self._rule = rule
        self._rule_name = rule_name
        self._window = window_s
        self._cadence = cadence_s
        self._stale_after = stale_after_s
        self._samples: deque[tuple[float, Reading]] = deque()
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

    def _average(self, t: float) -> tuple[float, np.ndarray | None, float]:
        """(moving average, mean head probabilities or None, newest arrival) at time t, or (NaN, None, NaN) with
        no live input. The head is averaged only when every sample averaged carries one of the same length."""
        self._prune(t)
        if not self._samples:
            return math.nan, None, math.nan
        newest_arrival, newest = self._samples[-1]
        if t - newest_arrival > self._stale_after:
            return math.nan, None, newest_arrival
        in_window = [r for a, r in self._samples if a > t - self._window] or [newest]
        mean = sum(r.value for r in in_window) / len(in_window)
        heads = [r.head for r in in_window]
        first = heads[0]
        usable = first is not None and all(h is not None and len(h) == len(first) for h in heads)
        return mean, (np.mean(np.array(heads, float), axis=0) if usable else None), newest_arrival

    def _decide(self, t: float, trigger: str) -> Decision:
        value, head, arrival = self._average(t)
        if math.isnan(value):
            waited = self._samples or t - self._start > self._stale_after
            status, n, source = (NO_INFORMATION if waited else WAITING), 0, ""
        elif head is not None:
            status, n, source = LIVE, int(head_class(head)), HEAD
        else:
            status, n, source = LIVE, self._rule(value), self._rule_name
        self.status = status
        return Decision(t, trigger, status, value, n, arrival, source)

    def _emitted(self, d: Decision) -> Decision:
        if d.trigger == CHANGE:
            self._n_before_change = self._last_n
            self._last_change = d.time
        self._last_n = d.n_pulses
        self.next_tick = d.time + self._cadence
        return d

    def add(self, t: float, value: float, head: tuple[float, ...] | None = None) -> Decision | None:
        """A sample arrived at time t (``head``: its head probabilities for Equation 2's class boundaries, or
        None); returns a CHANGE buffer to emit now, or None."""
        self._samples.append((t, Reading(value, head)))
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


class CueClock:
    """Which buffers carry the "no information" cue instead of silence: a tick without information, in an audible
    condition with the cue on, at least ``every_s`` after the last cue."""

    def __init__(self, audible: bool, enabled: bool, every_s: float):
        self._on = audible and enabled
        self._every = every_s
        self._last = -math.inf

    def trigger(self, d: Decision) -> str:
        """The trigger the buffer of ``d`` is logged with: :data:`CUE` when it carries the cue, else ``d.trigger``."""
        if self._on and d.status == NO_INFORMATION and d.trigger == TICK and d.time - self._last >= self._every - 1e-9:
            self._last = d.time
            return CUE
        return d.trigger
