"""Offline rendering: what a listener of the ``seesys`` condition hears for an estimate log, as one signal.

The estimate log's timestamps stand in for arrival times and drive the same :class:`PulseScheduler` as the live
generator, with the log's head probabilities where the live generator would use an estimate's head
(:func:`advisory.conditions.head_rule`); each buffer is laid into the output at the moment it stands for and replaces
the rest of the one before it, as the player does. The audio latency is left out: sample 0 is the first estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advisory.conditions import Condition, head_rule, pulse_rule
from advisory.config import AdvisoryConfig
from advisory.estimate_log import EstimateLog
from advisory.scheduler import Decision, PulseScheduler
from advisory.synth import buffer_samples, synthesise


@dataclass(frozen=True)
class Rendering:
    samples: np.ndarray  # float32 mono at the configured sample rate
    decisions: list[Decision]  # every buffer, times relative to the first estimate


def render_estimates(log: EstimateLog, cfg: AdvisoryConfig) -> Rendering:
    rate = cfg.audio.sample_rate
    timing = cfg.timing
    times = log.timestamps - log.timestamps[0]
    end = float(times[-1]) + timing.cadence_s + timing.buffer_s
    scheduler = PulseScheduler(
        pulse_rule(Condition.SEESYS, cfg), timing.window_s, timing.cadence_s, timing.stale_after_s, 0.0
    )
    buffers: dict[int, np.ndarray] = {}
    out = np.zeros(int(round(end * rate)) + buffer_samples(timing.buffer_s, rate), dtype=np.float32)
    decisions: list[Decision] = []
    with_head = log.head_probabilities is not None and head_rule(cfg)(log.head_thresholds_m)
    i = 0
    while True:
        # A sample that arrives at a tick's time is taken before the tick, as the live generator does.
        if i < times.size and times[i] <= scheduler.next_tick:
            d = scheduler.add(float(times[i]), float(log.errors_m[i]), log.head(i) if with_head else None)
            i += 1
        elif scheduler.next_tick <= end:
            d = scheduler.tick(scheduler.next_tick)
        else:
            break
        if d is not None:
            decisions.append(d)
            if d.n_pulses not in buffers:
                buffers[d.n_pulses] = synthesise(d.n_pulses, cfg.equation2, cfg.audio, timing.buffer_s)
            buf = buffers[d.n_pulses]
            start = int(round(d.time * rate))
            out[start : start + buf.size] = buf
    return Rendering(out[: int(round(end * rate))], decisions)
