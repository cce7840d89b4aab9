"""The advisory's step of the per-frame chain: readings in, buffers out, on any clock.

One :class:`Advice` holds a condition's :class:`~advisory.scheduler.PulseScheduler` and its
:class:`~advisory.scheduler.CueClock` and turns their decisions into :class:`Buffer` records: what is played (nothing
in a silent condition), which buffers carry the "no information" cue, the buffer's number and when it sounds, and its
row of ``advisory.csv``. The live generator (``advisory.generator``: the monotonic clock, readings from ZeroMQ) and
the simulated study (``seesys_app.simulate``: the camera's clock, readings from the loop) both step it, so the two
cannot disagree on what a reading makes the listener hear.

:class:`ReplayedAdvice` is the ``yoked`` condition's: it plays a recorded sequence of buffers at the same times from
the start, whatever the readings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from advisory.conditions import Condition, pulse_rule, rule_name
from advisory.config import AdvisoryConfig
from advisory.scheduler import CUE, LIVE, TICK, CueClock, Decision, PulseScheduler, Reading

#: ``pulses_from`` of a replayed buffer, and the status of a yoked buffer after the recording ends.
REPLAYED = "replayed"
REPLAY_ENDED = "replay_ended"


@dataclass(frozen=True)
class Buffer:
    """One buffer to play: the decision it stands for, its trigger (``cue`` where it carries the "no information"
    cue), the pulses it holds (0 in a silent condition, or for a cue), its number and when it should sound."""

    decision: Decision
    trigger: str
    played: int
    buffer_id: int
    play_at: float

    @property
    def heard_pulses(self) -> int:
        """The pulses a listener hears as a warning: the cue is not one."""
        return 0 if self.trigger == CUE else self.played

    def row(self, wall_time: float, condition: Condition) -> tuple:
        """Its row of ``advisory.csv`` (``seesys.core.session_layout.ADVISORY_COLUMNS``)."""
        d = self.decision
        return (
            wall_time,
            d.time,
            condition.value,
            d.status,
            self.trigger,
            d.value,
            d.n_pulses,
            self.played,
            self.buffer_id,
            d.arrival,
            self.play_at,
            d.pulses_from,
        )


class Advice:
    """A condition's advisory on one clock (``start``: the clock's time when it starts listening; ``latency_s``:
    from a buffer's time to its sound). Raises :class:`~seesys.core.errors.SeesysError` for ``yoked``, which
    :class:`ReplayedAdvice` plays."""

    def __init__(self, condition: Condition, cfg: AdvisoryConfig, start: float, latency_s: float):
        timing = cfg.timing
        self.condition = condition
        self.scheduler = PulseScheduler(
            pulse_rule(condition, cfg),
            timing.window_s,
            timing.cadence_s,
            timing.stale_after_s,
            start,
            rule_name(condition),
        )
        self._cues = CueClock(condition.audible, cfg.no_information.no_information_cue, cfg.no_information.cue_every_s)
        self._latency_s = latency_s
        self.buffers = 0

    def _buffer(self, d: Decision) -> Buffer:
        trigger = self._cues.trigger(d)
        played = d.n_pulses if self.condition.audible and trigger != CUE else 0
        buffer = Buffer(d, trigger, played, self.buffers, d.time + self._latency_s)
        self.buffers += 1
        return buffer

    def take(self, arrival: float, reading: Reading) -> list[Buffer]:
        """A reading arrived: the ticks due before it (each at its own time), then the change it makes, if any.
        A reading that is not finite is no reading."""
        out = []
        while self.scheduler.next_tick < arrival:
            out.append(self._buffer(self.scheduler.tick(self.scheduler.next_tick)))
        if math.isfinite(reading.value):
            decision = self.scheduler.add(arrival, reading.value, reading.head)
            if decision is not None:
                out.append(self._buffer(decision))
        return out

    def until(self, now: float) -> list[Buffer]:
        """Every tick due by ``now``, each at its own time (a clock stepped at least once a period gets one)."""
        out = []
        while self.scheduler.next_tick <= now:
            out.append(self._buffer(self.scheduler.tick(self.scheduler.next_tick)))
        return out

    def tick(self, now: float) -> Buffer:
        """The tick due at ``now`` on a live clock: one that fell more than a period behind resumes from ``now``
        (``PulseScheduler.tick``) instead of catching up with buffers already too late to play."""
        return self._buffer(self.scheduler.tick(now))


@dataclass(frozen=True)
class RecordedBuffer:
    """A buffer of a recorded session, its time from that session's start."""

    offset_s: float
    n_pulses: int
    played: int
    trigger: str


class ReplayedAdvice:
    """The ``yoked`` condition: ``recording`` played at the same times from ``start`` (the recorded session's
    start on its own clock), with the recorded pulses; after the recording's end, silent buffers at the cadence
    (status ``replay_ended``). Readings are ignored."""

    condition = Condition.YOKED

    def __init__(self, recording: Sequence[RecordedBuffer], cfg: AdvisoryConfig, start: float, latency_s: float):
        self._recording = sorted(recording, key=lambda b: b.offset_s)
        self._start = start
        self._cadence = cfg.timing.cadence_s
        self._latency_s = latency_s
        self._next = 0
        self._after_end = start + (self._recording[-1].offset_s if self._recording else 0.0) + self._cadence
        self.buffers = 0

    def _emit(self, time: float, status: str, trigger: str, n: int, played: int) -> Buffer:
        decision = Decision(time, TICK if trigger == CUE else trigger, status, math.nan, n, math.nan, REPLAYED)
        buffer = Buffer(decision, trigger, played, self.buffers, time + self._latency_s)
        self.buffers += 1
        return buffer

    def until(self, now: float) -> list[Buffer]:
        out = []
        while self._next < len(self._recording) and self._start + self._recording[self._next].offset_s <= now:
            b = self._recording[self._next]
            out.append(self._emit(self._start + b.offset_s, LIVE, b.trigger, b.n_pulses, b.played))
            self._next += 1
        if self._next == len(self._recording):
            while self._after_end <= now:
                out.append(self._emit(self._after_end, REPLAY_ENDED, TICK, 0, 0))
                self._after_end += self._cadence
        return out

    def take(self, arrival: float, reading: Reading) -> list[Buffer]:
        return self.until(arrival)
