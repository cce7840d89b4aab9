"""The broker: one process between the devices and the worker pool (the ZeroMQ guide's load-balancing broker).

Sockets (endpoints in ``configs/service.toml`` and ``network.toml``):

- ingest, SUB, bound at ``ingest_endpoint`` of ``network.toml`` (devices connect their PUB) and connected to device
  streams that bind their own PUB; it subscribes to everything, so that nothing sent to it goes uncounted, and every
  message is checked here: larger than ``max_message_bytes`` (*oversized*), of another protocol version
  (*wrong_version*) or anything :func:`seesys.core.messages.decode` refuses (*malformed*) is counted and dropped;
  for a model that reads no PSD (the workers say so when ready) a frame's PSD is read past, its framing checked but
  its codes not inflated, and the frame goes to its worker without it;
- backend, ROUTER, bound at ``worker_endpoint``: workers connect (DEALER) and say READY. A device is given to the
  worker with the fewest devices when its first frame arrives and stays there, so that one worker holds its windows
  and its estimates leave in order. A frame that finds its worker's queue (``worker_queue``) full is dropped and
  counted; a worker silent for ``worker_timeout_ms`` is presumed dead and its devices go to the others;
- estimates, PUB, bound at ``estimates_endpoint``: what the workers return, published for devices, advisories and
  study loggers; an estimate not newer than the last one published for its device is dropped (order is kept even
  while a device moves between workers);
- status, REP, bound at ``status_endpoint``: ``seesys estimator status`` asks, the broker answers in JSON.

A worker in the broker. Given a :class:`~estimator.service.worker_core.WorkerCore` (``workers = 0``), the broker
runs the model itself: that core is one more worker, listed in the status as the others are and given devices as
they are, but its frames are handed to it in this process and its estimates published from the same loop, with no
hop to another process and back. While it runs a batch the broker reads nothing else, so it suits a few devices;
workers that connect to ``worker_endpoint`` still take their share.

Device ids. A device id belongs to the stream that used it first: its stream session (a random number the device
draws when it starts and carries in every frame) and, with Curve on, its public key (the ZAP handler's User-Id of
the connection). Frames with the same id from another stream session or key are refused, logged once per stream
and counted as ``id_in_use`` under that id; the first device's windows and estimates are untouched. A stream whose
device has sent nothing for ``id_takeover_after_s`` loses the id to the next stream that uses it (a device that
restarted), which is logged and counted in ``takeovers``.

Status. Every drop is counted per device by name: the broker's own (``queue_full``, ``no_worker``,
``out_of_order``, ``id_in_use``) and every reason the workers report (``settings_mismatch``,
``shape_mismatch``, ``missing_rts``, ``missing_psd``, ``stale``: :data:`estimator.service.worker_core.DROP_REASONS`).

With ``[curve]`` set the ingest and estimates sockets are CurveZMQ servers and a ZAP handler admits only the
clients in the allow-list.
"""

from __future__ import annotations

import contextlib
import gc
import sys
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import zmq
from zmq.auth.thread import ThreadAuthenticator

from estimator.service import envelope, keys, stages
from estimator.service.config import ServiceConfig
from estimator.service.worker_core import DROP_REASONS, WorkerCore
from seesys.core import messages
from seesys.core.errors import SeesysError
from seesys.core.messages import FeatureFrame, MessageError
from seesys.io.network import NetworkConfig
from seesys.io.transport import LossCounter, bound_endpoint, open_socket

# Messages handled from one socket before the broker looks at the others (keeps estimates flowing under a flood).
_BURST = 256
# Frames for one worker sent as one message: the frames that arrived together go together (one send, one wake-up of
# the worker instead of one each), but no frame waits for more than this many others to be decoded.
_FORWARD_BATCH = 16
# The longest device id an Estimate can carry (a u8 length in seesys.core.messages): a frame whose id, carried in its
# topic, is longer could never be answered, and its estimate's encoding would fail in the worker.
_MAX_DEVICE_ID_BYTES = 255
# The routing id of the worker in the broker's own process: a worker's socket cannot have it (ZeroMQ reserves ids that
# begin with a zero byte, and those it makes itself are five bytes long).
_IN_BROKER = b"\x00in-broker"


