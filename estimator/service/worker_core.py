"""A worker without its socket: the windows of the devices routed to it, the batches the model runs on them and the
estimates they give, encoded for the broker. A worker process (:mod:`estimator.service.worker`) runs one behind its
DEALER socket; with ``workers = 0`` the broker runs one in its own loop and hands it its frames directly
(:mod:`estimator.service.broker`).

Windows. Every frame added goes to its device's :class:`~seesys.core.windows.WindowAssembler`, and at most one ready
window per device is kept: a newer window of the same device supersedes an older one not yet served, which is dropped
as stale. :meth:`WorkerCore.serve_batch` serves up to ``max_batch`` ready windows, freshest first, in one batched run;
a window whose last frame reached the broker more than ``stale_after_ms`` ago is dropped and counted instead (an
estimate that late would mislead the advisory more than no estimate). That age is measured on one clock, the core's
own monotonic clock, from the moment the frame reached the broker as the caller gives it.

Drops, counted per device by reason: ``settings_mismatch`` (a frame ending a window, which carries the device settings
with its PSD, whose settings differ from the model's, or that states none: refused, and the difference logged once per
stream session), ``shape_mismatch`` (a window whose PSD is of another shape than the model's: another PSD grid),
``missing_rts`` and ``missing_psd`` (a window end whose history arrived but with more than ``max_missing_rts`` rows
missing or untracked, or a PSD sample missing) and ``stale``. Non-finite RTS values (NaN, ±inf) the model sees as 0 are
counted per device too (``nonfinite``).

Order. Below capacity the queue is short and the order hardly matters. Overloaded, oldest first would serve every
window just before its deadline, one at a time (the oldest leaves no room for a batch), while the fresher ones
age behind it: every estimate late, and fewer of them. Freshest first serves the windows that still have time,
in batches, and lets the ones that cannot make it go stale. Each device's window is the freshest when it arrives,
so no device is left out for long. Per-device order is kept: a device has at most one ready window.

Batch size. A batch's estimates all leave when the batch ends, and on a CPU a batch costs about its size times one
window (DeepSEE on one thread: 5.7, 22.0 and 95.0 ms for 1, 4 and 16 windows), so a large batch gains little
throughput there and holds back its first estimates. The core therefore keeps a running cost per window and
takes the largest batch whose oldest window still finishes within ``stale_after_ms`` (:func:`batch_size`); on a
GPU, where a batch costs little more than one window, batches stay large.

A new stream session of a device, or frame indices that go backwards, mean the device restarted: its windows start
afresh.
"""

from __future__ import annotations

import os
import sys
import time
from collections import defaultdict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from estimator.service import envelope, stages
from estimator.service.config import ServiceConfig
from estimator.service.device_windows import SETTINGS_MISMATCH, SHAPE_MISMATCH, DeviceWindows
from estimator.service.model import ServedModel
from seesys.core import messages
from seesys.core.messages import Estimate, FeatureFrame
from seesys.core.windows import MISSING_PSD, MISSING_RTS, WindowConfig, WindowSample

# Inference times kept for the percentiles a heartbeat reports.
_TIMING_SAMPLES = 512
# Weight of the newest batch in the running cost per window (a few batches settle it; a slower machine shows soon).
_COST_WEIGHT = 0.2
#: Every reason a worker drops a frame or a window for, as the broker's status names it.
DROP_REASONS = (SETTINGS_MISMATCH, SHAPE_MISMATCH, MISSING_RTS, MISSING_PSD, "stale")


def batch_size(ages_ms: Sequence[float], max_batch: int, window_ms: float, stale_after_ms: float) -> int:
    """How many of the ready windows to run in one batch, taken freshest first (``ages_ms``: each window's time
    since its last frame reached the broker, ascending): the most, up to ``max_batch``, whose oldest still finishes
    within ``stale_after_ms`` at ``window_ms`` per window; at least one (whether that one is still in time is the
    stale check's to decide)."""
    n = min(len(ages_ms), max_batch)
    while n > 1 and ages_ms[n - 1] + n * window_ms > stale_after_ms:
        n -= 1
    return max(1, n)


