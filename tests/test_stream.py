"""The feature stream over real ZeroMQ sockets on loopback."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zmq

from seesys.protocol import rts_schema
from seesys.protocol.messages import FeatureFrame
from slam_monitor.stream import FeaturePublisher, FeatureSubscriber, StreamError
from seesys.protocol.tracking_state import TrackingState


def feature_frame(i: int, psd: bool) -> FeatureFrame:
    rng = np.random.default_rng(i)
    matrix = np.zeros((96, 128, 3), dtype=np.uint8)
    matrix[24:72, 32:96][rng.random((48, 64)) < 0.2] = 200
    return FeatureFrame("dev-7", i, 10.0 + i / 30, TrackingState.OK,
                        rng.normal(size=rts_schema.NUM_CHANNELS).astype(np.float32), matrix if psd else None)


@pytest.fixture
def publisher():
    pub = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=100)
    yield pub
    pub.close()


def _connect(publisher: FeaturePublisher, device: str = "") -> FeatureSubscriber:
    sub = FeatureSubscriber(publisher.bound_endpoint, device)
    # PUB-SUB "slow joiner": wait until the subscription has reached the publisher.
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        publisher.publish(feature_frame(0, psd=False))
        if sub.receive(timeout_ms=50) is not None:
            while sub.receive(timeout_ms=50) is not None:
                pass
            return sub
    raise AssertionError("subscriber never connected")


def test_frames_arrive_intact_and_in_order(publisher):
    sub = _connect(publisher)
    sent = [feature_frame(i, psd=i % 10 == 0) for i in range(1, 31)]
    for f in sent:
        publisher.publish(f)
    received = [sub.receive(timeout_ms=2000) for _ in sent]
    sub.close()
    assert [r.frame_index for r in received] == list(range(1, 31))
    for a, b in zip(sent, received):
        np.testing.assert_array_equal(a.rts, b.rts)
        assert (a.psd is None) == (b.psd is None)
        if a.psd is not None:
            np.testing.assert_array_equal(a.psd, b.psd)
        assert (b.device_id, b.timestamp, b.tracking_state) == (a.device_id, a.timestamp, a.tracking_state)


def test_publishing_with_nobody_listening_never_blocks(publisher):
    for i in range(500):                              # a blocking send would hang here (pytest timeout)
        publisher.publish(feature_frame(i, psd=True))
    assert publisher.stats.messages + publisher.stats.dropped == 500
    assert publisher.stats.wire_bytes > publisher.stats.payload_bytes > 500 * 100


def test_device_filter_and_malformed_messages_are_counted(publisher):
    sub = _connect(publisher, device="dev-7")
    other = feature_frame(5, psd=False)
    publisher.publish(FeatureFrame("dev-8", 5, other.timestamp, other.tracking_state, other.rts))
    publisher.publish(feature_frame(6, psd=False))
    assert sub.receive(timeout_ms=2000).frame_index == 6
    raw = zmq.Context.instance().socket(zmq.PUB)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    bad = FeatureSubscriber(f"tcp://127.0.0.1:{port}")
    time.sleep(0.3)
    raw.send_multipart([b"F/dev-7", b"SEES\x63garbage"])
    assert bad.receive(timeout_ms=500) is None
    assert bad.malformed == 1
    raw.close()
    bad.close()
    sub.close()


def test_endpoint_in_use_is_a_clear_error(publisher):
    with pytest.raises(StreamError, match="cannot open the feature stream on"):
        FeaturePublisher(publisher.bound_endpoint, send_high_water_mark=10)
