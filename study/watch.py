"""The runner's view of the network: it logs every pose-error estimate of its device it receives
(``estimates.csv``, with the Unix time of arrival) and counts the device's feature frames that did not arrive,
for the status line.

It listens to one device only (its feature topic and its estimate topic), as the advisory does: on a shared
estimator another device's estimates are not this person's information. The device draws a stream session when
it starts and states it on every feature frame; an estimate of another stream session (an earlier run of the
device, still in flight) is counted as foreign and not logged. Replayed estimates (``seesys advisory replay``)
come from their own device id and belong to no stream: all of them are logged.

Both sockets connect (SUB) to the endpoints of ``configs/network.toml``; the publishers (the device's feature
stream, the estimator or ``seesys advisory replay``) bind, so either side may start first. The estimates come
encrypted, with the logger's own key pair, when ``[curve]`` of ``network.toml`` is set. Malformed messages are
counted, not fatal.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import zmq

from seesys.core.messages import ESTIMATE_TOPIC, FEATURE_TOPIC, Estimate, FeatureFrame, MessageError, decode, topic
from seesys.io.logfiles import CsvLog
from seesys.io.network import NetworkConfig
from seesys.io.transport import LossCounter, subscriber
from study.estimates import ESTIMATE_COLUMNS, ESTIMATES_CSV

POLL_MS = 100


class StreamWatcher(threading.Thread):
    """A thread that logs ``device_id``'s estimates (those of ``estimates_from``, a replay's device id, instead when
    given) and watches its feature stream until :meth:`stop`."""

    def __init__(self, network: NetworkConfig, folder: Path, device_id: str, estimates_from: str | None = None):
        super().__init__(name="study-stream-watcher", daemon=True)
        self._network = network
        self._folder = folder
        self._device = device_id
        self._replayed = estimates_from is not None
        self._estimates_topic = topic(ESTIMATE_TOPIC, estimates_from or device_id)
        self.stream_session: int | None = None  # the device's, from its newest feature frame
        self.foreign_estimates = 0  # of another stream session of the device
        self._stopping = threading.Event()
        self._ready = threading.Event()
        self.estimates = 0
        self.tracked_frames = 0  # feature frames with a tracked pose (the rotation rule's input)
        self.last_frame_mono: float | None = None  # time.monotonic() when the newest feature frame arrived
        self.latest_error_m = math.nan
        self.bad_messages = 0
        self.frames_skipped = 0
        self.losses = LossCounter()
        self.error: str | None = None

    def wait_ready(self, timeout_s: float) -> bool:
        return self._ready.wait(timeout_s)

    def stop(self) -> None:
        self._stopping.set()
        self.join()

    def run(self) -> None:
        ctx = zmq.Context()
        log = CsvLog(self._folder / ESTIMATES_CSV, ESTIMATE_COLUMNS)
        sockets = []
        try:
            network = self._network
            sockets = [
                subscriber(
                    ctx,
                    network.estimates_endpoint,
                    "estimates",
                    [self._estimates_topic],
                    options=network.client_options(network.estimates_endpoint),
                ),
                subscriber(ctx, network.features_endpoint, "features", [topic(FEATURE_TOPIC, self._device)]),
            ]
            poller = zmq.Poller()
            for s in sockets:
                poller.register(s, zmq.POLLIN)
            self._ready.set()
            while not self._stopping.is_set():
                for sock, _ in poller.poll(POLL_MS):
                    frames = sock.recv_multipart()
                    arrived = time.time()
                    try:
                        message = decode(frames)
                    except MessageError:
                        self.bad_messages += 1
                        continue
                    if isinstance(message, Estimate):
                        if not self._replayed and message.stream_session != self.stream_session:
                            self.foreign_estimates += 1
                            continue
                        log.write(
                            arrived,
                            message.device_id,
                            message.frame_index,
                            message.timestamp,
                            message.error_m,
                            message.model_version,
                        )
                        self.estimates += 1
                        self.latest_error_m = message.error_m
                    elif isinstance(message, FeatureFrame):
                        self.stream_session = message.stream_session
                        self.losses.observe(message)
                        self.tracked_frames += message.tracking_state.tracked
                        self.last_frame_mono = time.monotonic()
                        self.frames_skipped = message.frames_skipped
        except Exception as e:
            self.error = f"{type(e).__name__}: {e}"
            self._ready.set()
        finally:
            log.close()
            for s in sockets:
                s.close()
            ctx.term()
