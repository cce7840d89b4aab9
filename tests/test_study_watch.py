"""The runner's and the app's stream watcher listens to its own device: its feature topic, its estimate topic and, of
the estimates, those of the stream session its device's frames state (an earlier run's still in flight, or another
device on a shared estimator, are not this person's information)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pandas as pd
import zmq
from testkit.polling import wait_for

from seesys.core import rts_schema
from seesys.core.messages import Estimate, FeatureFrame, encode
from seesys.core.tracking_state import TrackingState
from seesys.io.network import load_network_config
from seesys.io.transport import open_socket
from study.estimates import ESTIMATES_CSV
from study.watch import StreamWatcher

OURS, THEIRS, SESSION, EARLIER = "mine", "theirs", 7, 3


def _frame(device: str, index: int, state: TrackingState, session: int) -> FeatureFrame:
    return FeatureFrame(
        device, index, index / 30, state, np.zeros(rts_schema.NUM_CHANNELS, np.float32), stream_session=session
    )


def test_the_watcher_takes_its_devices_estimates_of_its_stream_session_only(tmp_path):
    network = dataclasses.replace(
        load_network_config(),
        features_endpoint=f"ipc://{tmp_path}/features",
        estimates_endpoint=f"ipc://{tmp_path}/estimates",
    )
    ctx = zmq.Context()
    features = open_socket(ctx, zmq.PUB, network.features_endpoint, "features", bind=True)
    estimates = open_socket(ctx, zmq.PUB, network.estimates_endpoint, "estimates", bind=True)
    watcher = StreamWatcher(network, tmp_path, OURS)
    watcher.start()
    try:
        assert watcher.wait_ready(30)
        index = 0

        def publish_until(condition) -> bool:
            # PUB drops what it sends before a subscription arrives: send again until the watcher has it.
            nonlocal index
            index += 1
            state = TrackingState.OK if index % 2 else TrackingState.LOST
            features.send_multipart(encode(_frame(OURS, index, state, SESSION)))
            features.send_multipart(encode(_frame(THEIRS, index, TrackingState.OK, 99)))
            for device, session, error in ((OURS, SESSION, 0.004), (OURS, EARLIER, 0.5), (THEIRS, 99, 0.9)):
                estimates.send_multipart(
                    encode(Estimate(device, index, index / 30, error, "m", stream_session=session))
                )
            return condition()

        wait_for(
            lambda: publish_until(
                lambda: watcher.stream_session == SESSION and watcher.estimates >= 3 and watcher.foreign_estimates >= 3
            ),
            what=lambda: (
                f"session {watcher.stream_session}, {watcher.estimates} estimates, "
                f"{watcher.foreign_estimates} foreign, error {watcher.error}"
            ),
        )
        assert watcher.error is None
        assert 0 < watcher.tracked_frames < index  # the tracked ones of our device only (every other is LOST)
        assert watcher.last_frame_mono is not None and watcher.last_frame_mono <= time.monotonic()
    finally:
        watcher.stop()
        features.close()
        estimates.close()
        ctx.term()
    logged = pd.read_csv(tmp_path / ESTIMATES_CSV)
    assert len(logged) == watcher.estimates and set(logged.device_id) == {OURS}
    assert (logged.error_m == 0.004).all()  # neither the earlier session's nor the other device's
