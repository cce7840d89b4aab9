"""Where an estimate's time in the service goes: the stages of the path from a window's last frame reaching the
broker to its estimate leaving the broker, each timed on the clock of the process that runs it (no clock is
compared across processes).

- ``ingest`` (broker): frame received → forwarded to its worker (size and version checks, decoding and validating,
  the device's id, packing the decoded frame for the worker);
- ``unpack`` (worker): the decoded frame read from the broker's message;
- ``assemble`` (worker): the frame added to its device's window, the window checked and formed;
- ``queued`` (worker): window formed → its batch starts (frames of other devices read first, an earlier batch);
- ``prepare`` (worker): the batch stacked, its RTS normalised and standardised;
- ``inference`` (worker): the ONNX Runtime run of the batch (every window of a batch waits for all of it);
- ``reply`` (worker): batch done → its estimates encoded and sent to the broker;
- ``publish`` (broker): estimates received from the worker → this one published;
- ``hops`` (the rest): broker → worker and worker → broker, both sockets' queues and the processes' wake-ups;
  the server's total less every stage above;
- ``server`` (broker): the total, frame received → estimate published.

A worker hands its stages back with each estimate (:func:`pack`), with the broker's ``ingest`` (which the broker
sent with the frame) and the worker's own total; the broker adds ``publish`` and ``hops`` and keeps the newest
``latency_window`` of them (:class:`StageTimes`) for ``seesys estimator status``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

#: Timed in the worker, in path order.
WORKER_STAGES = ("unpack", "assemble", "queued", "prepare", "inference", "reply")
#: Every stage in path order, then the total.
STAGES = ("ingest", *WORKER_STAGES, "hops", "publish", "server")
# ingest, the worker's total, then WORKER_STAGES; float32 milliseconds.
_TIMES = struct.Struct(f"<{2 + len(WORKER_STAGES)}f")


@dataclass(frozen=True)
class WorkerTimes:
    """One estimate's times in ms as the worker hands them back: the broker's ``ingest`` (handed through), the
    worker's total (frame received → estimate sent) and each of :data:`WORKER_STAGES`."""

    ingest: float
    worker: float
    stages: tuple[float, ...]


def pack(times: WorkerTimes) -> bytes:
    return _TIMES.pack(times.ingest, times.worker, *times.stages)


def unpack(data: bytes) -> WorkerTimes:
    """Inverse of :func:`pack`; ``struct.error`` for data of another length."""
    ingest, worker, *stages = _TIMES.unpack(data)
    return WorkerTimes(ingest, worker, tuple(stages))


@dataclass
class StageTimes:
    """The newest ``size`` estimates' stages, in ms, in the order of :data:`STAGES` (a ring of rows: adding one
    costs a row's copy, and the status reads the array as it is, without building one from many tuples)."""

    size: int
    _rows: np.ndarray = field(init=False, repr=False)
    _count: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self._rows = np.empty((self.size, len(STAGES)))

    def add(self, times: WorkerTimes, publish_ms: float, server_ms: float) -> None:
        hops = server_ms - times.ingest - times.worker - publish_ms
        self._rows[self._count % self.size] = (times.ingest, *times.stages, hops, publish_ms, server_ms)
        self._count += 1

    def percentiles(self) -> dict[str, dict[str, float]]:
        """Per stage its p50 and p99 (empty before the first estimate)."""
        if not self._count:
            return {}
        p50, p99 = np.percentile(self._rows[: min(self._count, self.size)], [50, 99], axis=0)
        return {stage: {"p50": float(a), "p99": float(b)} for stage, a, b in zip(STAGES, p50, p99)}
