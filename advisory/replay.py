"""``seesys advisory replay``: publish an estimate log as :class:`Estimate` messages at its original pace.

It binds the estimator's endpoint (``network.toml``'s ``estimates_endpoint``) exactly as the estimator service
does, so the advisory can run live before (or without) the estimator.
"""

from __future__ import annotations

import time

import zmq
from rich.progress import Progress

from advisory.config import ReplayConfig
from advisory.estimate_log import EstimateLog
from seesys.network import NetworkConfig
from seesys.protocol.messages import Estimate, encode
from seesys.protocol.transport import publisher


def replay_estimates(log: EstimateLog, replay: ReplayConfig, network: NetworkConfig, show_progress: bool) -> int:
    """Publish every estimate at ``start + (timestamp − first timestamp)``; returns how many were sent."""
    ctx = zmq.Context()
    pub = publisher(ctx, network.estimates_endpoint, "estimates", network.send_high_water_mark)
    try:
        time.sleep(replay.replay_settle_s)  # subscribers connect; PUB drops what it sends before that
        start = time.monotonic()
        first = float(log.timestamps[0])
        with Progress(disable=not show_progress, transient=True) as progress:
            task = progress.add_task("replaying estimates", total=log.timestamps.size)
            for index, (timestamp, error_m) in enumerate(zip(log.timestamps, log.errors_m)):
                delay = start + (float(timestamp) - first) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                pub.send_multipart(encode(Estimate(replay.replay_device_id, index, float(timestamp),
                                                   float(error_m), replay.replay_model_version)))
                progress.advance(task)
        return int(log.timestamps.size)
    finally:
        pub.close()
        ctx.term()
