"""Helpers for tests that subscribe to a real ZeroMQ publisher."""

from __future__ import annotations

import time

from seesys.io.transport import LossCounter
from slam_monitor.stream import FeatureSubscriber


def wait_until_subscribed(send_probe, sub: FeatureSubscriber, probe_device: str) -> None:
    """PUB-SUB "slow joiner": send probes until one arrives, then drain them and forget them."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        send_probe()
        if sub.receive(timeout_ms=50) is not None:
            while sub.receive(timeout_ms=50) is not None:
                pass
            sub.losses = LossCounter()
            sub.malformed = 0
            return
    raise AssertionError(f"subscriber never connected (probes from {probe_device})")
