"""Intel RealSense (D435i): a live camera or a recording (``.bag`` / ``.db3``).

A live camera is read through ``rs.pipeline``, configured from ``configs/camera.toml``. A recording is read from
the playback device's own sensors, frame by frame, because the pipeline loses framesets when it plays a file
(it plays the first frames before playback can be paused, and in real time it lost frames in the middle of
recordings whose reader kept up); image and depth are then paired by timestamp, as the pipeline's matcher does.
Both give the same framesets to the same conversion: the image stream is colour (converted to gray) or the left
infrared imager; depth, when asked for, is aligned to it with ``rs.align`` and scaled to metres with the frame's
own depth units. Intrinsics are read from the stream profile, i.e. from the device's calibration.
"""

from __future__ import annotations

import abc
import collections
import contextlib
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from seesys.core.camera import Intrinsics
from slam_monitor.frame import Frame
from slam_monitor.sources.base import DepthLimits, FrameSource, SourceError, check_depth, require_file, to_gray
from slam_monitor.sources.settings import RealSenseSettings, RecordingSettings

MS_PER_S = 1000.0
# Frames are awaited in slices of this many ms, so that the end of a recording or a signal is noticed promptly.
WAIT_SLICE_MS = 100
# Frames a recording's sensors may hand over before the reader takes them: as-fast-as-possible playback waits
# for the reader beyond this; real-time playback drops the oldest, as a camera would.
RECORDING_QUEUE_FRAMES = 8


def _rs():
    try:
        import pyrealsense2 as rs
    except ImportError as e:  # libusb missing is the usual cause
        raise SourceError(f"pyrealsense2 cannot be loaded ({e}); is libusb-1.0-0 installed?") from None
    return rs


def _intrinsics(profile) -> Intrinsics:
    rs = _rs()
    intr = profile.as_video_stream_profile().get_intrinsics()
    if intr.model not in (
        rs.distortion.none,
        rs.distortion.brown_conrady,
        rs.distortion.modified_brown_conrady,
        rs.distortion.inverse_brown_conrady,
    ):
        raise SourceError(
            f"RealSense stream uses the {intr.model} lens model, which ORB-SLAM3's pinhole camera cannot use"
        )
    coeffs = tuple(float(c) for c in intr.coeffs[:5])
    return Intrinsics(intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy, coeffs)  # type: ignore[arg-type]


def _image_stream(image_stream: str):
    """The SDK's stream and stream index for ``"color"`` or ``"infrared"`` (the left imager, index 1; -1: any)."""
    rs = _rs()
    return (rs.stream.color, -1) if image_stream == "color" else (rs.stream.infrared, 1)


class RealSenseSource(FrameSource):
    """Frames from RealSense framesets; use :func:`open_realsense_camera` or :func:`open_realsense_recording`."""

    def __init__(self, image_profile, with_depth: bool, depth_limits: DepthLimits, description: str):
        rs = _rs()
        self._depth_limits = depth_limits
        self.description = description
        self._stream = image_profile.stream_type()
        self.intrinsics = _intrinsics(image_profile)
        self.fps = float(image_profile.fps())
        self.has_depth = with_depth
        self._align = rs.align(self._stream) if with_depth else None

    @abc.abstractmethod
    def _framesets(self) -> Iterator:
        """Framesets, each with a new image and, in RGB-D mode, its depth; ends with the recording."""

    def _image_frame(self, frameset):
        rs = _rs()
        if self._stream == rs.stream.color:
            return frameset.get_color_frame()
        return frameset.get_infrared_frame(1)

    def frames(self) -> Iterator[Frame]:
        for index, frameset in enumerate(self._framesets()):
            if self._align is not None:
                frameset = self._align.process(frameset)
            image = self._image_frame(frameset)
            where = f"RealSense frame {image.get_frame_number()}"
            gray = to_gray(np.asanyarray(image.get_data()), where)
            depth = None
            if self.has_depth:
                depth_frame = frameset.get_depth_frame()
                raw = np.asanyarray(depth_frame.get_data()).astype(np.float32)
                depth = check_depth(raw * np.float32(depth_frame.get_units()), gray, self._depth_limits, where)
            yield Frame(index, image.get_timestamp() / MS_PER_S, gray, self.intrinsics, depth)