@dataclass
class WorkerCounters:
    """Cumulative counts a worker reports with every heartbeat (per device where it says so)."""

    frames: int = 0
    windows: int = 0
    estimates: int = 0
    batches: int = 0
    undelivered: int = 0
    dropped: dict[str, dict[str, int]] = field(
        default_factory=lambda: {reason: defaultdict(int) for reason in DROP_REASONS}
    )
    nonfinite: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    restarts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    settings_refused: dict[str, str] = field(default_factory=dict)  # device → why its frames are refused
    batch_ms: deque = field(default_factory=lambda: deque(maxlen=_TIMING_SAMPLES))
    batch_sizes: deque = field(default_factory=lambda: deque(maxlen=_TIMING_SAMPLES))

    def report(self, pending: int) -> dict:
        ms = np.asarray(self.batch_ms, dtype=float)
        return {
            "frames": self.frames,
            "windows": self.windows,
            "estimates": self.estimates,
            "batches": self.batches,
            "undelivered": self.undelivered,
            "pending": pending,
            "dropped": {reason: dict(by_device) for reason, by_device in self.dropped.items()},
            "nonfinite": dict(self.nonfinite),
            "restarts": dict(self.restarts),
            "settings_refused": dict(self.settings_refused),
            "batch_ms_p50": float(np.percentile(ms, 50)) if ms.size else None,
            "batch_ms_p99": float(np.percentile(ms, 99)) if ms.size else None,
            "batch_size_mean": float(np.mean(self.batch_sizes)) if self.batch_sizes else None,
        }


@dataclass
class _Ready:
    sample: WindowSample
    token: float  # the broker's, handed back with the estimate
    received: float  # on the core's clock: when its last frame reached the broker
    stream_session: int
    ingest_ms: float  # the broker's time with its last frame (handed back for the stage breakdown)
    arrived: float  # perf_counter: its last frame reached this worker
    unpack_ms: float
    assemble_ms: float
    formed: float  # perf_counter: the window was formed
    covariance: np.ndarray | None  # the window's last frame's predicted translation covariance, for its estimate


