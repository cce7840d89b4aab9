"""The frame-source interface and the checks every source applies to what it reads.

A source opens a camera, a recording or a dataset and yields :class:`slam_monitor.frame.Frame` records in
delivery order. Sources are libraries: the device worker, the dataset builder and the user study all open them
through :func:`slam_monitor.sources.open_source`.
"""

from __future__ import annotations

import abc
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seesys.core.camera import Intrinsics
from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from slam_monitor.frame import Frame


class SourceError(SeesysError):
    """A frame source cannot be opened or read: missing folder, unreadable image, bad depth, no camera."""


class FrameSource(abc.ABC):
    """One stream of frames with fixed intrinsics.

    ``fps`` is the nominal frame rate (ORB-SLAM3's ``Camera.fps``); ``has_depth`` says whether frames carry
    metric depth; ``frame_count`` is the number of frames when known in advance (files), else ``None``;
    ``paced_by_clock`` says whether frames come at camera rate by themselves.
    Use as a context manager, or call :meth:`close`.
    """

    intrinsics: Intrinsics
    fps: float
    has_depth: bool
    description: str

    @property
    def frame_count(self) -> int | None:
        return None

    @property
    def paced_by_clock(self) -> bool:
        """True when frames arrive at camera rate by themselves (a live camera, real-time playback)."""
        return False

    def ground_truth(self) -> Poses | None:
        """Ground-truth camera poses when the source has them."""
        return None

    @abc.abstractmethod
    def frames(self) -> Iterator[Frame]:
        """Yield the frames in order, raising :class:`SourceError` on one that cannot be read."""

    def close(self) -> None:  # noqa: B027 (a source with nothing to release keeps this no-op)
        """Release the camera or files."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class DepthLimits:
    """Plausible range of a frame's median valid depth, to catch a wrong depth scale early."""

    min_median_m: float
    max_median_m: float


def require_folder(path: Path, kind: str) -> Path:
    """``path`` as an existing folder, or a :class:`SourceError` naming it."""
    if not path.exists():
        raise SourceError(f"{kind} source folder not found: {path}")
    if not path.is_dir():
        raise SourceError(f"{kind} source is not a folder: {path}")
    return path


def require_file(path: Path, what: str) -> Path:
    if not path.is_file():
        raise SourceError(f"{what} not found: {path}")
    return path


def read_gray(path: Path) -> np.ndarray:
    """Read an image file as (H, W) uint8 gray, converting colour images."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SourceError(f"cannot read image {path} (missing, truncated or not an image)")
    return to_gray(image, str(path))


def to_gray(image: np.ndarray, where: str) -> np.ndarray:
    """(H, W) uint8 gray from a gray, BGR or BGRA 8-bit image."""
    import cv2

    if image.dtype != np.uint8:
        raise SourceError(f"image {where} is {image.dtype}, expected 8-bit")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    raise SourceError(f"image {where} has shape {image.shape}, expected gray or colour")


def read_depth_png(path: Path, units_per_metre: float) -> np.ndarray:
    """Read a 16-bit depth PNG as float32 metres."""
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise SourceError(f"cannot read depth image {path} (missing, truncated or not an image)")
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise SourceError(f"depth image {path} is {raw.dtype} {raw.shape}, expected a 16-bit single-channel PNG")
    return depth_metres(raw, units_per_metre)


def depth_metres(raw: np.ndarray, units_per_metre: float) -> np.ndarray:
    """A 16-bit depth image (``units_per_metre`` units per metre, 0 = no depth) as float32 metres."""
    return raw.astype(np.float32) / np.float32(units_per_metre)


def check_depth(depth_m: np.ndarray, gray: np.ndarray, limits: DepthLimits, where: str) -> np.ndarray:
    """Check that metric depth matches the image's shape and has a plausible scale; returns it as float32.

    The scale check looks at the median of the valid (non-zero) depths on a sparse grid: a depth in millimetres
    read as metres, or metres read as 1/5000 m, lands orders of magnitude outside ``limits``.
    """
    if depth_m.shape != gray.shape:
        raise SourceError(f"depth {where} has shape {depth_m.shape}, but the image is {gray.shape}")
    sparse = depth_m[::8, ::8]
    valid = sparse[np.isfinite(sparse) & (sparse > 0)]
    if valid.size:
        median = float(np.median(valid))
        if not limits.min_median_m <= median <= limits.max_median_m:
            raise SourceError(
                f"depth {where} has median {median:.4g} m, outside {limits.min_median_m}-{limits.max_median_m} m: "
                "wrong depth scale?"
            )
    return np.ascontiguousarray(depth_m, dtype=np.float32)


def _node_value(node):
    if node.isMap():
        return {key: _node_value(node.getNode(key)) for key in node.keys()}  # noqa: SIM118 (a cv2.FileNode is no iterable)
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isString():
        return node.string()
    if node.isInt() or node.isReal():
        return node.real()
    return None


def read_yaml(path: Path) -> dict:
    """A YAML calibration file (OpenCV's ``%YAML:1.0`` dialect or plain YAML) as nested dicts, lists, floats."""
    import cv2

    require_file(path, "calibration file")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:  # the binding wraps the parser's cv2.error in a SystemError
        raise SourceError(f"{path}: not valid YAML ({str(e.__cause__ or e).strip().splitlines()[-1]})") from None
    try:
        return _node_value(storage.root())
    finally:
        storage.release()


def read_timestamped_list(path: Path) -> list[tuple[float, str]]:
    """Read a TUM-style list file: ``timestamp filename`` per line, ``#`` comments."""
    require_file(path, "list file")
    entries = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            entries.append((float(parts[0]), parts[1]))
        except (ValueError, IndexError):
            raise SourceError(f"{path}:{number}: expected 'timestamp filename', got {line!r}") from None
    if not entries:
        raise SourceError(f"{path} lists no frames")
    return entries


def nominal_fps(timestamps: np.ndarray, fallback: float) -> float:
    """Frame rate from the median timestamp step, or ``fallback`` for fewer than two frames."""
    if len(timestamps) < 2:
        return fallback
    step = float(np.median(np.diff(timestamps)))
    return 1.0 / step if step > 0 else fallback
