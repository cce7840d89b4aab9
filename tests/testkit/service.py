"""Helpers for the estimator-service tests: a tiny untrained model, a config folder whose endpoints are private
ipc:// sockets, synthetic devices, and ``seesys estimator serve`` run as a real subprocess."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zmq

from seesys.core import messages, rts_schema
from seesys.core.errors import SeesysError
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.core.windows import assemble_windows
from seesys.io.core_settings import load_device_settings, load_window_config

# Long enough for a worker to start (spawn, import ONNX Runtime, load the model) on a loaded 2-core machine.
START_TIMEOUT_S = 240
PSD_SHAPE = (96, 128, 3)


_exported: dict[str, Path] = {}


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory) -> Path:
    """An untrained DeepSEE small enough for tests, exported as the service serves it (once per test session: each
    module importing this fixture has its own copy of it, hence the cache)."""
    return _tiny_export(tmp_path_factory, "tiny", ())


def _tiny_export(tmp_path_factory, name: str, thresholds_m: tuple[float, ...]) -> Path:
    from estimator.deepsee.config import FusionConfig, ModelConfig, PsdEncoderConfig, RtsEncoderConfig
    from estimator.deepsee.export import export_untrained

    if name not in _exported:
        config = ModelConfig(
            32,
            PsdEncoderConfig(16, 1, 2, 2.0, 0.0),
            RtsEncoderConfig(16, 2, 3, 0.0),
            FusionConfig(1, 2, 2.0, (32,), 0.0),
        )
        path = tmp_path_factory.mktemp("service_model") / f"{name}.onnx"
        _exported[name] = export_untrained(
            path, load_window_config(), PSD_SHAPE[:2], seed=0, model_config=config, thresholds_m=thresholds_m
        )
    return _exported[name]


@pytest.fixture(scope="session")
def tiny_head_model(tmp_path_factory) -> Path:
    """:func:`tiny_model` with an ordinal head for Equation 2's class boundaries (4, 8, 12 mm)."""
    return _tiny_export(tmp_path_factory, "tiny_head", (0.004, 0.008, 0.012))