class ServiceError(SeesysError):
    """The estimator service cannot start (no workers, bad endpoints, Curve keys) or a peer misbehaves."""


def is_other_protocol_version(body: bytes) -> bool:
    """A SEESys message body (magic, then the version byte) of a protocol version this end does not speak."""
    head = len(messages.MAGIC)
    return len(body) > head and body[:head] == messages.MAGIC and body[head] != messages.PROTOCOL_VERSION


@dataclass
class DeviceState:
    worker: bytes | None = None
    frames: int = 0
    estimates: int = 0
    queue_full: int = 0
    no_worker: int = 0
    out_of_order: int = 0
    id_in_use: int = 0
    takeovers: int = 0
    stream_session: int = 0  # of the stream the id is bound to
    key: str = ""  # its Curve public key (Z85), "" without Curve
    last_frame: float = 0.0  # monotonic time of the bound stream's last frame
    refused_streams: set = field(default_factory=set)  # (stream session, key) refused and logged
    last_published: int = -1
    latency_ms: deque = field(default_factory=deque)
    frame_times: deque = field(default_factory=deque)
    estimate_times: deque = field(default_factory=deque)


@dataclass
class WorkerState:
    identity: bytes
    name: str
    pid: int
    provider: str
    last_seen: float
    forwarded: int = 0
    devices: set[str] = field(default_factory=set)
    report: dict = field(default_factory=dict)


def _rate(times: deque, now: float, window_s: float) -> float:
    while times and times[0] < now - window_s:
        times.popleft()
    return len(times) / window_s


def _percentiles(values: Iterable[float]) -> dict[str, float | None]:
    data = np.asarray(list(values), dtype=float)
    if not data.size:
        return {"p50": None, "p90": None, "p99": None}
    p50, p90, p99 = np.percentile(data, [50, 90, 99])
    return {"p50": float(p50), "p90": float(p90), "p99": float(p99)}


