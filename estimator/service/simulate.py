"""Simulated devices: a logged session's feature stream (``rts.csv`` + ``psd/``) replayed by many devices at the
camera rate, each on its own connection to the service, with the latency of every estimate measured where the
device would see it (feature message sent → estimate received: transmit + inference).

Every message is encoded before the clock starts, so the replay's own cost while running is a send per frame and a
receive per estimate. The session loops with frame indices and timestamps going on (a window across the seam is
just another window).

Phases. Devices that run independently end their windows at unrelated moments, so by default the devices start
evenly spread over one estimate period (``end_stride`` frames) and their window ends arrive at an even pace. With
``bunched`` they start within one frame period: every device's window ends in the same frame period, and the
service gets them as one burst per estimate period (the worst case, as if all devices had been started together
to the frame).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import zmq

from seesys.core import messages
from seesys.core.messages import Estimate, FeatureFrame
from seesys.core.windows import WindowConfig
from seesys.io.transport import open_socket


@dataclass
class FleetResult:
    """What the simulated devices saw: per estimate, its device, frame index and latency (ms)."""

    devices: int
    duration_s: float
    frames_sent: int
    window_ends_sent: int
    latency_ms: list[float] = field(default_factory=list)
    estimates: list[Estimate] = field(default_factory=list)

    @property
    def estimates_per_s(self) -> float:
        return len(self.estimates) / self.duration_s

    def percentiles(self) -> tuple[float, float, float]:
        if not self.latency_ms:
            return (float("nan"),) * 3
        p50, p90, p99 = np.percentile(self.latency_ms, [50, 90, 99])
        return float(p50), float(p90), float(p99)


def looped(frames: Sequence[FeatureFrame], count: int, device_id: str, rate_hz: float) -> list[FeatureFrame]:
    """``count`` frames of ``frames`` played in a loop as ``device_id``, indices and timestamps continuing."""
    n = len(frames)
    return [replace(frames[k % n], device_id=device_id, frame_index=k, timestamp=k / rate_hz) for k in range(count)]


def send_schedule(devices: int, frames: int, rate_hz: float, spread_s: float) -> list[tuple[float, int, int]]:
    """``(due time in s from the start, device, frame index)`` of every message, in time order: each device sends
    ``frames`` frames at ``rate_hz``, and the devices' first frames are spread evenly over ``spread_s``."""
    return sorted((k / rate_hz + j * spread_s / devices, j, k) for j in range(devices) for k in range(frames))


class DeviceFleet:
    """``devices`` simulated devices connected to a service (``ingest_endpoint`` in, ``estimates_endpoint`` out).

    ``socket_options`` (CurveZMQ client keys) apply to every connection."""

    def __init__(
        self,
        ingest_endpoint: str,
        estimates_endpoint: str,
        device_ids: Sequence[str],
        socket_options: dict | None = None,
        send_hwm: int = 1000,
    ):
        self.ctx = zmq.Context()
        self.device_ids = list(device_ids)
        self._pubs = [
            open_socket(
                self.ctx,
                zmq.PUB,
                ingest_endpoint,
                f"simulated device {d}",
                bind=False,
                send_hwm=send_hwm,
                options=socket_options,
            )
            for d in self.device_ids
        ]
        self._sub = open_socket(
            self.ctx,
            zmq.SUB,
            estimates_endpoint,
            "estimates",
            bind=False,
            subscribe=[messages.topic(messages.ESTIMATE_TOPIC, d) for d in self.device_ids],
            options=socket_options,
        )

    def replay(
        self,
        frames: Sequence[FeatureFrame],
        duration_s: float,
        rate_hz: float,
        windows: WindowConfig,
        drain_s: float = 1.0,
        bunched: bool = False,
    ) -> FleetResult:
        """Send ``duration_s`` of frames per device at ``rate_hz``, then wait up to ``drain_s`` for estimates;
        ``bunched``: see the module's docstring."""
        count = int(duration_s * rate_hz)
        n = len(self.device_ids)
        encoded = [[messages.encode(f) for f in looped(frames, count, d, rate_hz)] for d in self.device_ids]
        spread_s = (1 if bunched else windows.end_stride) / rate_hz
        schedule = send_schedule(n, count, rate_hz, spread_s)
        sent_at: dict[tuple[str, int], float] = {}
        result = FleetResult(n, duration_s, 0, 0)
        start = time.perf_counter()
        for due, j, k in schedule:
            while True:
                wait = start + due - time.perf_counter()
                if wait <= 0:
                    break
                self._receive(result, sent_at, timeout_ms=max(1, int(wait * 1000)))
            self._pubs[j].send_multipart(encoded[j][k], zmq.NOBLOCK)
            result.frames_sent += 1
            if windows.is_psd_frame(k):
                sent_at[(self.device_ids[j], k)] = time.perf_counter()
                result.window_ends_sent += 1
        deadline = time.perf_counter() + drain_s
        while time.perf_counter() < deadline:
            self._receive(result, sent_at, timeout_ms=int(1000 * (deadline - time.perf_counter())) + 1)
        return result

    def _receive(self, result: FleetResult, sent_at: dict, timeout_ms: int) -> None:
        if not self._sub.poll(timeout_ms):
            return
        while True:
            try:
                parts = self._sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            now = time.perf_counter()
            estimate = messages.decode(parts)
            if not isinstance(estimate, Estimate):  # not on the estimates' topics this socket subscribes to
                continue
            sent = sent_at.pop((estimate.device_id, estimate.frame_index), None)
            result.estimates.append(estimate)
            if sent is not None:
                result.latency_ms.append((now - sent) * 1000.0)

    def close(self) -> None:
        for sock in [*self._pubs, self._sub]:
            sock.close()
        self.ctx.term()
