"""The broker → worker frames: every field of a decoded feature frame reaches the worker as the broker decoded it,
and several frames travel in one message."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import zmq
from testkit.service import device_frames

from estimator.service import envelope, stages
from seesys.core import messages, rts_schema
from seesys.core.device_settings import DeviceSettings
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState


def _frame(with_psd: bool, with_settings: bool, psd_skipped: bool = False) -> FeatureFrame:
    rng = np.random.default_rng(1)
    psd = rng.integers(0, 255, (96, 128, 3), dtype=np.uint8) if with_psd else None
    settings = DeviceSettings("mono", 15, 1200, 16, 2, 0.75, 1) if with_settings else None
    # Every field away from its default, so that one the envelope leaves out shows.
    return FeatureFrame(
        "dev-7",
        12345,
        411.5,
        TrackingState.RECENTLY_LOST,
        rng.normal(size=rts_schema.NUM_CHANNELS).astype(np.float32),
        psd,
        frames_skipped=3,
        rts_schema_version=rts_schema.SCHEMA_VERSION,
        rts_schema_fingerprint=0xABCDEF12,
        stream_session=0xFEEDFACE12345678,
        settings=settings,
        translation_covariance=np.array([[4e-6, 1e-7, 0], [1e-7, 2e-6, -3e-7], [0, -3e-7, 9e-6]]) if with_psd else None,
        psd_skipped=psd_skipped,
    )


@pytest.mark.parametrize(
    ("with_psd", "with_settings", "psd_skipped"),
    [(True, True, False), (False, True, False), (True, False, False), (False, True, True)],
)
def test_every_field_of_a_frame_reaches_the_worker_unchanged(with_psd, with_settings, psd_skipped):
    frame = _frame(with_psd, with_settings, psd_skipped)
    other = dataclasses.replace(frame, device_id="dev-8", frame_index=12346)
    # one message of two frames, as a worker's socket receives it
    parts = [envelope.FRAME, envelope.pack_frame(1234.5, 0.25, frame), envelope.pack_frame(1234.75, 0.5, other)]
    (token, age_ms, received), (*times, second) = envelope.unpack_frames(parts)
    assert (token, age_ms, times) == (1234.5, 0.25, [1234.75, 0.5])
    assert (second.device_id, second.frame_index) == ("dev-8", 12346)
    for field in dataclasses.fields(FeatureFrame):
        sent, got = getattr(frame, field.name), getattr(received, field.name)
        if isinstance(sent, np.ndarray):
            assert got.dtype == sent.dtype and np.array_equal(got, sent), field.name
        else:
            assert got == sent, field.name


def test_an_estimates_times_come_back_with_it_and_the_broker_keeps_the_newest():
    times = stages.WorkerTimes(0.5, 4.0, (0.25, 0.5, 0.375, 0.75, 2.5, 0.125))  # exact in float32, as they travel
    served = [
        envelope.ServedEstimate(b"E/dev-7\x00", b"body", "dev-7", 7.5, 30, 99, times),
        envelope.ServedEstimate(b"E/d\xc3\xa9v\x00", b"", "d\u00e9v", 8.0, -1, 2**64 - 1, times),
    ]
    assert list(envelope.unpack_estimates(envelope.pack_estimates(served))) == served
    kept = stages.StageTimes(size=2)
    for server_ms in (100.0, 6.0, 8.0):  # the first is pushed out by the two after it
        kept.add(times, publish_ms=0.5, server_ms=server_ms)
    p50 = {stage: t["p50"] for stage, t in kept.percentiles().items()}
    assert list(p50) == list(stages.STAGES)
    assert p50["server"] == 7.0
    assert p50["hops"] == 7.0 - 0.5 - 4.0 - 0.5  # what the broker and the worker did not time themselves
    assert p50["inference"] == 2.5


@pytest.mark.parametrize("reads_psd", [True, False])
def test_the_frames_of_a_round_go_to_their_worker_together_at_most_16_a_message_in_order(setup_factory, reads_psd):
    """Real broker and worker sockets; the round is driven by hand (what ``_from_devices`` does with what it reads
    from the ingest socket), so that how many frames arrived together is not left to timing."""
    from estimator.service.broker import Broker
    from estimator.service.config import load_service_config
    from seesys.io.network import load_network_config

    setup = setup_factory()
    broker = Broker(load_service_config(setup.config_dir), load_network_config(setup.config_dir))
    ctx = zmq.Context()
    worker = ctx.socket(zmq.DEALER)
    worker.setsockopt(zmq.LINGER, 0)
    worker.connect(broker.endpoints["workers"])
    try:
        ready = {"name": "w", "pid": 1, "model_version": "m", "reads_psd": reads_psd}
        worker.send_multipart([envelope.READY, envelope.pack_json(ready)])
        assert broker.wait_for_workers(1, 60)
        outbox: dict = {}
        for frame in device_frames("dev-r", 40):
            broker._ingest_one(messages.encode(frame), "", outbox)
        for identity, items in outbox.items():  # the end of the round
            broker._forward(identity, items)
        received = []
        while len([f for parts in received for f in parts[1:]]) < 40:
            assert worker.poll(60_000), "the broker forwarded fewer than 40 frames"
            received.append(worker.recv_multipart())
        assert [len(parts) - 1 for parts in received] == [16, 16, 8]
        forwarded = [frame for parts in received for _, _, frame in envelope.unpack_frames(parts)]
        assert [frame.frame_index for frame in forwarded] == list(range(40))
        # For a model that reads no PSD the broker reads past each one: the window ends come without, but say so.
        ends = [frame for frame in forwarded if frame.states_settings]
        assert [frame.frame_index for frame in ends] == [
            f.frame_index for f in device_frames("dev-r", 40) if f.psd is not None
        ]
        assert all((frame.psd is not None) == reads_psd and frame.psd_skipped != reads_psd for frame in ends)
        assert broker.status()["devices"]["dev-r"]["frames"] == 40
    finally:
        worker.close()
        ctx.term()
        broker.close()
