"""The feature stream: device → estimator over ZeroMQ publish-subscribe, one :class:`FeatureFrame` per frame.

The device's PUB socket binds ``features_endpoint`` of ``configs/network.toml``; estimators and advisories
connect SUB sockets. A PUB socket never blocks its sender: with no subscriber, messages are discarded, and when a
subscriber lags by more than the high-water mark, new messages are dropped — the device keeps tracking and logging
either way. ZeroMQ does not tell the sender what it dropped, so the publisher counts only what it sent, and every
message carries the device's count of frames it did not publish; the subscriber counts per device what it
missed (:class:`seesys.io.transport.LossCounter`).

With CurveZMQ configured (``[curve]`` of ``network.toml``), the device also connects a second PUB socket, encrypted
with its own key pair, to the estimator service's ``ingest_endpoint`` and publishes every frame there too: an
encrypting service accepts only connections its clients make, and the bound stream stays for local subscribers
(the device's own estimate observer, an advisory on the device).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import zmq

from seesys.core import messages
from seesys.core.messages import FeatureFrame, MessageError
from seesys.io.network import NetworkConfig
from seesys.io.transport import LossCounter, bound_endpoint, publisher, subscriber


def zmtp_frame_overhead(size: int) -> int:
    """Bytes ZeroMQ adds on the wire to a message part of ``size`` bytes."""
    # ZMTP 3 frame header: flags + 1-byte size up to 255 bytes, flags + 8-byte size beyond.
    return 2 if size <= 255 else 9


@dataclass
class StreamStats:
    """What the device handed to its PUB socket (not what arrived: PUB cannot know that)."""

    messages: int = 0
    payload_bytes: int = 0
    wire_bytes: int = 0


class FeaturePublisher:
    """Publishes feature frames on a bound PUB socket, counting what it sends; and, where ``service_endpoint`` is
    given, on a PUB socket connected there with ``service_options`` (the device's Curve keys)."""

    def __init__(
        self,
        endpoint: str,
        send_high_water_mark: int,
        service_endpoint: str | None = None,
        service_options: Mapping[int, int | bytes] | None = None,
    ):
        self.endpoint = endpoint
        ctx: zmq.Context = zmq.Context.instance()
        self._socket = publisher(ctx, endpoint, "feature stream", send_high_water_mark)
        #: The endpoint actually bound (differs from ``endpoint`` when that uses a wildcard port, ``tcp://host:*``).
        self.bound_endpoint = bound_endpoint(self._socket)
        #: The socket connected to the service (None: the service connects to the bound one), for a socket monitor
        #: that sees the handshake a service refuses (``zmq.EVENT_HANDSHAKE_FAILED_AUTH``: a key not allowed).
        self.service_socket: zmq.Socket | None = None
        if service_endpoint is not None:
            self.service_socket = publisher(
                ctx,
                service_endpoint,
                "estimator service ingest",
                send_high_water_mark,
                bind=False,
                options=service_options,
            )
        self._sockets = [s for s in (self._socket, self.service_socket) if s is not None]
        self.stats = StreamStats()

    @classmethod
    def for_network(cls, network: NetworkConfig) -> FeaturePublisher:
        """The device's publisher of ``network.toml``: bound at ``features_endpoint``, and connected to the
        service's ``ingest_endpoint`` with the device's keys when ``[curve]`` is set."""
        if not network.curve.enabled:
            return cls(network.features_endpoint, network.send_high_water_mark)
        return cls(
            network.features_endpoint,
            network.send_high_water_mark,
            network.ingest_endpoint,
            network.client_options(network.ingest_endpoint),
        )

    def publish(self, frame: FeatureFrame) -> None:
        parts = messages.encode(frame)
        for sock in self._sockets:
            sock.send_multipart(parts, flags=zmq.NOBLOCK)
        payload = sum(len(p) for p in parts)
        self.stats.messages += 1
        self.stats.payload_bytes += payload
        self.stats.wire_bytes += payload + sum(zmtp_frame_overhead(len(p)) for p in parts)

    def close(self) -> None:
        for sock in self._sockets:
            sock.close()


class FeatureSubscriber:
    """Receives feature frames from a device's PUB socket (one device, or every device with ``device_id=None``).

    Malformed messages and messages of another protocol or RTS schema are counted in ``malformed`` and skipped;
    frames that never arrived are counted per device in ``losses``.
    """

    def __init__(self, endpoint: str, device_id: str | None = None, receive_high_water_mark: int | None = None):
        topic = messages.FEATURE_TOPIC if device_id is None else messages.topic(messages.FEATURE_TOPIC, device_id)
        self._socket = subscriber(
            zmq.Context.instance(), endpoint, "feature stream", [topic], receive_hwm=receive_high_water_mark
        )
        self.malformed = 0
        self.losses = LossCounter()

    def receive(self, timeout_ms: int) -> FeatureFrame | None:
        """The next valid feature frame, or None when none arrives within ``timeout_ms``."""
        while self._socket.poll(timeout_ms):
            try:
                message = messages.decode(self._socket.recv_multipart())
            except MessageError:
                self.malformed += 1
                continue
            if isinstance(message, FeatureFrame):
                self.losses.observe(message)
                return message
            self.malformed += 1
        return None

    def close(self) -> None:
        self._socket.close()
