"""What a run of ``seesys run`` is doing, observed from outside its parts: the session's growing logs (frames, the
estimates the device received, the advisory's buffers) and the local estimator's status endpoint.

The app's decisions (is the estimator ready, is it loading its model after a restart, what did it drop) and the live
view both read one :class:`Observation`; the view only draws it.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seesys.core.session_layout import ADVISORY_CSV, ESTIMATES_CSV, FRAMES_CSV
from seesys.io.children import CsvTail, RowCounter, last_line
from seesys.io.supervision import PartStatus
from seesys_app.config import ViewConfig

# The frame rate is measured over this many seconds of the frame log.
RATE_WINDOW_S = 2.0


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


@dataclass(frozen=True)
class EstimatorObservation:
    """The local estimator as its status endpoint answered (a remote one, or one not running, is not asked)."""

    asked: bool = False
    answering: bool = False
    model_version: str = ""
    dropped: dict[str, int] | None = None  # this device's windows dropped and the broker's rejections, by reason


@dataclass(frozen=True)
class Observation:
    """The run at one moment."""

    elapsed_s: float = 0.0
    frames: int = 0
    tracking_state: str = ""  # the device's newest frame's state ("" before its first frame)
    fps: float = math.nan
    estimates: int = 0
    latest_error_m: float = math.nan
    estimate_age_s: float = math.nan
    recent_errors_m: tuple[float, ...] = ()  # the estimates of the last ``sparkline_s``
    latency_ms: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # p50, p95, p99
    pulses: tuple[int, ...] = ()  # the newest advisory buffers'
    estimator: EstimatorObservation = field(default_factory=EstimatorObservation)


class RunObserver:
    """Reads the session folder's logs (only what they gained since the last look) and asks the local estimator
    for its status every ``estimator_poll_s``."""

    def __init__(self, folder: Path, config: ViewConfig, device_id: str, status_endpoint: str | None):
        self.folder, self.cfg, self.device_id, self.status_endpoint = folder, config, device_id, status_endpoint
        self._started = time.monotonic()
        self._frames = RowCounter(folder / FRAMES_CSV)
        self._rates: deque[tuple[float, int]] = deque()
        self._estimates = CsvTail(folder / ESTIMATES_CSV)
        self._count = 0
        self._recent: deque[tuple[float, float]] = deque()  # (received unix, error m)
        self._latencies: deque[float] = deque(maxlen=config.latency_window)
        self._advisory = CsvTail(folder / ADVISORY_CSV)
        self._pulses: deque[int] = deque(maxlen=config.buffers_shown)
        self._last_status = -math.inf
        self._status: dict[str, Any] | None = None
        self.latest = Observation()

    def estimator_answers(self) -> bool:
        """Ask the local estimator for its status now; True when it answered. RuntimeError for a remote one."""
        from estimator.service.broker import ServiceError
        from estimator.service.status import query_status

        if self.status_endpoint is None:
            raise RuntimeError("only a local estimator is asked for its status (a remote one has no endpoint here)")
        self._last_status = time.monotonic()
        try:
            self._status = query_status(self.status_endpoint, self.cfg.status_timeout_ms)
        except ServiceError:
            self._status = None
        return self._status is not None

    def _estimator(self, part: PartStatus | None) -> EstimatorObservation:
        if self.status_endpoint is None or part is None or part.restarting or not part.running:
            self._status = None  # what a dead estimator answered before says nothing of the next one
            return EstimatorObservation()
        if time.monotonic() - self._last_status >= self.cfg.estimator_poll_s:
            self.estimator_answers()
        if self._status is None:
            return EstimatorObservation(asked=True)
        device = self._status["devices"].get(self.device_id)
        dropped = dict(device["dropped"]) if device else {}
        for reason, n in self._status["rejected"].items():  # messages the broker rejected, by their own reasons
            dropped[f"rejected {reason}"] = n
        return EstimatorObservation(True, True, self._status["model_version"], dropped)

    def look(self, parts: Mapping[str, PartStatus]) -> Observation:
        """The run now; ``parts``: the supervised parts as they are now (the estimator is asked only while it
        runs)."""
        now_mono, now = time.monotonic(), time.time()
        frames = self._frames()
        row = last_line(self.folder / FRAMES_CSV).split(",")
        self._rates.append((now_mono, frames))
        while len(self._rates) > 2 and now_mono - self._rates[0][0] > RATE_WINDOW_S:
            self._rates.popleft()
        (t0, f0), (t1, f1) = self._rates[0], self._rates[-1]
        for r in self._estimates.new_rows():
            self._recent.append((_float(r["received_unix"]), _float(r["error_m"])))
            end_to_end_ms = _float(r["end_to_end_ms"])
            if not math.isnan(end_to_end_ms):
                self._latencies.append(end_to_end_ms)
            self._count += 1
        latest_error, age = math.nan, math.nan
        if self._recent:
            received, latest_error = self._recent[-1]
            age = now - received
        while self._recent and now - self._recent[0][0] > self.cfg.sparkline_s:
            self._recent.popleft()
        latency = (math.nan, math.nan, math.nan)
        if self._latencies:
            p50, p95, p99 = (float(v) for v in np.percentile(list(self._latencies), [50, 95, 99]))
            latency = (p50, p95, p99)
        for r in self._advisory.new_rows():
            self._pulses.append(int(r["played_pulses"]) if r["played_pulses"].isdigit() else 0)
        self.latest = Observation(
            elapsed_s=now_mono - self._started,
            frames=frames,
            tracking_state=row[2] if len(row) > 2 else "",
            fps=(f1 - f0) / (t1 - t0) if t1 > t0 else math.nan,
            estimates=self._count,
            latest_error_m=latest_error,
            estimate_age_s=age,
            recent_errors_m=tuple(error for _, error in self._recent),
            latency_ms=latency,
            pulses=tuple(self._pulses),
            estimator=self._estimator(parts.get("estimator")),
        )
        return self.latest
