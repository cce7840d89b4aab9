"""The embedded sample, small dataset folders made from it, the ``seesys`` CLI run as a subprocess, and real
RealSense recordings made with ``rs.software_device`` + ``rs.recorder``."""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "data" / "sample"


def copy_tum_subset(source: Path, target: Path, count: int) -> Path:
    """A TUM folder with the first ``count`` frames of ``source`` (list files, images, ground truth)."""
    target.mkdir(parents=True, exist_ok=True)
    for list_name in ("rgb.txt", "depth.txt"):
        lines = [line for line in (source / list_name).read_text().splitlines() if line and not line.startswith("#")]
        kept = lines[:count]
        (target / list_name).write_text("\n".join(kept) + "\n")
        for line in kept:
            name = line.split()[1]
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source / name, target / name)
    shutil.copyfile(source / "groundtruth.txt", target / "groundtruth.txt")
    shutil.copyfile(source / "calibration.yaml", target / "calibration.yaml")
    return target


def run_seesys(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run the real ``seesys`` command line in a subprocess."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "seesys", *args], capture_output=True, text=True, cwd=REPO, env=full_env, timeout=timeout
    )


def sample_frames(count: int, with_depth: bool = True):
    """The first ``count`` frames of the embedded sample."""
    from slam_monitor.sources import load_camera_config, open_source, parse_source_spec

    with open_source(parse_source_spec(f"tum:{SAMPLE}"), load_camera_config(), with_depth) as source:
        return list(itertools.islice(source.frames(), count))


def record_realsense(
    path: Path,
    frames,
    stream: str = "color",
    fps: int = 30,
    depth_units: float = 0.001,
    push_period_s: float = 0.0,
    without_depth: frozenset[int] = frozenset(),
) -> Path:
    """Record ``frames`` (gray + metric depth) as a RealSense D435-style recording (``.db3`` in SDK 2.59).

    Image and depth streams live in separate software sensors (the software device cannot record two video
    streams of one sensor with extrinsics between them), depth is registered to the image with identity
    extrinsics, and pixels are pushed with hardware-clock timestamps ``n / fps``. Real-time playback follows
    the wall clock of the recording, so ``push_period_s`` spaces the pushes (against deadlines) when it matters.
    Frames numbered in ``without_depth`` are recorded with their image only, as when a camera drops a depth frame.
    """
    import cv2
    import pyrealsense2 as rs

    height, width = frames[0].gray.shape
    k = frames[0].intrinsics
    device = rs.software_device()
    depth_sensor = device.add_sensor("Stereo Module")
    image_sensor = device.add_sensor("RGB Camera" if stream == "color" else "Infrared Camera")
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = width, height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = k.fx, k.fy, k.cx, k.cy
    intrinsics.model = rs.distortion.brown_conrady
    intrinsics.coeffs = [0.0] * 5

    def video_stream(kind, index, uid, fmt, bpp):
        s = rs.video_stream()
        s.type, s.index, s.uid, s.width, s.height, s.fps, s.bpp, s.fmt = kind, index, uid, width, height, fps, bpp, fmt
        s.intrinsics = intrinsics
        return s

    depth_profile = depth_sensor.add_video_stream(video_stream(rs.stream.depth, 0, 0, rs.format.z16, 2))
    if stream == "color":
        image_profile = image_sensor.add_video_stream(video_stream(rs.stream.color, 0, 1, rs.format.rgb8, 3))
    else:
        image_profile = image_sensor.add_video_stream(video_stream(rs.stream.infrared, 1, 1, rs.format.y8, 1))
    depth_sensor.add_read_only_option(rs.option.depth_units, depth_units)
    identity = rs.extrinsics()
    identity.rotation = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    identity.translation = [0.0, 0.0, 0.0]
    depth_profile.register_extrinsics_to(image_profile, identity)
    device.create_matcher(rs.matchers.default)
    recorder = rs.recorder(str(path), device)
    depth_sensor.open(depth_profile)
    image_sensor.open(image_profile)
    for sensor in (depth_sensor, image_sensor):
        sensor.start(lambda frame: None)
    start = time.perf_counter()
    for n, frame in enumerate(frames):
        time.sleep(max(0.0, start + n * push_period_s - time.perf_counter()))
        image = cv2.cvtColor(frame.gray, cv2.COLOR_GRAY2RGB) if stream == "color" else frame.gray
        depth = np.round(frame.depth / depth_units).astype(np.uint16)
        streams = [(image_sensor, image_profile, image), (depth_sensor, depth_profile, depth)]
        for sensor, profile, pixels in streams[: 1 if n in without_depth else 2]:
            pixels = np.ascontiguousarray(pixels)
            bpp = pixels.itemsize * (pixels.shape[2] if pixels.ndim == 3 else 1)
            video_frame = rs.software_video_frame()
            video_frame.pixels, video_frame.bpp, video_frame.stride = pixels, bpp, width * bpp
            video_frame.timestamp = n * 1000.0 / fps
            video_frame.domain = rs.timestamp_domain.hardware_clock
            video_frame.frame_number = n
            video_frame.profile = profile.as_video_stream_profile()
            if profile is depth_profile:
                video_frame.depth_units = depth_units
            sensor.on_video_frame(video_frame)
    for sensor in (depth_sensor, image_sensor):
        sensor.stop()
        sensor.close()
    del recorder  # the file is finalised when the recorder is destroyed
    return path


def stretched_sample(folder: Path, factor: int) -> Path:
    """A TUM folder with the sample's images and its timestamps spread ``factor`` times further apart (frames
    taken at 30 Hz, played at 30/``factor`` Hz)."""
    folder.mkdir()
    for name in ("rgb", "depth"):
        (folder / name).symlink_to(SAMPLE / name)
    t0 = None
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "associations.txt"):
        lines = []
        for line in (SAMPLE / name).read_text().splitlines():
            if line.startswith("#") or not line.strip():
                lines.append(line)
                continue
            fields = line.split()
            t0 = float(fields[0]) if t0 is None else t0
            for i, value in enumerate(fields):
                if i % 2 == 0 and (i == 0 or name == "associations.txt"):
                    fields[i] = f"{t0 + (float(value) - t0) * factor:.6f}"
            lines.append(" ".join(fields))
        (folder / name).write_text("\n".join(lines) + "\n")
    # The calibration keeps fps 30: these are the sample's 30 Hz frames played slower, and the device states the
    # rate its frames were taken at, the one the served model was made for (another is refused as settings_mismatch).
    (folder / "calibration.yaml").symlink_to(SAMPLE / "calibration.yaml")
    return folder
