"""The device's side of the estimator: an observer that receives this device's estimates and logs, per estimated
frame, where the time went, in ``estimates.csv`` of the session folder.

Three moments per frame, on this process's monotonic clock:

- *tracked*: ORB-SLAM3 returned the frame and the monitor got it (this observer's ``on_frame`` runs right after the
  monitor's); the frame was captured ``track_ms`` before;
- *sent*: the frame's feature message appeared on the device's own feature stream (a local subscriber to
  ``features_endpoint``: the moment the monitor published it, plus a loopback hop of tens of µs);
- *received*: its estimate arrived from ``estimates_endpoint``.

``estimates.csv``: ``frame_index, timestamp, error_m, model_version, server_ms, received_unix, tracking_ms,
preprocess_ms`` (tracked → sent: the monitor's features, PSD and encoding; it writes its logs after publishing),
``transmit_inference_ms`` (sent → received), ``end_to_end_ms`` (tracked → received, what the paper reports as end
to end) and ``capture_to_estimate_ms`` (tracking included). A time not observed is empty (for example the first
frames, before the local subscriber is connected). Rows are flushed as they come.

Only this device's estimates are logged: those of its device id *and* its stream session (the session's random
number, carried in its frames and in every estimate made from them); an estimate of another stream session with
the same id (another device given the same id, or an earlier run of this one) is counted in ``foreign`` and
skipped.

Nothing here can stop tracking: the receiving thread only reads sockets and writes the log; sockets reconnect by
themselves after the estimator restarts, and the estimates simply resume.
"""

from __future__ import annotations

import csv
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import zmq

from seesys.core import messages
from seesys.core.messages import Estimate, FeatureFrame, MessageError
from seesys.core.session_layout import ESTIMATE_COLUMNS, ESTIMATES_CSV
from seesys.io.network import load_network_config
from seesys.io.transport import open_socket
from slam_monitor.monitor_config import load_monitor_config, resolve_device_id

# Frames whose moments are remembered while their estimate may still come (10 s at 30 Hz).
_REMEMBERED = 300
_POLL_MS = 100


class _Moments:
    """Bounded frame index → moment map (the oldest go first)."""

    def __init__(self) -> None:
        self._items: OrderedDict[int, tuple[float, ...]] = OrderedDict()
        self._lock = threading.Lock()

    def put(self, index: int, value: tuple[float, ...]) -> None:
        with self._lock:
            self._items[index] = value
            while len(self._items) > _REMEMBERED:
                self._items.popitem(last=False)

    def get(self, index: int) -> tuple[float, ...] | None:
        with self._lock:
            return self._items.get(index)


def _ms(later: float | None, earlier: float | None) -> float:
    return math.nan if later is None or earlier is None else (later - earlier) * 1000.0


class EstimateObserver:
    """Device-worker observer logging this device's estimates and their latency into ``estimates.csv``."""

    def __init__(
        self,
        out_dir: Path,
        device_id: str,
        features_endpoint: str,
        estimates_endpoint: str,
        socket_options: Mapping[int, int | bytes] | None = None,
        stream_session: int = 0,
    ):
        self.device_id = device_id
        self.stream_session = stream_session
        self.received = 0
        self.foreign = 0
        self._tracked = _Moments()
        self._sent = _Moments()
        self._ctx = zmq.Context()
        self._features = open_socket(
            self._ctx,
            zmq.SUB,
            features_endpoint,
            "own feature stream",
            bind=False,
            subscribe=[messages.topic(messages.FEATURE_TOPIC, device_id)],
        )
        self._estimates = open_socket(
            self._ctx,
            zmq.SUB,
            estimates_endpoint,
            "estimates",
            bind=False,
            subscribe=[messages.topic(messages.ESTIMATE_TOPIC, device_id)],
            options=socket_options,
        )
        self._file = open(Path(out_dir) / ESTIMATES_CSV, "w", newline="")
        self._csv = csv.writer(self._file)
        self._csv.writerow(ESTIMATE_COLUMNS)
        self._file.flush()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="estimate-observer", daemon=True)
        self._thread.start()

    def on_frame(self, frame: Any, result: Any) -> None:
        now = time.perf_counter()
        self._tracked.put(frame.index, (now, float(result.track_ms)))

    def _run(self) -> None:
        poller = zmq.Poller()
        poller.register(self._features, zmq.POLLIN)
        poller.register(self._estimates, zmq.POLLIN)
        while not self._stop.is_set():
            for sock, _ in poller.poll(_POLL_MS):
                try:
                    message = messages.decode(sock.recv_multipart())
                except MessageError:
                    continue  # not ours to judge: the estimator counts what it rejects
                now = time.perf_counter()
                if message.stream_session != self.stream_session:
                    self.foreign += isinstance(message, Estimate)
                elif isinstance(message, FeatureFrame):
                    self._sent.put(message.frame_index, (now,))
                elif isinstance(message, Estimate):
                    self._log(message, now)

    def _log(self, estimate: Estimate, received: float) -> None:
        tracked, track_ms = self._tracked.get(estimate.frame_index) or (None, math.nan)
        sent = (self._sent.get(estimate.frame_index) or (None,))[0]
        end_to_end = _ms(received, tracked)
        row = [
            estimate.frame_index,
            f"{estimate.timestamp:.6f}",
            f"{estimate.error_m:.6g}",
            estimate.model_version,
            f"{estimate.server_ms:.3f}",
            f"{time.time():.6f}",
            f"{track_ms:.3f}",
            f"{_ms(sent, tracked):.3f}",
            f"{_ms(received, sent):.3f}",
            f"{end_to_end:.3f}",
            f"{track_ms + end_to_end:.3f}",
        ]
        self._csv.writerow(["" if v == "nan" else v for v in row])
        self._file.flush()
        self.received += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        for sock in (self._features, self._estimates):
            sock.close()
        self._ctx.term()
        self._file.close()


def create_observer(context: Any, device_id: str | None = None) -> EstimateObserver:
    """Observer factory for :class:`slam_monitor.device_worker.ObserverSpec`: endpoints and Curve keys of
    network.toml (estimates encrypted when its ``[curve]`` is set), device id of monitor.toml unless given (use the
    monitor's; ``auto`` resolves as the monitor's does), the session's stream session."""
    config_dir = context.options.config_dir
    network = load_network_config(config_dir)
    device_id = resolve_device_id(device_id or load_monitor_config(config_dir).device_id, context.options.source)
    return EstimateObserver(
        context.out_dir,
        device_id,
        network.features_endpoint,
        network.estimates_endpoint,
        network.client_options(network.estimates_endpoint),
        context.stream_session,
    )


def summary_line(out_dir: Path) -> str:
    """One line on the session's ``estimates.csv``: how many estimates came and their end-to-end latency."""
    import pandas as pd

    table = pd.read_csv(Path(out_dir) / ESTIMATES_CSV)
    if table.empty:
        return f"estimates: none received (is `seesys estimator serve` running?); {ESTIMATES_CSV} is empty"
    p50, p99 = table.end_to_end_ms.quantile([0.5, 0.99])
    return (
        f"estimates: {len(table)} received, end to end (frame tracked → estimate on the device) p50 "
        f"{p50:.1f} ms, p99 {p99:.1f} ms ({ESTIMATES_CSV})"
    )
