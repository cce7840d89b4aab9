"""The device's per-frame loop: frame source → pacing → ORB-SLAM3 → session files → observers.

:func:`run_device_session` runs a whole session in the current process. It is normally called in a child
process by :mod:`slam_monitor.supervisor`, because ORB-SLAM3 may exit or crash the process it runs in.

Observers see every frame after it has been logged. They are built inside the worker from picklable
:class:`ObserverSpec` records (``"package.module:factory"`` plus keyword settings), so that the supervisor can
pass them to the child; ``factory(context, **settings)`` returns a :class:`FrameObserver`. Objects may also be
passed directly to :func:`run_device_session` when it runs in-process.
"""

from __future__ import annotations

import dataclasses
import importlib
import itertools
import secrets
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from seesys.core import session_layout
from seesys.core.camera import Intrinsics
from seesys.core.errors import SeesysError
from seesys.io.config import as_dict
from slam_monitor import session
from slam_monitor.frame import Frame
from slam_monitor.orbslam_settings import (
    SlamConfig,
    SlamMode,
    build_settings,
    load_slam_config,
    vocabulary_path,
    write_settings,
)
from slam_monitor.pacing import FramePacer, ThreadDemand
from slam_monitor.sources import (
    CameraConfig,
    FrameSource,
    SourceError,
    load_camera_config,
    open_source,
    parse_source_spec,
)
from slam_monitor.tracker import Tracker, TrackOutput


@runtime_checkable
class FrameObserver(Protocol):
    """Sees every frame and what SLAM made of it, in order, in the worker process."""

    def on_frame(self, frame: Frame, result: TrackOutput) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class ObserverSpec:
    """How to build an observer in the worker: ``factory`` is ``"package.module:function"``."""

    factory: str
    settings: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SessionOptions:
    """One device session. Picklable: it crosses to the worker process.

    ``source`` is ``KIND:PATH``; ``max_frames`` stops early; ``settings_file`` replaces the generated ORB-SLAM3
    settings; ``vocabulary`` replaces the configured vocabulary; ``pace`` and ``wait_for_mapping`` override
    ``[pacing]`` of slam.toml; ``config_dir`` replaces ``configs/``; ``observers`` are built in the worker (the RTS
    monitor is one).
    """

    source: str
    mode: SlamMode
    out_dir: Path
    max_frames: int | None = None
    settings_file: Path | None = None
    vocabulary: Path | None = None
    pace: bool | None = None
    wait_for_mapping: bool | None = None
    config_dir: Path | None = None
    observers: tuple[ObserverSpec, ...] = ()


@dataclass(frozen=True)
class SessionContext:
    """What an observer factory gets: the options and what the worker resolved for this session.

    ``stream_session`` is drawn at random for every session: the feature stream carries it in every frame and the
    estimator service binds the device id to it (:mod:`seesys.core.messages`)."""

    options: SessionOptions
    out_dir: Path
    mode: SlamMode
    intrinsics: Intrinsics
    fps: float
    slam_config: SlamConfig
    camera_config: CameraConfig
    stream_session: int = 0


@dataclass(frozen=True)
class SessionStarted:
    description: str
    frame_count: int | None


@dataclass(frozen=True)
class FrameTracked:
    frame_index: int
    tracked: bool


@dataclass(frozen=True)
class SessionResult:
    out_dir: Path
    frames: int
    frames_tracked: int
    has_ground_truth: bool


ProgressEvent = SessionStarted | FrameTracked
ProgressCallback = Callable[[ProgressEvent], None]


def new_stream_session() -> int:
    """A random, non-zero 64-bit stream session."""
    return secrets.randbits(64) or 1


def build_observer(spec: ObserverSpec, context: SessionContext) -> FrameObserver:
    """Import ``spec.factory`` and call it with the context and the spec's settings."""
    module_name, _, function_name = spec.factory.partition(":")
    try:
        factory = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError) as e:
        raise SeesysError(f"observer factory {spec.factory!r} cannot be loaded: {e}") from None
    return factory(context, **spec.settings)


def checked_frames(source: FrameSource, mode: SlamMode, depth_correction: float = 1.0) -> Iterator[Frame]:
    """The source's frames, checked against its intrinsics so that ORB-SLAM3 never sees a mismatched image, their
    depth multiplied by ``depth_correction`` (``[scale]`` of camera.toml: a camera's measured depth scale error)."""
    size = (source.intrinsics.height, source.intrinsics.width)
    for frame in source.frames():
        if frame.gray.shape != size:
            raise SourceError(
                f"frame {frame.index} is {frame.gray.shape[1]}x{frame.gray.shape[0]}, but the source's intrinsics "
                f"are for {size[1]}x{size[0]}"
            )
        if mode is SlamMode.RGBD and frame.depth is None:
            raise SourceError(f"frame {frame.index} has no depth (needed for RGB-D)")
        if frame.depth is not None and depth_correction != 1.0:
            frame = dataclasses.replace(frame, depth=corrected_depth(frame.depth, depth_correction))
        yield frame


def corrected_depth(depth_m: np.ndarray, depth_correction: float) -> np.ndarray:
    """Metric depth multiplied by the camera's ``depth_correction`` (``[scale]`` of camera.toml)."""
    return depth_m if depth_correction == 1.0 else depth_m * np.float32(depth_correction)