class ServiceSetup:
    """A copy of configs/ whose service and network endpoints are ipc:// sockets in a fresh short folder."""

    def __init__(self, **service: object):
        from estimator.service.sandbox import private_configs

        self.folder = Path(tempfile.mkdtemp(prefix="svc"))  # ipc paths must stay short (107 bytes)
        # Windows are served long after their frames on a loaded test machine: not what these tests test.
        settings = {"connect_device_stream": False, "stale_after_ms": 60000.0, **service}
        self.config_dir, self.endpoints = private_configs(self.folder, **settings)
        self.env = {**os.environ, "SEESYS_CONFIG_DIR": str(self.config_dir)}

    def cleanup(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


@pytest.fixture
def setup_factory():
    """``make(**service)``: a :class:`ServiceSetup` with those service.toml values, cleaned up after the test."""
    made = []

    def make(**service) -> ServiceSetup:
        made.append(ServiceSetup(**service))
        return made[-1]

    yield make
    for setup in made:
        setup.cleanup()


def expected_errors(model_path: Path, frames: list[FeatureFrame]) -> dict[int, float]:
    """What the model gives for the stream's windows, computed here, one window at a time."""
    from estimator.service.model import ServedModel

    windows = load_window_config()
    model = ServedModel.load(model_path, windows)
    return {w.frame_index: float(model.estimate([w])[0]) for w in assemble_windows(frames, windows)}


class ServiceProcess:
    """``seesys estimator serve`` in a subprocess; :meth:`wait_ready` returns once its status endpoint answers."""

    def __init__(self, setup: ServiceSetup, model: Path, *args: str):
        from estimator.service.sandbox import start_service

        self.setup = setup
        self.log = setup.folder / f"serve-{time.monotonic_ns()}.log"
        self.process = start_service(setup.config_dir, model, *args, log=self.log)

    def output(self) -> str:
        return self.log.read_text()

    def status(self, timeout_ms: int = 500) -> dict | None:
        from estimator.service.status import query_status

        try:
            return query_status(self.setup.endpoints["status"], timeout_ms)
        except SeesysError:
            return None

    def wait_ready(self) -> dict:
        from estimator.service.sandbox import wait_ready

        return wait_ready(self.process, self.setup.endpoints["status"], START_TIMEOUT_S, self.log)

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.process.poll() is None:
            self.process.send_signal(sig)
        return self.process.wait(60)

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


@contextlib.contextmanager
def running_service(setup: ServiceSetup, model: Path, *args: str) -> Iterator[ServiceProcess]:
    """``seesys estimator serve`` started and ready; killed on the way out if it still runs."""
    service = ServiceProcess(setup, model, *args)
    try:
        service.wait_ready()
        yield service
    finally:
        service.kill()


def device_frames(
    device_id: str,
    count: int,
    seed: int = 0,
    stream_session: int = 0,
    psd_shape: tuple[int, int, int] = PSD_SHAPE,
    settings=None,
) -> list[FeatureFrame]:
    """A synthetic tracked device stream: RTS rows of plausible magnitude, a sparse PSD on every window end; the
    configured device settings (RGB-D at 30 Hz) unless ``settings`` are given."""
    rng = np.random.default_rng(seed)
    windows = load_window_config()
    settings = settings or load_device_settings("rgbd", 30.0)
    frames = []
    for i in range(count):
        psd = None
        if windows.is_psd_frame(i):
            cells = rng.random(psd_shape)
            psd = np.where(cells < 0.05, rng.integers(1, 256, psd_shape), 0).astype(np.uint8)
        rts = np.abs(rng.normal(1.0, 0.5, rts_schema.NUM_CHANNELS)).astype(np.float32)
        frames.append(
            FeatureFrame(
                device_id,
                i,
                10.0 + i / 30.0,
                TrackingState.OK,
                rts,
                psd,
                stream_session=stream_session,
                settings=settings,
            )
        )
    return frames


class Client:
    """A device (PUB connected to the ingest endpoint) that also subscribes to estimates (of ``topics``)."""

    def __init__(self, setup: ServiceSetup, topics: list[bytes], options: dict | None = None):
        from seesys.io.transport import open_socket

        self.ctx = zmq.Context()
        self.pub = open_socket(
            self.ctx, zmq.PUB, setup.endpoints["ingest"], "test device", bind=False, send_hwm=100_000, options=options
        )
        self.sub = open_socket(
            self.ctx,
            zmq.SUB,
            setup.endpoints["estimates"],
            "test estimates",
            bind=False,
            subscribe=topics,
            options=options,
        )

    def send(self, frame: FeatureFrame) -> None:
        self.pub.send_multipart(messages.encode(frame))

    def receive(self, timeout_ms: int) -> messages.Estimate | None:
        if not self.sub.poll(timeout_ms):
            return None
        return messages.decode(self.sub.recv_multipart())

    def close(self) -> None:
        self.pub.close()
        self.sub.close()
        self.ctx.term()


def serve_in_lockstep(client: Client, frames: list[FeatureFrame], timeout_s: float = 120) -> list:
    """Send ``frames``; after each window end, wait for its estimate before going on (no stale windows, no
    sleeps). PUB–SUB connections are made asynchronously, so the first window end is re-sent (the service
    ignores a repeated frame index) until its estimate shows that both connections are up. Only estimates of the
    frames' stream session count."""
    windows = load_window_config()
    estimates = []
    first = True
    for frame in frames:
        client.send(frame)
        if frame.frame_index < windows.history or not windows.is_psd_frame(frame.frame_index):
            continue
        deadline = time.monotonic() + timeout_s
        while True:
            estimate = client.receive(200)
            if (
                estimate is not None
                and estimate.frame_index == frame.frame_index
                and estimate.stream_session == frame.stream_session
            ):
                estimates.append(estimate)
                break
            assert time.monotonic() < deadline, f"no estimate for frame {frame.frame_index}"
            if first and estimate is None:
                for earlier in frames[: frame.frame_index + 1]:
                    client.send(earlier)
        first = False
    return estimates