class RealSenseCamera(RealSenseSource):
    """A live camera through a started ``rs.pipeline``."""

    def __init__(self, pipeline, profile, image_stream: str, with_depth: bool, timeout_ms: int, **kwargs):
        super().__init__(profile.get_stream(*_image_stream(image_stream)), with_depth, **kwargs)
        self._pipeline = pipeline
        self._timeout_ms = timeout_ms

    @property
    def paced_by_clock(self) -> bool:
        return True

    def _framesets(self) -> Iterator:
        last_number = -1
        waited = 0
        while True:
            # Waited for in slices, so that a signal handler runs while the camera is silent.
            ok, frameset = self._pipeline.try_wait_for_frames(WAIT_SLICE_MS)
            if not ok:
                waited += WAIT_SLICE_MS
                if waited >= self._timeout_ms:
                    raise SourceError(f"the RealSense camera delivered no frame for {self._timeout_ms} ms (unplugged?)")
                continue
            waited = 0
            image = self._image_frame(frameset)
            # The pipeline re-sends the latest frame of each stream in every frameset: keep new images only, and
            # in RGB-D mode only once their depth has come.
            if not image or image.get_frame_number() <= last_number:
                continue
            if self.has_depth and not frameset.get_depth_frame():
                continue
            last_number = image.get_frame_number()
            yield frameset

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):  # already stopped
            self._pipeline.stop()


class RealSenseRecording(RealSenseSource):
    """A recording read from its playback device's sensors, image and depth paired by timestamp.

    Nothing is played before :meth:`frames` is iterated. As fast as possible, every recorded frame is delivered;
    in real time, a reader slower than the recording loses the oldest frames, as with a camera. In RGB-D mode an
    image with no depth frame within half a frame period is skipped, as the camera's pipeline would.
    """

    def __init__(self, device, image_profile, depth_profile, real_time: bool, timeout_ms: int, **kwargs):
        super().__init__(image_profile, depth_profile is not None, **kwargs)
        self._playback = device.as_playback()
        self._playback.set_real_time(real_time)
        self._real_time = real_time
        self._timeout_ms = timeout_ms
        profiles = [p for p in (image_profile, depth_profile) if p is not None]
        periods_ms = [MS_PER_S / p.fps() for p in profiles]
        self._tolerance_ms = min(periods_ms) / 2
        self._queue: queue.Queue = queue.Queue(maxsize=RECORDING_QUEUE_FRAMES)
        self._closing = threading.Event()
        self._started: list = []
        self._to_combine: list = []
        self._combiner = _rs().processing_block(self._combine)
        self._combined = _rs().frame_queue(1, keep_frames=True)
        self._combiner.start(self._combined)
        self._sensors = []
        ids = {p.unique_id() for p in profiles}
        for sensor in device.query_sensors():
            wanted = [p for p in sensor.get_stream_profiles() if p.unique_id() in ids]
            if wanted:
                sensor.open(wanted)
                self._sensors.append(sensor)

    @property
    def paced_by_clock(self) -> bool:
        return self._real_time

    def _deliver(self, frame) -> None:
        """Sensor callback (a librealsense thread): hand the frame to the reader; must not raise."""
        frame.keep()
        if self._real_time:
            while True:
                try:
                    self._queue.put_nowait(frame)
                    return
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        self._queue.get_nowait()
        # As fast as possible: playback waits here for the reader, so nothing is lost.
        while not self._closing.is_set():
            with contextlib.suppress(queue.Full):
                self._queue.put(frame, timeout=WAIT_SLICE_MS / MS_PER_S)
                return

    def _combine(self, frame, source) -> None:
        source.frame_ready(source.allocate_composite_frame(self._to_combine))

    def _delivered(self) -> Iterator:
        """The sensors' frames in delivery order, until the recording ends or nothing comes for the timeout."""
        rs = _rs()
        waited = 0
        while waited < self._timeout_ms:
            try:
                yield self._queue.get(timeout=WAIT_SLICE_MS / MS_PER_S)
                waited = 0
            except queue.Empty:
                if self._playback.current_status() == rs.playback_status.stopped:
                    break
                waited += WAIT_SLICE_MS
        # Frames handed over while the end was noticed: the sensors' callbacks have all returned once stopped.
        self._stop_sensors()
        while True:
            try:
                yield self._queue.get_nowait()
            except queue.Empty:
                return

    def _pairs(self) -> Iterator[list]:
        depth_kind = _rs().stream.depth
        images: collections.deque = collections.deque()
        depths: collections.deque = collections.deque()
        for frame in self._delivered():
            if frame.get_profile().stream_type() == depth_kind:
                depths.append(frame)
            elif not self.has_depth:
                yield [frame]
            else:
                images.append(frame)
            # Each stream arrives in time order, so the oldest of each decides.
            while images and depths:
                gap_ms = depths[0].get_timestamp() - images[0].get_timestamp()
                if gap_ms < -self._tolerance_ms:
                    depths.popleft()
                elif gap_ms > self._tolerance_ms:
                    images.popleft()
                else:
                    yield [images.popleft(), depths.popleft()]

    def _framesets(self) -> Iterator:
        # Playback starts with the first sensor: held until all are started, so none misses the first frames.
        self._playback.pause()
        for sensor in self._sensors:
            sensor.start(self._deliver)
            self._started.append(sensor)
        self._playback.resume()
        for frames in self._pairs():
            self._to_combine = frames
            self._combiner.invoke(frames[0])
            yield self._combined.wait_for_frame().as_frameset()

    def _stop_sensors(self) -> None:
        self._closing.set()
        while self._started:
            with contextlib.suppress(RuntimeError):
                self._started.pop().stop()

    def close(self) -> None:
        self._stop_sensors()
        for sensor in self._sensors:
            with contextlib.suppress(RuntimeError):
                sensor.close()
        self._sensors = []


