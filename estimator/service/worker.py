"""A worker process: a :class:`~estimator.service.worker_core.WorkerCore` (the windows of the devices the broker
routes to it, the model's batches, the estimates) behind a DEALER socket connected to the broker.

Loop. The worker reads every frame already waiting (at most ``max_batch × end_stride × 4`` per round, so a flood
cannot starve the model) and adds each to its core, then serves one batch of the ready windows and sends their
estimates to the broker. A window's age is measured on the worker's own monotonic clock, from the moment the worker
received its last frame, plus the age the broker reported when it forwarded it: no wall clock of another machine is
compared with this one's. Every ``heartbeat_ms`` it reports its counters to the broker. SIGINT and SIGTERM end the
loop after the current batch; so does a stop message from the broker.
"""

from __future__ import annotations

import gc
import os
import signal
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

import zmq

from estimator.service import envelope
from estimator.service.config import ServiceConfig
from estimator.service.model import ServedModel
from estimator.service.worker_core import WorkerCore
from seesys.core.windows import WindowConfig
from seesys.io.processes import die_with_parent
from seesys.io.transport import open_socket


class Worker:
    """One worker process's socket and loop; :meth:`run` returns when told to stop."""

    def __init__(
        self,
        broker_endpoint: str,
        model: ServedModel,
        windows: WindowConfig,
        config: ServiceConfig,
        name: str | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.core = WorkerCore(model, windows, config, name or f"{socket.gethostname()}:{os.getpid()}", clock)
        self._stopping = False
        self._ctx = zmq.Context()
        # The broker's ROUTER bounds what it queues for us (worker_queue); our own receive queue is bounded too.
        self._socket = open_socket(
            self._ctx,
            zmq.DEALER,
            broker_endpoint,
            "estimator broker",
            bind=False,
            receive_hwm=config.worker_queue,
            send_hwm=config.worker_queue,
        )
        self._drain_limit = config.max_batch * windows.end_stride * 4

    @property
    def name(self) -> str:
        return self.core.name

    def stop(self, *_: object) -> None:
        self._stopping = True

    def run(self) -> None:
        # The loaded model and its modules live as long as the loop: frozen out of the garbage collector, a full
        # collection no longer walks them (tens of ms, in the middle of some window's path).
        gc.freeze()
        core = self.core
        self._send([envelope.READY, envelope.pack_json(core.identity())])
        next_heartbeat = time.monotonic()
        try:
            while not self._stopping:
                timeout = 0 if core.has_ready else self.config.heartbeat_ms
                if self._socket.poll(timeout):
                    self._drain()
                if core.has_ready and not self._stopping:
                    estimates = core.serve_batch()
                    if estimates:
                        self._send([envelope.ESTIMATES, *envelope.pack_estimates(estimates)])
                if time.monotonic() >= next_heartbeat:
                    self._send([envelope.STATS, envelope.pack_json(core.report())])
                    next_heartbeat = time.monotonic() + self.config.heartbeat_ms / 1000.0
        finally:
            self._socket.close()
            self._ctx.term()

    def _send(self, parts: list[bytes]) -> None:
        """Send to the broker without ever blocking: while it is gone, messages queue up to the high-water mark and
        the rest are dropped (estimates by then stale, reports superseded by the next)."""
        try:
            self._socket.send_multipart(parts, zmq.NOBLOCK)
        except zmq.Again:
            self.core.counters.undelivered += 1

    def _drain(self) -> None:
        read = 0  # frames, at most the drain limit (a message may carry several)
        while read < self._drain_limit:
            try:
                parts = self._socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if parts[0] == envelope.STOP:
                self._stopping = True
                return
            if parts[0] == envelope.FRAME:
                arrived = time.perf_counter()
                for token, age_ms, frame in envelope.unpack_frames(parts):  # decoded and validated by the broker
                    self.core.add(token, age_ms, self.core.clock() - age_ms / 1000.0, arrived, frame)
                    read += 1


def run_worker(
    broker_endpoint: str, model_path: Path, windows: WindowConfig, config: ServiceConfig, name: str | None = None
) -> None:
    """Load the model on one intra-op thread and the configured execution providers, say which provider runs it,
    and serve until SIGINT, SIGTERM or a stop from the broker."""
    model = ServedModel.load(model_path, windows, threads=1, providers=config.providers)
    worker = Worker(broker_endpoint, model, windows, config, name)
    print(
        f"estimator worker {worker.name}: model {model.version} on {model.provider}, broker {broker_endpoint}",
        file=sys.stderr,
        flush=True,
    )
    signal.signal(signal.SIGINT, worker.stop)
    signal.signal(signal.SIGTERM, worker.stop)
    worker.run()


def worker_process_main(
    broker_endpoint: str, model_path: Path, windows: WindowConfig, config: ServiceConfig, parent_pid: int, name: str
) -> None:
    """Entry point of a worker started by ``serve``: dies with its parent (a SIGKILLed service leaves no worker)."""
    die_with_parent(parent_pid)
    run_worker(broker_endpoint, model_path, windows, config, name)
