"""``seesys advisory replay``: publish an estimate log as :class:`Estimate` messages at its original pace, each with
the log's head probabilities and their thresholds where the log has them.

It binds the estimator's endpoint (``network.toml``'s ``estimates_endpoint``) exactly as the estimator service
does, so the advisory can run live before (or without) the estimator. Optionally it logs when it sent each
estimate, so that its pace can be checked from its own send times rather than from when a receiver woke up.

A replay that stands in for the estimator of a session (``seesys study run --replay-estimates``) is started with
the session's other listeners and waits for the device: its schedule begins when the device's first feature frame
arrives, as a live estimator's estimates begin with the device's frames, whatever its own start-up cost.
"""

from __future__ import annotations

import time
from pathlib import Path

import zmq
from rich.progress import Progress

from advisory.config import ReplayConfig
from advisory.estimate_log import EstimateLog
from seesys.core.messages import FEATURE_TOPIC, Estimate, Exceedance, encode, topic
from seesys.io.logfiles import CsvLog
from seesys.io.network import NetworkConfig
from seesys.io.transport import publisher, subscriber

SENT_LOG_COLUMNS = ("frame_index", "timestamp", "sent_mono")


def _wait_until(due: float) -> float:
    """Sleep until CLOCK_MONOTONIC reaches ``due`` (never returns earlier); returns the clock's reading then."""
    while (now := time.monotonic()) < due:
        time.sleep(due - now)
    return now


def _wait_for_first_frame(ctx: zmq.Context, network: NetworkConfig, device_id: str) -> None:
    """Block until ``device_id``'s first feature frame arrives on ``features_endpoint`` (its content unread)."""
    sub = subscriber(ctx, network.features_endpoint, "features", [topic(FEATURE_TOPIC, device_id)])
    try:
        sub.recv_multipart()
    finally:
        sub.close()


def replay_estimates(
    log: EstimateLog,
    replay: ReplayConfig,
    network: NetworkConfig,
    show_progress: bool,
    sent_log: Path | None = None,
    start_with_device: str | None = None,
) -> int:
    """Publish every estimate at ``first send + (timestamp − first timestamp)``; returns how many were sent.

    Each estimate carries the log's frame index (the row number in a log without a ``frame_index`` column).
    No estimate is sent before its time. One that falls behind (a busy machine) is sent at once and the ones
    after it keep the original schedule, so the replay does not drift. With ``sent_log``, each estimate's
    ``frame_index``, ``timestamp`` and ``sent_mono`` (CLOCK_MONOTONIC just before the send) is written to that
    CSV, one flushed row per estimate; the file appears (its header) once the publisher is bound and settled, so
    a supervisor may take it for "ready", and a log that cannot be written is a :class:`SeesysError` before
    anything is sent. With ``start_with_device``, the first estimate is sent when that device's first feature
    frame arrives (it waits for it as long as it runs).
    """
    ctx = zmq.Context()
    pub = publisher(ctx, network.estimates_endpoint, "estimates", network.send_high_water_mark)
    sent: CsvLog | None = None
    try:
        time.sleep(replay.replay_settle_s)  # subscribers connect; PUB drops what it sends before that
        sent = CsvLog(sent_log, SENT_LOG_COLUMNS) if sent_log is not None else None
        if start_with_device is not None:
            _wait_for_first_frame(ctx, network, start_with_device)
        first = float(log.timestamps[0])
        start = time.monotonic()
        with Progress(disable=not show_progress, transient=True) as progress:
            task = progress.add_task("replaying estimates", total=log.timestamps.size)
            for index, (timestamp, error_m) in enumerate(zip(log.timestamps, log.errors_m)):
                sent_mono = _wait_until(start + (float(timestamp) - first))
                if index == 0:
                    start = sent_mono  # the schedule runs from the first send, however late that was
                frame_index = log.frame_index(index)
                head = tuple(Exceedance(t, p) for t, p in zip(log.head_thresholds_m, log.head(index) or ()))
                pub.send_multipart(
                    encode(
                        Estimate(
                            replay.replay_device_id,
                            frame_index,
                            float(timestamp),
                            float(error_m),
                            replay.replay_model_version,
                            head=head,
                        )
                    )
                )
                if sent is not None:
                    sent.write(frame_index, float(timestamp), sent_mono)
                progress.advance(task)
        return int(log.timestamps.size)
    finally:
        pub.close()
        ctx.term()
        if sent is not None:
            sent.close()
