"""The feature stream over real ZeroMQ sockets on loopback."""

from __future__ import annotations

import numpy as np
import pytest
import zmq
from testkit.stream import wait_until_subscribed

from seesys.core import messages, rts_schema
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.io.transport import LossCounter, TransportError, bound_endpoint, publisher
from slam_monitor.stream import FeaturePublisher, FeatureSubscriber


def feature_frame(
    i: int,
    psd: bool,
    device: str = "dev-7",
    noisy_psd: bool = False,
    skipped: int = 0,
    schema_version: int = rts_schema.SCHEMA_VERSION,
) -> FeatureFrame:
    rng = np.random.default_rng(i)
    matrix = np.zeros((96, 128, 3), dtype=np.uint8)
    if noisy_psd:  # does not compress: ~37 kB a message
        matrix = rng.integers(0, 256, matrix.shape, dtype=np.uint8)
    else:
        matrix[24:72, 32:96][rng.random((48, 64)) < 0.2] = 200
    return FeatureFrame(
        device,
        i,
        10.0 + i / 30,
        TrackingState.OK,
        rng.normal(size=rts_schema.NUM_CHANNELS).astype(np.float32),
        matrix if psd else None,
        frames_skipped=skipped,
        rts_schema_version=schema_version,
    )


@pytest.fixture
def feature_publisher():
    pub = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=100)
    yield pub
    pub.close()


def connect(pub: FeaturePublisher, device: str | None = "dev-7") -> FeatureSubscriber:
    sub = FeatureSubscriber(pub.bound_endpoint, device)
    wait_until_subscribed(
        lambda: pub.publish(feature_frame(0, psd=False, device=device or "dev-7")), sub, device or "dev-7"
    )
    return sub


def test_frames_arrive_intact_and_in_order(feature_publisher):
    sub = connect(feature_publisher)
    sent = [feature_frame(i, psd=i % 10 == 0) for i in range(1, 31)]
    for f in sent:
        feature_publisher.publish(f)
    received = [sub.receive(timeout_ms=5000) for _ in sent]
    sub.close()
    assert [r.frame_index for r in received] == list(range(1, 31))
    for a, b in zip(sent, received):
        np.testing.assert_array_equal(a.rts, b.rts)
        assert (a.psd is None) == (b.psd is None)
        if a.psd is not None:
            np.testing.assert_array_equal(a.psd, b.psd)
        assert (b.device_id, b.timestamp, b.tracking_state) == (a.device_id, a.timestamp, a.tracking_state)
    assert sub.losses.devices["dev-7"].lost_in_transit == 0


def test_publishing_with_nobody_listening_never_blocks(feature_publisher):
    for i in range(500):  # a blocking send would hang here (pytest timeout)
        feature_publisher.publish(feature_frame(i, psd=True))
    assert feature_publisher.stats.messages == 500
    assert feature_publisher.stats.wire_bytes > feature_publisher.stats.payload_bytes > 500 * 100


def test_a_device_subscription_does_not_match_a_longer_device_id():
    pub = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=1000)
    sub = connect(pub, device="dev-1")
    everyone = FeatureSubscriber(pub.bound_endpoint, None)
    wait_until_subscribed(lambda: pub.publish(feature_frame(0, psd=False, device="probe")), everyone, "probe")
    for i in range(1, 21):
        pub.publish(feature_frame(i, psd=False, device="dev-10"))
        pub.publish(feature_frame(i, psd=False, device="dev-1"))
    mine = [sub.receive(timeout_ms=5000) for _ in range(20)]
    assert {f.device_id for f in mine} == {"dev-1"}
    assert [f.frame_index for f in mine] == list(range(1, 21))
    assert sub.receive(timeout_ms=200) is None  # nothing of dev-10 is queued behind them
    both = [everyone.receive(timeout_ms=5000) for _ in range(40)]
    assert sorted({f.device_id for f in both}) == ["dev-1", "dev-10"]
    for s in (sub, everyone):
        s.close()
    pub.close()


def test_malformed_and_other_schema_messages_are_counted_and_skipped():
    ctx = zmq.Context.instance()
    raw = publisher(ctx, "tcp://127.0.0.1:*", "test", send_hwm=1000)
    sub = FeatureSubscriber(bound_endpoint(raw), "dev-7")
    wait_until_subscribed(lambda: raw.send_multipart(messages.encode(feature_frame(0, psd=False))), sub, "dev-7")
    topic = messages.topic(messages.FEATURE_TOPIC, "dev-7")
    raw.send_multipart([topic, b"SEES\x63garbage"])
    raw.send_multipart(messages.encode(feature_frame(1, psd=False, schema_version=rts_schema.SCHEMA_VERSION + 1)))
    raw.send_multipart(messages.encode(feature_frame(2, psd=False)))
    good = sub.receive(timeout_ms=5000)
    assert good.frame_index == 2
    assert sub.malformed == 2
    raw.close()
    sub.close()


@pytest.mark.system
def test_a_subscriber_that_stops_reading_counts_what_it_lost():
    pub = FeaturePublisher("tcp://127.0.0.1:*", send_high_water_mark=5)
    sub = FeatureSubscriber(pub.bound_endpoint, "dev-7", receive_high_water_mark=5)
    wait_until_subscribed(lambda: pub.publish(feature_frame(0, psd=False)), sub, "dev-7")
    sent = 300
    for i in range(1, sent + 1):  # the subscriber reads nothing meanwhile; ~11 MB cannot all be buffered
        pub.publish(feature_frame(i, psd=True, noisy_psd=True))
    received = []
    while (frame := sub.receive(timeout_ms=1000)) is not None:
        received.append(frame.frame_index)
    # Frames dropped at the end of the flood leave no gap until a later frame arrives: send one, now that the
    # subscriber reads again, and wait for it.
    pub.publish(feature_frame(sent + 1, psd=False))
    while (frame := sub.receive(timeout_ms=5000)) is not None:
        received.append(frame.frame_index)
        if frame.frame_index == sent + 1:
            break
    assert received[-1] == sent + 1
    loss = sub.losses.devices["dev-7"]
    assert 0 < len(received) - 1 < sent
    assert received == sorted(received)
    assert loss.received == len(received)
    assert loss.lost_in_transit > 0
    assert loss.received + loss.lost_in_transit == received[-1] - received[0] + 1
    assert loss.skipped_by_device == 0
    sub.close()
    pub.close()


def test_loss_counter_tells_device_skips_from_transit_losses():
    counter = LossCounter()
    # frames 3 and 4 were skipped by the device (it says 2 skipped on frame 5); frame 6 was lost on the way
    for index, skipped in [(1, 0), (2, 0), (5, 2), (7, 2), (8, 2)]:
        counter.observe(feature_frame(index, psd=False, skipped=skipped))
    # a second device, restarted: its indices start again
    for index in (10, 11, 0, 1):
        counter.observe(feature_frame(index, psd=False, device="dev-8"))
    mine, other = counter.devices["dev-7"], counter.devices["dev-8"]
    assert (mine.received, mine.skipped_by_device, mine.lost_in_transit) == (5, 2, 1)
    assert (other.received, other.out_of_order, other.lost_in_transit) == (4, 1, 0)
    assert counter.lost_in_transit == 1


def test_endpoint_in_use_is_a_clear_error(feature_publisher):
    with pytest.raises(TransportError, match="cannot bind the feature stream endpoint"):
        FeaturePublisher(feature_publisher.bound_endpoint, send_high_water_mark=10)