class Broker:
    """The broker's sockets and state; :meth:`run` serves until :meth:`stop`."""

    def __init__(
        self,
        config: ServiceConfig,
        network: NetworkConfig,
        device_endpoints: Iterable[str] = (),
        ctx: zmq.Context | None = None,
        core: WorkerCore | None = None,
    ):
        self.config, self.network = config, network
        self.device_endpoints = list(device_endpoints)
        if config.curve.enabled and self.device_endpoints:
            raise ServiceError(
                "with Curve on, devices connect to ingest_endpoint; the service does not connect to "
                f"device streams ({', '.join(self.device_endpoints)})"
            )
        self.ctx = ctx or zmq.Context()
        self.model_version: str | None = None
        # Whether the served model reads the PSD (its workers say so): if not, the broker reads past each frame's PSD
        # without inflating it and forwards the frame without.
        self.reads_psd = True
        self.devices: dict[str, DeviceState] = {}
        self.workers: dict[bytes, WorkerState] = {}
        self.refused_workers = 0
        self.rejected = {"oversized": 0, "wrong_version": 0, "malformed": 0}
        self.losses = LossCounter()
        self.stages = stages.StageTimes(config.latency_window)
        self.started = time.monotonic()
        self._stopping = False
        self._authenticator: ThreadAuthenticator | None = None
        # The device-facing sockets, from open() on (each set as it opens, so that close() closes what opened).
        self._ingest: zmq.Socket | None = None
        self._estimates: zmq.Socket | None = None
        self._status: zmq.Socket | None = None
        self._backend = open_socket(
            self.ctx,
            zmq.ROUTER,
            config.worker_endpoint,
            "estimator workers",
            bind=True,
            send_hwm=config.worker_queue,
            options={zmq.ROUTER_MANDATORY: 1},
        )
        self.endpoints = {"workers": bound_endpoint(self._backend)}
        self._core = core
        if core is not None:
            self._worker_says(_IN_BROKER, core.report(), is_stats=True)

    # ----------------------------------------------------------------------------------------------- start-up
    def wait_for_workers(self, count: int, timeout_s: float, alive: Callable[[], bool] = lambda: True) -> bool:
        """Handle worker messages until ``count`` workers are ready (True) or :meth:`stop` is called (False);
        raises :class:`ServiceError` on timeout or when ``alive`` says the local workers died."""
        deadline = time.monotonic() + timeout_s
        while len(self.workers) < count:
            if self._stopping:
                return False
            if time.monotonic() > deadline:
                raise ServiceError(f"only {len(self.workers)} of {count} workers were ready after {timeout_s:g} s")
            if not alive():
                raise ServiceError("a worker process ended before it was ready (see its error above)")
            if self._backend.poll(100):
                self._from_workers()
        return True

    def open(self) -> None:
        """Bind the device-facing sockets (after the workers are ready, so no device waits on an empty pool)."""
        cfg = self.config
        server_options: dict = {}
        if cfg.curve.enabled:
            from seesys.io.resources import resolve

            self._authenticator = keys.start_authenticator(self.ctx, resolve(cfg.curve.allowed_clients))
            server_options = keys.server_socket_options(resolve(cfg.curve.server_secret_key))
        self._ingest = ingest = open_socket(
            self.ctx,
            zmq.SUB,
            self.network.ingest_endpoint,
            "feature ingest",
            bind=True,
            receive_hwm=cfg.ingest_queue,
            subscribe=[b""],
            options=server_options,
        )
        self.endpoints["ingest"] = bound_endpoint(ingest)  # before the connects, which change LAST_ENDPOINT
        for endpoint in self.device_endpoints:
            try:
                ingest.connect(endpoint)
            except zmq.ZMQError as e:
                raise ServiceError(f"cannot connect to the device stream at {endpoint}: {e}") from None
        self._estimates = estimates = open_socket(
            self.ctx,
            zmq.PUB,
            self.network.estimates_endpoint,
            "estimates",
            bind=True,
            send_hwm=self.network.send_high_water_mark,
            options=server_options,
        )
        self._status = status = open_socket(self.ctx, zmq.REP, cfg.status_endpoint, "estimator status", bind=True)
        self.endpoints.update(estimates=bound_endpoint(estimates), status=bound_endpoint(status))

    @staticmethod
    def _opened(sock: zmq.Socket | None) -> zmq.Socket:
        """A device-facing socket; RuntimeError before :meth:`open`."""
        if sock is None:
            raise RuntimeError("the broker's device-facing sockets are used before open()")
        return sock

    # ----------------------------------------------------------------------------------------------- loop
    def stop(self, *_: object) -> None:
        self._stopping = True

    def run(self) -> None:
        # Everything alive now (modules, sockets, configs) lives as long as the loop: frozen out of the garbage
        # collector, a full collection no longer walks it (tens of ms, in the middle of some frame's path).
        gc.freeze()
        ingest, status = self._opened(self._ingest), self._opened(self._status)
        poller = zmq.Poller()
        for sock in (self._backend, ingest, status):
            poller.register(sock, zmq.POLLIN)
        core = self._core
        while not self._stopping:
            events = dict(poller.poll(0 if core is not None and core.has_ready else self.config.heartbeat_ms))
            if self._backend in events:
                self._from_workers()
            if ingest in events:
                self._from_devices()
            if core is not None and core.has_ready:
                self._publish(_IN_BROKER, core.serve_batch())
            if status in events:
                status.recv_multipart()
                status.send(envelope.pack_json(self.status()))
            self._expire_workers()

    def close(self) -> None:
        """Tell the workers to stop, close every socket, stop the ZAP handler."""
        for identity in list(self.workers):
            if identity == _IN_BROKER:
                continue
            # Gone or full: it stops on SIGTERM or when its parent ends.
            with contextlib.suppress(zmq.ZMQError):
                self._backend.send_multipart([identity, envelope.STOP], zmq.NOBLOCK)
        for sock in (self._ingest, self._estimates, self._status, self._backend):
            if sock is not None:
                sock.close()
        if self._authenticator is not None:
            self._authenticator.stop()

    # ----------------------------------------------------------------------------------------------- devices
    def _from_devices(self) -> None:
        curve = self.config.curve.enabled
        outbox: dict[bytes, list[tuple[DeviceState, float, FeatureFrame]]] = {}
        ingest = self._opened(self._ingest)
        for _ in range(_BURST):
            try:
                frames = ingest.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                break
            # User-Id: the Curve client's public key, a string property (the stub's get() may give an int too)
            key = str(frames[0].get("User-Id") or "") if curve else ""
            self._ingest_one([f.bytes for f in frames], key, outbox)
        for identity, items in outbox.items():
            if items:
                self._forward(identity, items)

    def _log(self, text: str) -> None:
        print(f"estimator broker: {text}", file=sys.stderr, flush=True)

    def _admit(self, frame: FeatureFrame, key: str, device: DeviceState, now: float) -> bool:
        """Whether ``frame`` belongs to the stream its device id is bound to (binding a new id, or handing an id
        whose stream went silent for ``id_takeover_after_s`` to this one)."""
        stream = (frame.stream_session, key)
        if device.frames == 0 or stream == (device.stream_session, device.key):
            device.stream_session, device.key = stream
            return True
        silent_s = now - device.last_frame
        if silent_s > self.config.id_takeover_after_s:
            self._log(
                f"device {frame.device_id!r}: stream session {frame.stream_session:x}{_key_text(key)} takes "
                f"the id over from stream session {device.stream_session:x}{_key_text(device.key)}, silent "
                f"for {silent_s:.1f} s"
            )
            device.stream_session, device.key = stream
            device.takeovers += 1
            device.last_published = -1
            device.refused_streams.discard(stream)
            return True
        device.id_in_use += 1
        if stream not in device.refused_streams:
            device.refused_streams.add(stream)
            self._log(
                f"device {frame.device_id!r}: frames of stream session {frame.stream_session:x}"
                f"{_key_text(key)} refused: the id is in use by stream session {device.stream_session:x}"
                f"{_key_text(device.key)} (give each device its own device_id in monitor.toml)"
            )
        return False

    def _ingest_one(
        self, parts: list[bytes], key: str, outbox: dict[bytes, list[tuple[DeviceState, float, FeatureFrame]]]
    ) -> None:
        """Check and decode one message; a frame admitted is put in ``outbox`` for its worker (sent from there
        with the others of this round, or at once when :data:`_FORWARD_BATCH` are waiting for that worker)."""
        token = time.monotonic()
        if sum(len(p) for p in parts) > self.config.max_message_bytes:
            self.rejected["oversized"] += 1
            return
        if len(parts) == 2 and is_other_protocol_version(parts[1]):
            self.rejected["wrong_version"] += 1
            return
        try:
            frame = messages.decode(parts, psd=self.reads_psd)
        except MessageError:
            self.rejected["malformed"] += 1
            return
        if not isinstance(frame, FeatureFrame) or len(frame.device_id.encode()) > _MAX_DEVICE_ID_BYTES:
            self.rejected["malformed"] += 1
            return
        device = self.devices.get(frame.device_id)
        if device is None:
            device = self.devices[frame.device_id] = DeviceState(latency_ms=deque(maxlen=self.config.latency_window))
        if not self._admit(frame, key, device, token):
            return
        previous = self.losses.devices.get(frame.device_id)
        if previous is not None and frame.frame_index <= previous.last_index:
            device.last_published = -1  # the device restarted: its frame indices begin again
        device.frames += 1
        device.last_frame = token
        worker = self._assign(frame.device_id, device)
        if worker is None:
            device.no_worker += 1
        else:
            items = outbox.setdefault(worker.identity, [])
            items.append((device, token, frame))
            if len(items) >= _FORWARD_BATCH:
                self._forward(worker.identity, items)
                items.clear()
        # Counted after the frame left: what is not needed to route it stays off its path.
        self.losses.observe(frame)
        device.frame_times.append(token)

    def _assign(self, device_id: str, device: DeviceState) -> WorkerState | None:
        worker = self.workers.get(device.worker) if device.worker is not None else None
        if worker is None:
            if not self.workers:
                return None
            worker = min(self.workers.values(), key=lambda w: (len(w.devices), w.forwarded))
            worker.devices.add(device_id)
            device.worker = worker.identity
        return worker

    def _forward(self, identity: bytes, items: list[tuple[DeviceState, float, FeatureFrame]]) -> None:
        """Send ``items`` (device, token, frame) to the worker ``identity`` as one message, each frame with its age
        at the broker; a full queue drops them all (``queue_full``), a worker gone loses them (``no_worker``). The
        worker in the broker is handed them here instead."""
        worker = self.workers.get(identity)
        now = time.monotonic()
        if worker is not None and identity == _IN_BROKER and self._core is not None:
            arrived = time.perf_counter()
            for _, token, frame in items:
                self._core.add(token, (now - token) * 1000.0, token, arrived, frame)
            worker.forwarded += len(items)
            return
        try:
            if worker is None:
                raise zmq.ZMQError(zmq.EHOSTUNREACH)
            self._backend.send_multipart(
                [
                    identity,
                    envelope.FRAME,
                    *(envelope.pack_frame(token, (now - token) * 1000.0, frame) for _, token, frame in items),
                ],
                zmq.NOBLOCK,
            )
        except zmq.Again:
            for device, _, _ in items:
                device.queue_full += 1
            return
        except zmq.ZMQError:  # EHOSTUNREACH: the worker's connection is gone
            self._remove_worker(identity)
            for device, _, _ in items:
                device.no_worker += 1
            return
        worker.forwarded += len(items)

    # ----------------------------------------------------------------------------------------------- workers
    def _from_workers(self) -> None:
        for _ in range(_BURST):
            try:
                identity, kind, *rest = self._backend.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if kind in (envelope.READY, envelope.STATS):
                self._worker_says(identity, envelope.unpack_json(rest[0]), kind == envelope.STATS)
            elif kind == envelope.ESTIMATES and identity in self.workers:
                self.workers[identity].last_seen = time.monotonic()
                self._publish(identity, envelope.unpack_estimates(rest))

    def _worker_says(self, identity: bytes, data: dict, is_stats: bool) -> None:
        worker = self.workers.get(identity)
        if worker is None:  # a new worker, or one that outlived an earlier broker
            version = data.get("model_version")
            if self.model_version is not None and version != self.model_version:
                self.refused_workers += 1
                self._backend.send_multipart([identity, envelope.STOP], zmq.NOBLOCK)
                return
            self.model_version = version
            self.reads_psd = bool(data["reads_psd"])
            worker = self.workers[identity] = WorkerState(
                identity, data["name"], data["pid"], data.get("provider", "unknown"), time.monotonic()
            )
        worker.last_seen = time.monotonic()
        if is_stats:
            worker.report = data

    def _publish(self, identity: bytes, estimates: Iterable[envelope.ServedEstimate]) -> None:
        received = time.monotonic()
        for estimate in estimates:
            device = self.devices.get(estimate.device_id)
            if (
                device is None
                or device.worker != identity
                or estimate.frame_index <= device.last_published
                or estimate.stream_session != device.stream_session
            ):
                if device is not None:
                    device.out_of_order += 1
                continue
            self._opened(self._estimates).send_multipart([estimate.topic, estimate.body])
            now = time.monotonic()
            device.last_published = estimate.frame_index
            device.estimates += 1
            server_ms = (now - estimate.token) * 1000.0
            device.latency_ms.append(server_ms)
            device.estimate_times.append(now)
            self.stages.add(estimate.times, (now - received) * 1000.0, server_ms)

    def _remove_worker(self, identity: bytes) -> None:
        worker = self.workers.pop(identity, None)
        if worker is None:
            return
        for device_id in worker.devices:
            self.devices[device_id].worker = None  # reassigned with its next frame

    def _expire_workers(self) -> None:
        if self._core is not None:
            self.workers[_IN_BROKER].last_seen = time.monotonic()  # alive while this loop runs
        limit = time.monotonic() - self.config.worker_timeout_ms / 1000.0
        for identity in [i for i, w in self.workers.items() if w.last_seen < limit]:
            self._remove_worker(identity)

    # ----------------------------------------------------------------------------------------------- status
    def status(self) -> dict:
        """Devices, workers, rates, queue depths, drops and latency percentiles, as plain data."""
        now, window = time.monotonic(), self.config.rate_window_s
        if self._core is not None:
            self.workers[_IN_BROKER].report = self._core.report()
        reported: dict[str, dict[str, int]] = {reason: {} for reason in DROP_REASONS}
        nonfinite: dict[str, int] = {}
        refused: dict[str, str] = {}
        for w in self.workers.values():
            for reason, by_device in w.report.get("dropped", {}).items():
                counts = reported.setdefault(reason, {})
                for device_id, n in by_device.items():
                    counts[device_id] = counts.get(device_id, 0) + n
            for device_id, n in w.report.get("nonfinite", {}).items():
                nonfinite[device_id] = nonfinite.get(device_id, 0) + n
            refused.update(w.report.get("settings_refused", {}))
        devices = {}
        for device_id, d in sorted(self.devices.items()):
            loss = self.losses.devices.get(device_id)
            worker = self.workers.get(d.worker) if d.worker is not None else None
            devices[device_id] = {
                "worker": worker.name if worker else None,
                "frames": d.frames,
                "stream_session": f"{d.stream_session:x}",
                "takeovers": d.takeovers,
                "frames_per_s": _rate(d.frame_times, now, window),
                "estimates": d.estimates,
                "estimates_per_s": _rate(d.estimate_times, now, window),
                "lost_in_transit": loss.lost_in_transit if loss else 0,
                "skipped_by_device": loss.skipped_by_device if loss else 0,
                "dropped": {
                    **{reason: counts.get(device_id, 0) for reason, counts in reported.items()},
                    "queue_full": d.queue_full,
                    "no_worker": d.no_worker,
                    "out_of_order": d.out_of_order,
                    "id_in_use": d.id_in_use,
                },
                "nonfinite": nonfinite.get(device_id, 0),
                "settings_refused": refused.get(device_id),
                "server_ms": _percentiles(d.latency_ms),
            }
        workers = [
            {
                "name": w.name,
                "pid": w.pid,
                "provider": w.provider,
                "devices": sorted(w.devices),
                "queue_depth": max(0, w.forwarded - w.report.get("frames", 0)) + w.report.get("pending", 0),
                "last_seen_s": now - w.last_seen,
                **{
                    k: w.report.get(k)
                    for k in ("estimates", "batches", "batch_ms_p50", "batch_ms_p99", "batch_size_mean")
                },
            }
            for w in self.workers.values()
        ]
        all_latency = [v for d in self.devices.values() for v in d.latency_ms]
        return {
            "uptime_s": now - self.started,
            "model_version": self.model_version,
            "endpoints": self.endpoints,
            "curve": self.config.curve.enabled,
            "rejected": dict(self.rejected),
            "refused_workers": self.refused_workers,
            "workers": workers,
            "devices": devices,
            "estimates_per_s": sum(v["estimates_per_s"] for v in devices.values()),
            "server_ms": _percentiles(all_latency),
            "stages_ms": self.stages.percentiles(),
        }


def _key_text(key: str) -> str:
    return f" (key {key[:8]}…)" if key else ""


def default_model(config: ServiceConfig, model: Path | None) -> Path:
    """``model`` or the configured one; a missing file is a :class:`ServiceError` saying how to make one."""
    from seesys.io.resources import resolve

    path = Path(model) if model is not None else resolve(config.model)
    if not path.is_file():
        raise ServiceError(
            f"no model at {path}: pass --model FILE.onnx (`seesys estimator export`), or make an "
            f"untrained stand-in of the configured size with `seesys estimator untrained-model "
            f"--out {path}`"
        )
    return path
