"""The feature stream: device → estimator over ZeroMQ publish-subscribe, one :class:`FeatureFrame` per frame.

The device's PUB socket binds ``features_endpoint`` of ``configs/network.toml``; estimators and advisories
connect SUB sockets. A PUB socket never blocks its sender: with no subscriber, messages are discarded, and when a
subscriber lags by more than the high-water mark, new messages are dropped (counted here) — the device keeps
tracking and logging either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import zmq

from seesys.errors import SeesysError
from seesys.protocol import messages
from seesys.protocol.messages import FeatureFrame, MessageError


class StreamError(SeesysError):
    """The feature stream socket cannot be opened."""


def _zmtp_frame_overhead(size: int) -> int:
    # ZMTP 3 frame header: flags + 1-byte size up to 255 bytes, flags + 8-byte size beyond.
    return 2 if size <= 255 else 9


@dataclass
class StreamStats:
    messages: int = 0
    payload_bytes: int = 0
    wire_bytes: int = 0
    dropped: int = 0


class FeaturePublisher:
    """Publishes feature frames on a bound PUB socket, counting what it sends."""

    def __init__(self, endpoint: str, send_high_water_mark: int):
        self.endpoint = endpoint
        self._socket = zmq.Context.instance().socket(zmq.PUB)
        self._socket.setsockopt(zmq.SNDHWM, send_high_water_mark)
        self._socket.setsockopt(zmq.LINGER, 0)
        try:
            self._socket.bind(endpoint)
        except zmq.ZMQError as e:
            self._socket.close()
            raise StreamError(f"cannot open the feature stream on {endpoint}: {e}") from None
        #: The endpoint actually bound (differs from ``endpoint`` when that uses a wildcard port, ``tcp://host:*``).
        self.bound_endpoint = self._socket.getsockopt_string(zmq.LAST_ENDPOINT)
        self.stats = StreamStats()

    def publish(self, frame: FeatureFrame) -> None:
        parts = messages.encode(frame)
        try:
            self._socket.send_multipart(parts, flags=zmq.NOBLOCK)
        except zmq.Again:
            self.stats.dropped += 1
            return
        payload = sum(len(p) for p in parts)
        self.stats.messages += 1
        self.stats.payload_bytes += payload
        self.stats.wire_bytes += payload + sum(_zmtp_frame_overhead(len(p)) for p in parts)

    def close(self) -> None:
        self._socket.close()


class FeatureSubscriber:
    """Receives feature frames from a device's PUB socket; malformed messages are counted and skipped."""

    def __init__(self, endpoint: str, device_id: str = ""):
        self._socket = zmq.Context.instance().socket(zmq.SUB)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.setsockopt(zmq.SUBSCRIBE, messages.FEATURE_TOPIC + device_id.encode("utf-8"))
        try:
            self._socket.connect(endpoint)
        except zmq.ZMQError as e:
            self._socket.close()
            raise StreamError(f"cannot connect to the feature stream at {endpoint}: {e}") from None
        self.malformed = 0

    def receive(self, timeout_ms: int) -> FeatureFrame | None:
        """The next valid feature frame, or None when none arrives within ``timeout_ms``."""
        while self._socket.poll(timeout_ms):
            try:
                message = messages.decode(self._socket.recv_multipart())
            except MessageError:
                self.malformed += 1
                continue
            if isinstance(message, FeatureFrame):
                return message
            self.malformed += 1
        return None

    def close(self) -> None:
        self._socket.close()