def _read_user_settings(options: SessionOptions) -> bytes | None:
    """The ``--settings`` file's content, read before the session folder (which may hold it) is reset."""
    if options.settings_file is None:
        return None
    try:
        return options.settings_file.read_bytes()
    except OSError:
        raise SeesysError(f"ORB-SLAM3 settings file not found or unreadable: {options.settings_file}") from None


def _settings_file(
    options: SessionOptions, user_settings: bytes | None, source: FrameSource, config: SlamConfig, out_dir: Path
) -> Path:
    """The settings ORB-SLAM3 will read, saved in the session folder either way."""
    target = out_dir / session_layout.SETTINGS
    if user_settings is not None:
        target.write_bytes(user_settings)
        return target
    return write_settings(target, build_settings(source.intrinsics, source.fps, options.mode, config))


def run_device_session(
    options: SessionOptions,
    observers: Iterable[FrameObserver] = (),
    progress: ProgressCallback | None = None,
) -> SessionResult:
    """Run one session to the end of the source (or ``max_frames``) and return its counts.

    Raises :class:`SeesysError` on bad input; the session files then hold every frame before the problem and
    ``session.json`` says ``failed`` with the message.
    """
    slam_config = load_slam_config(options.config_dir)
    camera_config = load_camera_config(options.config_dir)
    spec = parse_source_spec(options.source)
    vocabulary = options.vocabulary or vocabulary_path(slam_config)
    user_settings = _read_user_settings(options)
    writer = session.SessionWriter(
        session.prepare_session_folder(options.out_dir),
        {
            "source": str(spec),
            "mode": options.mode.value,
            "max_frames": options.max_frames,
            "vocabulary": str(vocabulary),
            "settings_file": str(options.settings_file or session_layout.SETTINGS),
            "config": {"slam": as_dict(slam_config), "camera": as_dict(camera_config)},
        },
    )
    active: list[FrameObserver] = []
    try:
        with open_source(spec, camera_config, with_depth=options.mode is SlamMode.RGBD) as source:
            writer.describe_source(source.description, as_dict(source.intrinsics), source.fps)
            ground_truth = source.ground_truth()
            if ground_truth is not None:
                writer.write_ground_truth(ground_truth)
            if progress:
                progress(SessionStarted(source.description, _expected_frames(source, options.max_frames)))
            settings = _settings_file(options, user_settings, source, slam_config, writer.folder)
            tracker = Tracker(vocabulary, settings, options.mode, source.intrinsics)
            try:
                context = SessionContext(
                    options,
                    writer.folder,
                    options.mode,
                    source.intrinsics,
                    source.fps,
                    slam_config,
                    camera_config,
                    new_stream_session(),
                )
                active = list(observers) + [build_observer(s, context) for s in options.observers]
                pace = options.pace if options.pace is not None else slam_config.pacing.paces(options.mode)
                pacing = slam_config.pacing
                if options.wait_for_mapping is not None:
                    pacing = dataclasses.replace(pacing, wait_for_mapping=options.wait_for_mapping)
                pacer = FramePacer(
                    pacing, pace and not source.paced_by_clock, ThreadDemand(tracker.background_thread_ids)
                )
                frames = checked_frames(source, options.mode, camera_config.scale.depth_correction)
                for frame in itertools.islice(frames, options.max_frames):
                    pacer.wait(frame.timestamp)
                    output = tracker.track(frame)
                    with holding_interrupt():
                        writer.write_frame(output)
                        for observer in active:
                            observer.on_frame(frame, output)
                    if progress:
                        progress(FrameTracked(output.frame_index, output.tracked))
            finally:
                tracker.shutdown()
        _close_all(active)
    except BaseException as e:  # record how the session ended, whatever ended it, then let it propagate
        interrupted = isinstance(e, KeyboardInterrupt)
        try:
            _close_all(active)
        finally:
            if interrupted:
                writer.finish("interrupted")
            else:
                writer.finish("failed", error=str(e) if isinstance(e, SeesysError) else f"{type(e).__name__}: {e}")
        raise
    writer.finish("completed", mapping_wait_s=round(pacer.mapping_wait_s, 3))
    return SessionResult(writer.folder, writer.frames_written, writer.frames_tracked, ground_truth is not None)


@contextmanager
def holding_interrupt() -> Iterator[None]:
    """Hold a SIGINT that arrives inside the block until its end: a frame is logged and handed to every observer, or
    neither (an interrupt between the two left ``frames.csv`` a frame ahead of the monitor's logs). Outside the main
    thread, where no handler can be set, a plain block."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    handler = signal.signal(signal.SIGINT, lambda signum, _frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
    if held:
        if callable(handler):
            handler(signal.SIGINT, None)
        elif handler == signal.SIG_DFL:
            raise KeyboardInterrupt


def _expected_frames(source: FrameSource, max_frames: int | None) -> int | None:
    count = source.frame_count
    if count is None:
        return max_frames
    return min(count, max_frames) if max_frames is not None else count


def _close_all(observers: list[FrameObserver]) -> None:
    """Close every observer still open, even when one fails, then re-raise the first failure.

    Closed observers leave the list, so the failure path after a failed close does not close them twice.
    """
    first_failure: BaseException | None = None
    while observers:
        observer = observers.pop(0)
        try:
            observer.close()
        except BaseException as e:
            first_failure = first_failure or e
    if first_failure is not None:
        raise first_failure
