"""Estimates as a client API: subscribe to a device's pose-error estimates and read them as typed records.

For applications that adapt to the pose quality (docs/client.md): an AR app placing content only when the pose is
good, an adaptive SLAM front end, a logger. Five lines::

    from seesys.client import EstimateClient

    with EstimateClient("device-0") as client:
        for record in client:                 # blocks; one record per estimate of this device
            if record.error_class >= 2:       # Equation 2's pulse count: 0 good ... 3 bad
                print(f"pose off by {record.error_m * 1000:.1f} mm at frame {record.frame_index}")

The endpoint, Curve keys and Equation 2 come from ``configs/network.toml`` and ``configs/advisory.toml`` (or the
folder in ``$SEESYS_CONFIG_DIR``, or ``config_dir``). Messages are decoded by :mod:`seesys.core.messages`, the
service's own codec, so a client speaks whatever protocol version this SEESys speaks; a message it cannot decode
(another version, garbage) is counted in :attr:`EstimateClient.rejected` and skipped.

**Which estimates.** Every estimate names the device id and the stream session of the frames it was made from (a
random number the device draws when it starts, :mod:`seesys.core.messages`). With ``stream_session`` given, the
client takes only that stream's estimates (counting others in :attr:`EstimateClient.foreign`); without, it takes
every estimate of the device id, and :attr:`EstimateRecord.stream_session` says which stream each came from, so
that an application matches an estimate to its frame by device, stream session and frame index.

**Reconnection.** The subscription is a ZeroMQ SUB socket connected to the service's estimate endpoint; ZeroMQ
reconnects it by itself when the service restarts or the network comes back (every ``reconnect_ivl`` ms, the
ZeroMQ default of 100 ms), and estimates resume when the restarted service has filled a new window (about a second
of frames). Nothing here needs restarting, and a client may start before the service.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zmq

from seesys.core import messages
from seesys.core.equation2 import PulseSettings
from seesys.core.messages import Estimate, MessageError
from seesys.core.pose_covariance import scaled_to_error, translation_pair_covariance
from seesys.io.core_settings import load_label_config, load_pulse_settings
from seesys.io.network import load_network_config
from seesys.io.transport import subscriber


@dataclass(frozen=True)
class EstimateRecord:
    """One estimate of the device's pose error, as the application sees it.

    ``error_m``: the estimated translation error (metres; docs/labels.md); ``error_class``: Equation 2's pulse
    count for it (0 below alpha, up to the maximum, 3 with the paper's values, at or above beta), of this single
    estimate (the audio advisory applies Equation 2 to a 0.33 s moving mean instead); ``frame_index`` and
    ``timestamp``: the device's frame it estimates (the device's clock); ``model_version``: the model that made it;
    ``server_ms``: its time in the service; ``received``: :func:`time.monotonic` when it arrived here;
    ``stream_session``: the device's stream session the estimated frame belongs to; ``translation_covariance``:
    the estimated frame's predicted translation covariance (3×3, m², the world's axes, float16's three significant
    digits; None when the device's monitor predicted none), the Cramér–Rao bound of its pose fit, which leaves out
    the map's own error: on renders two to four times too small in σ at the median (docs/rts-features.md), to be
    inflated before an application fuses it; ``scaled_translation_covariance``: the same scaled so that the label
    pair's σ is ``error_m`` (:func:`seesys.core.pose_covariance.scaled_to_error`: the shape from the pose fit, the
    size from the estimate), the pair being this frame and the one the label's span (``delta_frames``) before it,
    whose estimate this client received; None without both covariances. The stream carries the frames' translation
    blocks only, so the pair here leaves out the first pose's rotation, which ``seesys session export-bag``'s
    scaled covariance includes (docs/device.md).
    """

    device_id: str
    frame_index: int
    timestamp: float
    error_m: float
    error_class: int
    model_version: str
    server_ms: float
    received: float
    stream_session: int = 0
    translation_covariance: np.ndarray | None = None
    scaled_translation_covariance: np.ndarray | None = None

    @property
    def age_s(self) -> float:
        """Seconds since the estimate arrived: an application should not act on an old one."""
        return time.monotonic() - self.received


class EstimateClient:
    """A subscription to one device's estimates; iterate it, or call :meth:`receive` with a timeout.

    ``endpoint`` defaults to ``estimates_endpoint`` of ``network.toml``; Curve keys, when its ``[curve]`` is set,
    encrypt the connection (a key the service does not allow receives nothing). Raises
    :class:`seesys.io.transport.TransportError` for a malformed endpoint and
    :class:`seesys.io.transport.CurveKeyError` for an unreadable key file.
    """

    def __init__(
        self,
        device_id: str,
        endpoint: str | None = None,
        config_dir: Path | None = None,
        pulses: PulseSettings | None = None,
        stream_session: int | None = None,
    ):
        network = load_network_config(config_dir)
        self.endpoint = endpoint or network.estimates_endpoint
        self.device_id = device_id
        self.stream_session = stream_session
        self.pulses = pulses or load_pulse_settings(config_dir)
        self.delta_frames = load_label_config(config_dir).delta_frames
        # The translation covariances of the last estimates by (stream session, frame index): each record's label
        # pair reaches delta_frames back.
        self._covariances: dict[tuple[int, int], np.ndarray] = {}
        self.rejected = 0
        self.foreign = 0  # estimates of the device id from another stream session than ``stream_session``
        self._ctx = zmq.Context()
        self._sub = subscriber(
            self._ctx,
            self.endpoint,
            "estimates",
            [messages.topic(messages.ESTIMATE_TOPIC, device_id)],
            options=network.client_options(self.endpoint),
        )

    def receive(self, timeout_s: float | None = None) -> EstimateRecord | None:
        """The next estimate, or ``None`` when none arrived within ``timeout_s`` (``None``: wait for ever)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            left_ms = -1 if deadline is None else max(0, int((deadline - time.monotonic()) * 1000))
            if not self._sub.poll(left_ms):
                return None
            try:
                message = messages.decode(self._sub.recv_multipart())
            except MessageError:
                self.rejected += 1
                continue
            if not isinstance(message, Estimate):
                self.rejected += 1
            elif self.stream_session is not None and message.stream_session != self.stream_session:
                self.foreign += 1
            else:
                return self._record(message)

    def _scaled(self, estimate: Estimate) -> np.ndarray | None:
        """The estimate's translation covariance scaled to its error, from the pair's earlier estimate's (kept)."""
        covariance = estimate.translation_covariance
        key = (estimate.stream_session, estimate.frame_index)
        if covariance is None:
            return None
        self._covariances[key] = covariance
        earlier = self._covariances.get((estimate.stream_session, estimate.frame_index - self.delta_frames))
        for old in [k for k in self._covariances if k[0] != key[0] or k[1] <= key[1] - self.delta_frames]:
            del self._covariances[old]  # another stream, or older than any later pair needs
        if earlier is None:
            return None
        return scaled_to_error(covariance, translation_pair_covariance(earlier, covariance), estimate.error_m)

    def _record(self, estimate: Estimate) -> EstimateRecord:
        return EstimateRecord(
            estimate.device_id,
            estimate.frame_index,
            estimate.timestamp,
            estimate.error_m,
            self.pulses.pulses(estimate.error_m),
            estimate.model_version,
            estimate.server_ms,
            time.monotonic(),
            estimate.stream_session,
            estimate.translation_covariance,
            self._scaled(estimate),
        )

    def __iter__(self) -> Iterator[EstimateRecord]:
        while True:
            record = self.receive()
            if record is not None:
                yield record

    def close(self) -> None:
        self._sub.close()
        self._ctx.term()

    def __enter__(self) -> EstimateClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
