"""Thresholds for the ``motion`` condition that make it pulse as often as ``seesys`` did in pilot sessions.

A control that sounds less than SEESys cannot tell information from pacing: the operator slows down less. So the
``motion`` condition's thresholds are set from pilot sessions of the ``seesys`` condition (people, or simulated
operators drawn from another seed than the study's): for every pulse count k, the share of the pilot's ``seesys``
ticks with N ≥ k is measured, and the k-th threshold is the quantile of the motion statistic (its moving mean at the
same ticks, replayed through the ``motion`` condition's own :class:`~advisory.advice.Advice` from the sessions'
feature logs) that gives the same share. Quantile matching on the same sessions keeps the amount and the loudness of
the sound the same; only what it follows differs.

The result says how well it matched: the share of buffers that warned (N ≥ 1) under the ``motion`` rule replayed on
the pilot with the new thresholds, beside the ``seesys`` sessions' own share. The motion rule is replayed on motion
that the seesys pulses shaped, which is the closest a pilot can come to the motion the ``motion`` arm will meet.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advisory.advice import Advice
from advisory.conditions import Condition, feature_reading
from advisory.config import AdvisoryConfig
from advisory.scheduler import TICK
from seesys.core.equation2 import max_pulses
from seesys.core.errors import SeesysError
from seesys.core.session_layout import ADVISORY_CSV
from seesys.io.logfiles import read_csv_log
from seesys.io.rts_log import read_feature_frames
from study.protocol import read_protocol
from study.sessions import advice_start, done_attempts


@dataclass(frozen=True)
class MotionCalibration:
    """Thresholds (m/s) and how well they match: per pulse count k = 1.., the share of ticks with N ≥ k of the
    pilot's ``seesys`` sessions and of the ``motion`` rule replayed on them; and the shares of buffers that warned."""

    pilot: str
    pilot_record: dict  # the pilot's simulation.json (settings, model version) where it is a simulated study
    sessions: list[str]
    thresholds_m_s: list[float]
    seesys_tick_shares: list[float]
    motion_tick_shares: list[float]
    seesys_warning_share: float
    motion_warning_share: float

    @property
    def warning_ratio(self) -> float:
        """The motion rule's warning share over SEESys's (1: matched)."""
        return self.motion_warning_share / self.seesys_warning_share if self.seesys_warning_share else math.nan

    def record(self) -> dict:
        return {**dataclasses.asdict(self), "warning_ratio": self.warning_ratio}


def pilot_sessions(pilot: Path, condition: str = Condition.SEESYS.value) -> list[Path]:
    """The done attempts of ``condition`` in the study folder ``pilot``; :class:`SeesysError` when there are none."""
    protocol = read_protocol(pilot)
    found = []
    for person in protocol.participants:
        if condition not in person.conditions:
            continue
        folder = protocol.phase_folder(pilot, person.id, protocol.analysed_phase, condition)
        found += done_attempts(folder)
    if not found:
        raise SeesysError(f"{pilot} has no finished {condition} session to calibrate the motion condition on")
    return found


def _simulation_record(pilot: Path) -> dict:
    """What a simulated pilot was made with (its ``simulation.json``), or nothing for a pilot with people."""
    try:
        return json.loads((Path(pilot) / "simulation.json").read_text())
    except (OSError, ValueError):
        return {}


def replay_motion(attempt: Path, cfg: AdvisoryConfig, latency_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``motion`` condition replayed on a session's feature log (each frame arriving ``latency_s`` after its
    timestamp): every buffer's (moving mean, N, whether a tick), in order."""
    frames = list(read_feature_frames(attempt, "pilot"))
    if not frames:
        raise SeesysError(f"{attempt}: no feature frames to replay")
    start = advice_start(attempt)
    advice = Advice(Condition.MOTION, cfg, frames[0].timestamp if start is None else start, 0.0)
    reading = feature_reading(Condition.MOTION, cfg)
    buffers = []
    for frame in frames:
        sample = reading(frame)
        if sample is not None:
            buffers += advice.take(frame.timestamp + latency_s, sample)
        buffers += advice.until(frame.timestamp)
    values = np.array([b.decision.value for b in buffers], float)
    pulses = np.array([b.decision.n_pulses for b in buffers], int)
    ticks = np.array([b.decision.trigger == TICK for b in buffers], bool)
    return values, pulses, ticks


def _shares(pulses: np.ndarray, most: int) -> list[float]:
    """The share of ``pulses`` at least k, for k = 1..most."""
    return [float(np.mean(pulses >= k)) if pulses.size else math.nan for k in range(1, most + 1)]


def _quantile_thresholds(values: np.ndarray, shares: list[float]) -> list[float]:
    """Thresholds t_k with P(value ≥ t_k) ≈ shares[k], strictly ascending and positive; a pulse count the pilot
    never reached gets none (the rule then never plays it). Raises SeesysError when no count was reached."""
    out: list[float] = []
    for share in shares:
        if share <= 0:
            break
        t = float(np.quantile(values, 1.0 - share))
        out.append(max(t, float(np.nextafter(out[-1], math.inf)) if out else float(np.nextafter(0.0, 1.0))))
    if not out:
        raise SeesysError("the pilot's seesys sessions never warned: there is no pulse rate to match")
    return out


def calibrate_motion(pilot: Path, cfg: AdvisoryConfig, latency_s: float = 0.0) -> MotionCalibration:
    """Thresholds for the ``motion`` condition from the ``seesys`` sessions of the study folder ``pilot`` (see the
    module docstring). Raises :class:`SeesysError` for a pilot without such sessions or logs."""
    sessions = pilot_sessions(pilot)
    most = max_pulses(cfg.equation2, cfg.timing.buffer_s)
    seesys_ticks, seesys_warned, motion_values = [], [], []
    for attempt in sessions:
        log = read_csv_log(attempt / ADVISORY_CSV)
        live = log[log.status == "live"]
        seesys_ticks.append(live.loc[live.trigger == TICK, "n_pulses"].to_numpy(int))
        seesys_warned.append(log.played_pulses.to_numpy(float) > 0)
        values, _, ticks = replay_motion(attempt, cfg, latency_s)
        motion_values.append(values[ticks & np.isfinite(values)])
    target = _shares(np.concatenate(seesys_ticks), most)
    thresholds = _quantile_thresholds(np.concatenate(motion_values), target)
    matched = dataclasses.replace(cfg, motion=dataclasses.replace(cfg.motion, thresholds_m_s=thresholds))
    replayed_pulses, replayed_ticks = [], []
    for attempt in sessions:
        _, pulses, ticks = replay_motion(attempt, matched, latency_s)
        replayed_pulses.append(pulses)
        replayed_ticks.append(pulses[ticks])
    return MotionCalibration(
        Path(pilot).name,
        _simulation_record(pilot),
        [str(a.relative_to(pilot)) for a in sessions],
        thresholds,
        target,
        _shares(np.concatenate(replayed_ticks), most),
        float(np.mean(np.concatenate(seesys_warned))),
        float(np.mean(np.concatenate(replayed_pulses) > 0)),
    )