def _image_format(rs, stream: str):
    return rs.format.bgr8 if stream == "color" else rs.format.y8


def open_realsense_camera(
    serial: str, settings: RealSenseSettings, depth_limits: DepthLimits, with_depth: bool
) -> RealSenseSource:
    """Start a live camera (the first one, or the one with ``serial``) with the configured streams."""
    rs = _rs()
    devices = rs.context().query_devices()
    serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
    if not serials:
        raise SourceError("no RealSense camera connected")
    if serial and serial not in serials:
        raise SourceError(f"no RealSense camera with serial {serial} connected (connected: {', '.join(serials)})")
    if with_depth and not settings.depth:
        raise SourceError("RGB-D mode needs depth, but configs/camera.toml has realsense.depth = false")
    config = rs.config()
    if serial:
        config.enable_device(serial)
    config.enable_stream(
        *_image_stream(settings.stream),
        settings.width,
        settings.height,
        _image_format(rs, settings.stream),
        settings.fps,
    )
    if with_depth:
        config.enable_stream(rs.stream.depth, settings.width, settings.height, rs.format.z16, settings.fps)
    pipeline = rs.pipeline()
    try:
        profile = pipeline.start(config)
    except RuntimeError as e:
        raise SourceError(
            f"cannot start the RealSense camera with {settings.stream} {settings.width}x{settings.height}"
            f"@{settings.fps}: {e}"
        ) from None
    name = profile.get_device().get_info(rs.camera_info.name)
    return RealSenseCamera(
        pipeline,
        profile,
        settings.stream,
        with_depth,
        settings.frame_timeout_ms,
        depth_limits=depth_limits,
        description=f"RealSense {name} ({profile.get_device().get_info(rs.camera_info.serial_number)})",
    )


def _recorded_profile(device, stream, index: int = -1):
    """The recorded video profile of ``stream`` (with that index unless -1), or ``None``."""
    for sensor in device.query_sensors():
        for profile in sensor.get_stream_profiles():
            if profile.stream_type() == stream and index in (-1, profile.stream_index()):
                return profile
    return None


def open_realsense_recording(
    path: Path, preferred_stream: str, settings: RecordingSettings, depth_limits: DepthLimits, with_depth: bool
) -> RealSenseSource:
    """Play a RealSense recording at recorded pace or as fast as the reader takes the frames."""
    rs = _rs()
    require_file(path, "RealSense recording")
    if path.suffix not in (".bag", ".db3"):
        raise SourceError(f"RealSense recording {path} must be a .bag or .db3 file")
    try:
        device = rs.context().load_device(str(path))
    except RuntimeError as e:
        raise SourceError(f"cannot play RealSense recording {path}: {e}") from None
    fallback = "infrared" if preferred_stream == "color" else "color"
    for image_stream in (preferred_stream, fallback):
        image_profile = _recorded_profile(device, *_image_stream(image_stream))
        if image_profile is not None:
            break
    else:
        raise SourceError(f"RealSense recording {path} has no colour or infrared stream")
    depth_profile = _recorded_profile(device, rs.stream.depth) if with_depth else None
    if with_depth and depth_profile is None:
        raise SourceError(f"RealSense recording {path} has no depth stream (needed for RGB-D)")
    return RealSenseRecording(
        device,
        image_profile,
        depth_profile,
        settings.real_time,
        settings.frame_timeout_ms,
        depth_limits=depth_limits,
        description=f"RealSense recording {path}",
    )