class WorkerCore:
    """One worker's windows, batches and counters: :meth:`add` each frame, :meth:`serve_batch` while
    :attr:`has_ready`."""

    def __init__(
        self,
        model: ServedModel,
        windows: WindowConfig,
        config: ServiceConfig,
        name: str,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.model, self.windows, self.config, self.name = model, windows, config, name
        self.counters = WorkerCounters()
        self.clock = clock  # seconds; only ever compared with itself
        self._windows = DeviceWindows(model, windows)
        self._ready: dict[str, _Ready] = {}
        self._window_ms = 0.0  # running model cost per window of a batch; 0 until the first batch is measured

    @property
    def has_ready(self) -> bool:
        """Whether a window waits to be served."""
        return bool(self._ready)

    def identity(self) -> dict:
        """Who serves (name, pid, model version, provider, whether the model reads the PSD), as the broker takes a
        worker on."""
        return {
            "name": self.name,
            "pid": os.getpid(),
            "model_version": self.model.version,
            "provider": self.model.provider,
            "reads_psd": self.model.reads_psd,
        }

    def report(self) -> dict:
        """:meth:`identity` and the counters, as a heartbeat carries them."""
        return {**self.identity(), **self.counters.report(len(self._ready))}

    def _note_settings(self, frame: FeatureFrame) -> None:
        """Log (once per stream session) and record a device whose settings differ from the model's."""
        device = frame.device_id
        differences, news = self._windows.settings_differences(frame)
        if differences:
            why = "; ".join(differences)
            if news:
                print(
                    f"estimator worker {self.name}: device {device!r} (stream session {frame.stream_session:x}): "
                    f"frames refused, its settings differ from the model's: {why}",
                    file=sys.stderr,
                    flush=True,
                )
            self.counters.settings_refused[device] = why
        else:
            self.counters.settings_refused.pop(device, None)

    def add(self, token: float, ingest_ms: float, received: float, arrived: float, frame: FeatureFrame) -> None:
        """Add one frame: ``token`` the broker's (handed back), ``ingest_ms`` the broker's time with it,
        ``received`` when it reached the broker on this core's clock, ``arrived`` (perf_counter) when it reached
        this worker."""
        unpacked = time.perf_counter()
        self.counters.frames += 1
        device = frame.device_id
        if frame.states_settings:
            self._note_settings(frame)
        added = self._windows.add(frame)
        if added.restarted:
            self._ready.pop(device, None)
            self.counters.restarts[device] += 1
        if added.formed:
            self.counters.windows += 1
        if added.refused is not None:
            self.counters.dropped[added.refused][device] += 1
        if added.window is None:
            return
        if device in self._ready:
            self.counters.dropped["stale"][device] += 1  # superseded before it was served
        formed = time.perf_counter()
        self._ready[device] = _Ready(
            added.window,
            token,
            received,
            frame.stream_session,
            ingest_ms,
            arrived,
            (unpacked - arrived) * 1000.0,
            (formed - unpacked) * 1000.0,
            formed,
            frame.translation_covariance,
        )

    def serve_batch(self) -> list[envelope.ServedEstimate]:
        """Drop the stale windows, run the freshest that fit in one batch and return their estimates as the broker
        takes them (a worker process packs them: :func:`estimator.service.envelope.pack_estimates`); empty when no
        window was left to serve."""
        now = self.clock()
        limit = self.config.stale_after_ms / 1000.0
        for device, ready in list(self._ready.items()):
            if now - ready.received > limit:
                del self._ready[device]
                self.counters.dropped["stale"][device] += 1
        waiting = sorted(self._ready.values(), key=lambda r: r.received, reverse=True)  # freshest first
        if not waiting:
            return []
        ages_ms = [(now - r.received) * 1000.0 for r in waiting]
        batch = waiting[: batch_size(ages_ms, self.config.max_batch, self._window_ms, self.config.stale_after_ms)]
        for ready in batch:
            del self._ready[ready.sample.device_id]
        start = time.perf_counter()
        inputs = self.model.prepare([r.sample for r in batch])
        prepared = time.perf_counter()
        estimates = self.model.run(inputs)
        done = time.perf_counter()
        elapsed_ms = (done - start) * 1000.0
        per_window = elapsed_ms / len(batch)
        self._window_ms = (
            per_window if not self._window_ms else ((1 - _COST_WEIGHT) * self._window_ms + _COST_WEIGHT * per_window)
        )
        self.counters.batch_ms.append(elapsed_ms)
        self.counters.batch_sizes.append(len(batch))
        self.counters.batches += 1
        sent = self.clock()
        encoded = []
        for i, (ready, error_m, nonfinite) in enumerate(zip(batch, estimates.errors_m, estimates.nonfinite)):
            s = ready.sample
            if nonfinite:
                self.counters.nonfinite[s.device_id] += int(nonfinite)
            estimate = Estimate(
                s.device_id,
                s.frame_index,
                s.timestamp,
                float(error_m),
                self.model.version,
                (sent - ready.received) * 1000.0,
                ready.stream_session,
                estimates.head(i),
                ready.covariance,
            )
            encoded.append((ready, messages.encode(estimate)))
        # The stages end where the message leaves: every estimate of the batch carries the batch's encoding time.
        replied = time.perf_counter()
        batch_times = ((prepared - start) * 1000.0, (done - prepared) * 1000.0, (replied - done) * 1000.0)
        served = []
        for ready, (topic, body) in encoded:
            times = stages.WorkerTimes(
                ready.ingest_ms,
                (replied - ready.arrived) * 1000.0,
                (ready.unpack_ms, ready.assemble_ms, (start - ready.formed) * 1000.0, *batch_times),
            )
            sample = ready.sample
            served.append(
                envelope.ServedEstimate(
                    topic, body, sample.device_id, ready.token, sample.frame_index, ready.stream_session, times
                )
            )
        self.counters.estimates += len(batch)
        return served
