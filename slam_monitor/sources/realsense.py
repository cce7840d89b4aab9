"""Intel RealSense (D435i): a live camera or a recording (``.bag`` / ``.db3``) through the same pipeline code.

Both go through ``rs.pipeline``: a live camera is configured from ``configs/camera.toml`` and a recording from
the file (``rs.config.enable_device_from_file``), so a recording exercises exactly the camera's code path. The
image stream is colour (converted to gray) or the left infrared imager; depth, when asked for, is aligned to it
with ``rs.align`` and scaled to metres with the frame's own depth units. Intrinsics are read from the stream
profile, i.e. from the device's calibration.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from seesys.core.camera import Intrinsics
from slam_monitor.frame import Frame
from slam_monitor.sources.base import DepthLimits, FrameSource, SourceError, check_depth, require_file, to_gray
from slam_monitor.sources.settings import RealSenseSettings, RecordingSettings

MS_PER_S = 1000.0
# Frames are awaited in slices of this many ms, so that the end of a recording is noticed promptly.
WAIT_SLICE_MS = 100


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


class RealSenseSource(FrameSource):
    """Frames from a started ``rs.pipeline``; use :func:`open_realsense_camera` or :func:`open_realsense_recording`."""

    def __init__(
        self,
        pipeline,
        profile,
        image_stream: str,
        with_depth: bool,
        timeout_ms: int,
        depth_limits: DepthLimits,
        description: str,
        playback=None,
    ):
        rs = _rs()
        self._pipeline = pipeline
        self._timeout_ms = timeout_ms
        self._depth_limits = depth_limits
        self._playback = playback
        self.description = description
        self._stream = rs.stream.color if image_stream == "color" else rs.stream.infrared
        image_profile = profile.get_stream(self._stream, 1 if image_stream == "infrared" else -1)
        self.intrinsics = _intrinsics(image_profile)
        self.fps = float(image_profile.fps())
        self.has_depth = with_depth
        self._align = rs.align(self._stream) if with_depth else None

    def _image_frame(self, frameset):
        rs = _rs()
        if self._stream == rs.stream.color:
            return frameset.get_color_frame()
        return frameset.get_infrared_frame(1)

    @property
    def paced_by_clock(self) -> bool:
        return self._playback is None or self._playback.is_real_time()

    def _next_frameset(self):
        """The next frameset, or ``None`` at the end of a recording; a silent camera is an error."""
        rs = _rs()
        waited = 0
        while waited < self._timeout_ms:
            ok, frameset = self._pipeline.try_wait_for_frames(WAIT_SLICE_MS)
            if ok:
                return frameset
            if self._playback is not None and self._playback.current_status() == rs.playback_status.stopped:
                return None
            waited += WAIT_SLICE_MS
        if self._playback is not None:
            return None
        raise SourceError(f"the RealSense camera delivered no frame for {self._timeout_ms} ms (unplugged?)")

    def frames(self) -> Iterator[Frame]:
        if self._playback is not None:
            self._playback.resume()
        last_number = -1
        index = 0
        while (frameset := self._next_frameset()) is not None:
            if self._align is not None:
                frameset = self._align.process(frameset)
            image = self._image_frame(frameset)
            # The pipeline re-sends the latest frame of each stream in every frameset: keep new images only.
            if not image or image.get_frame_number() <= last_number:
                continue
            last_number = image.get_frame_number()
            where = f"RealSense frame {last_number}"
            gray = to_gray(np.asanyarray(image.get_data()), where)
            depth = None
            if self.has_depth:
                depth_frame = frameset.get_depth_frame()
                if not depth_frame:
                    continue
                raw = np.asanyarray(depth_frame.get_data()).astype(np.float32)
                depth = check_depth(raw * np.float32(depth_frame.get_units()), gray, self._depth_limits, where)
            yield Frame(index, image.get_timestamp() / MS_PER_S, gray, self.intrinsics, depth)
            index += 1

    def close(self) -> None:
        with contextlib.suppress(RuntimeError):  # already stopped, e.g. after the end of a recording
            self._pipeline.stop()


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
    index = 1 if settings.stream == "infrared" else -1
    stream = rs.stream.color if settings.stream == "color" else rs.stream.infrared
    config.enable_stream(
        stream, index, settings.width, settings.height, _image_format(rs, settings.stream), settings.fps
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
    return RealSenseSource(
        pipeline,
        profile,
        settings.stream,
        with_depth,
        settings.frame_timeout_ms,
        depth_limits,
        f"RealSense {name} ({profile.get_device().get_info(rs.camera_info.serial_number)})",
    )


def open_realsense_recording(
    path: Path, preferred_stream: str, settings: RecordingSettings, depth_limits: DepthLimits, with_depth: bool
) -> RealSenseSource:
    """Play a RealSense recording through the camera's pipeline code, at recorded pace or as fast as possible."""
    rs = _rs()
    require_file(path, "RealSense recording")
    if path.suffix not in (".bag", ".db3"):
        raise SourceError(f"RealSense recording {path} must be a .bag or .db3 file")
    config = rs.config()
    config.enable_device_from_file(str(path), repeat_playback=False)
    pipeline = rs.pipeline()
    try:
        profile = pipeline.start(config)
    except RuntimeError as e:
        raise SourceError(f"cannot play RealSense recording {path}: {e}") from None
    playback = profile.get_device().as_playback()
    playback.set_real_time(settings.real_time)
    # Held until frames() is iterated: in real time, frames played while SLAM starts up would be lost.
    playback.pause()
    recorded = {p.stream_type() for p in profile.get_streams()}
    fallback = "infrared" if preferred_stream == "color" else "color"
    stream_of = {"color": rs.stream.color, "infrared": rs.stream.infrared}
    image_stream = next((s for s in (preferred_stream, fallback) if stream_of[s] in recorded), None)
    if image_stream is None:
        pipeline.stop()
        raise SourceError(f"RealSense recording {path} has no colour or infrared stream")
    if with_depth and rs.stream.depth not in recorded:
        pipeline.stop()
        raise SourceError(f"RealSense recording {path} has no depth stream (needed for RGB-D)")
    return RealSenseSource(
        pipeline,
        profile,
        image_stream,
        with_depth,
        settings.frame_timeout_ms,
        depth_limits,
        f"RealSense recording {path}",
        playback,
    )
