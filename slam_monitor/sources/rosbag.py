"""ROS bags (ROS 1 ``.bag``, ROS 2 folders with ``.db3`` or ``.mcap`` storage), read with ``rosbags``: no ROS install.

Topics are named in ``configs/camera.toml [rosbag]`` or found by message type (docs/device.md): colour
(``sensor_msgs/Image`` or ``CompressedImage``), depth (``Image``, 16UC1/mono16 millimetres or 32FC1 metres, REP 118),
camera info (``sensor_msgs/CameraInfo``) and ground truth (``geometry_msgs/PoseStamped``, ``TransformStamped``,
``nav_msgs/Odometry`` or the transforms of a ``tf2_msgs/TFMessage`` topic). Frames are timed by their header stamps;
depth is paired with the colour image nearest in time, as for a TUM folder.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seesys.core.camera import Intrinsics
from seesys.core.trajectory import Poses
from seesys.core.units import MM_PER_M
from slam_monitor.frame import Frame
from slam_monitor.sources.base import (
    DepthLimits,
    FrameSource,
    SourceError,
    check_depth,
    depth_metres,
    nominal_fps,
    to_gray,
)
from slam_monitor.sources.settings import FileSourceDefaults, RosbagSettings, folder_calibration

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry")
TF = "tf2_msgs/msg/TFMessage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
# A topic whose name contains this is taken for depth when topics are found by type (REP 118 names).
DEPTH_WORD = "depth"
NS_PER_S = 1e9
ROS2_STORAGE_SUFFIXES = (".db3", ".mcap")


def _stamp(message) -> float:
    stamp = message.header.stamp
    return stamp.sec + stamp.nanosec / NS_PER_S


def _field(message, name: str):
    """A field that ROS 1 spells in capitals (``K``, ``D``) and ROS 2 in lower case (``k``, ``d``)."""
    return getattr(message, name) if hasattr(message, name) else getattr(message, name.upper())


def bag_path(path: Path) -> Path:
    """The path ``rosbags`` opens: a ``.bag`` file, or the ROS 2 bag folder (also for a ``.db3``/``.mcap`` in it)."""
    if not path.exists():
        raise SourceError(f"ROS bag not found: {path}")
    if path.is_file() and path.suffix in ROS2_STORAGE_SUFFIXES:
        path = path.parent
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise SourceError(f"{path} is not a ROS 2 bag folder (no metadata.yaml)")
    if path.is_file() and path.suffix != ".bag":
        raise SourceError(f"{path} is not a ROS bag (.bag file, or a ROS 2 folder / .db3 / .mcap)")
    return path


def _open_reader(path: Path):
    from rosbags.highlevel import AnyReader, AnyReaderError

    reader = AnyReader([path])
    try:
        reader.open()
    except (AnyReaderError, OSError) as e:
        raise SourceError(f"cannot read ROS bag {path}: {e}") from None
    return reader


def _topics_listing(reader) -> str:
    return ", ".join(f"{topic} ({info.msgtype})" for topic, info in sorted(reader.topics.items())) or "no topics"


def _pick(reader, named: str, types: tuple[str, ...], what: str, key: str, keep=lambda topic: True) -> str | None:
    """The topic ``named`` (checked), or the one topic of ``types`` that ``keep`` accepts, or ``None`` if none.

    Several candidates are an error naming them and the configuration key that chooses one.
    """
    topics = reader.topics
    if named:
        if named not in topics:
            raise SourceError(f"{what} topic {named} is not in the bag (it has: {_topics_listing(reader)})")
        if topics[named].msgtype not in types:
            raise SourceError(f"{what} topic {named} is {topics[named].msgtype}, expected {' or '.join(types)}")
        return named
    found = sorted(topic for topic, info in topics.items() if info.msgtype in types and keep(topic))
    if len(found) > 1:
        raise SourceError(
            f"the bag has several {what} topics ({', '.join(found)}): name one in configs/camera.toml [rosbag] {key}"
        )
    return found[0] if found else None


@dataclass(frozen=True)
class BagTopics:
    """The topics a bag source reads; ``None`` where the bag has none."""

    image: str
    depth: str | None
    camera_info: str | None
    ground_truth: str | None


def find_topics(reader, settings: RosbagSettings, with_depth: bool) -> BagTopics:
    """Resolve every topic from the configuration or by message type; no image topic is an error naming the topics."""
    image = _pick(
        reader, settings.image_topic, IMAGE_TYPES, "image", "image_topic", lambda topic: DEPTH_WORD not in topic.lower()
    )
    if image is None:
        raise SourceError(
            f"the bag has no image topic (sensor_msgs Image or CompressedImage); it has: {_topics_listing(reader)}"
        )
    depth = None
    if with_depth:
        depth = _pick(
            reader, settings.depth_topic, (IMAGE,), "depth", "depth_topic", lambda topic: DEPTH_WORD in topic.lower()
        )
        if depth is None:
            raise SourceError(
                f"RGB-D mode needs a depth topic (sensor_msgs/Image with 'depth' in its name, or "
                f"[rosbag] depth_topic); the bag has: {_topics_listing(reader)}"
            )
    beside = image.rsplit("/", 1)[0] + "/camera_info"
    info_named = settings.camera_info_topic or (beside if reader.topics.get(beside) else "")
    info = _pick(reader, info_named, (CAMERA_INFO,), "camera info", "camera_info_topic")
    truth = _pick(
        reader,
        settings.ground_truth_topic,
        POSE_TYPES + (TF,),
        "ground truth",
        "ground_truth_topic",
        lambda topic: reader.topics[topic].msgtype in POSE_TYPES,
    )
    if truth is None and not settings.ground_truth_topic:
        truth = _pick(reader, "", (TF,), "ground truth", "ground_truth_topic", lambda topic: topic == "/tf")
    return BagTopics(image, depth, info, truth)


def _messages(reader, topics: list[str]) -> Iterator[tuple[str, Any]]:
    # Any: rosbags deserialises each message into a class of its type, made at run time.
    connections = [c for c in reader.connections if c.topic in topics]
    for connection, _, raw in reader.messages(connections=connections):
        yield connection.topic, reader.deserialize(raw, connection.msgtype)


def _intrinsics(message) -> Intrinsics:
    k = np.asarray(_field(message, "k"), dtype=float)
    d = [float(v) for v in _field(message, "d")][:5]
    if message.distortion_model not in ("", "plumb_bob", "rational_polynomial"):
        raise SourceError(
            f"camera info uses the {message.distortion_model!r} model, which ORB-SLAM3's pinhole camera cannot use"
        )
    k1, k2, p1, p2, k3 = (d + [0.0] * 5)[:5]
    return Intrinsics(
        int(message.width),
        int(message.height),
        float(k[0]),
        float(k[4]),
        float(k[2]),
        float(k[5]),
        (k1, k2, p1, p2, k3),
    )


def decode_image(message, where: str) -> np.ndarray:
    """(H, W) uint8 gray from an 8-bit ``Image`` (mono8, bgr8, rgb8, bgra8, rgba8) or a ``CompressedImage``."""
    import cv2

    if hasattr(message, "format"):
        image = cv2.imdecode(np.frombuffer(message.data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SourceError(f"{where}: cannot decode the compressed image ({message.format})")
        return to_gray(image, where)
    channels = {"mono8": 1, "8UC1": 1, "bgr8": 3, "rgb8": 3, "8UC3": 3, "bgra8": 4, "rgba8": 4}.get(message.encoding)
    if channels is None:
        raise SourceError(f"{where}: image encoding {message.encoding!r} is not an 8-bit gray or colour image")
    pixels = np.asarray(message.data, np.uint8).reshape(message.height, message.step)
    image = pixels[:, : message.width * channels].reshape(message.height, message.width, channels)
    if message.encoding.startswith("rgb"):
        image = image[..., [2, 1, 0] + ([3] if channels == 4 else [])]
    return to_gray(np.ascontiguousarray(image.squeeze(axis=2) if channels == 1 else image), where)


def decode_depth(message, where: str) -> np.ndarray:
    """(H, W) float32 metres from a 16UC1/mono16 (millimetres) or 32FC1 (metres) ``Image``."""
    dtypes = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}
    if message.encoding not in dtypes:
        raise SourceError(f"{where}: depth encoding {message.encoding!r} is not 16UC1, mono16 or 32FC1")
    dtype = np.dtype(dtypes[message.encoding]).newbyteorder(">" if message.is_bigendian else "<")
    raw = np.frombuffer(np.asarray(message.data, np.uint8).tobytes(), dtype)
    rows = raw.reshape(message.height, message.step // dtype.itemsize)[:, : message.width]
    depth = depth_metres(rows, MM_PER_M) if dtype.kind == "u" else rows.astype(np.float32)
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)


def _ground_truth_pose(topic_type: str, message, child_frame: str) -> list[tuple[float, list[float], list[float]]]:
    """(t, position, quaternion xyzw) of each camera pose ``message`` carries."""
    if topic_type == TF:
        transforms = [t for t in message.transforms if not child_frame or t.child_frame_id == child_frame]
        return [
            (
                _stamp(t),
                [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                [t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w],
            )
            for t in transforms
        ]
    if topic_type == "geometry_msgs/msg/TransformStamped":
        p, q = message.transform.translation, message.transform.rotation
    else:
        pose = message.pose.pose if topic_type == "nav_msgs/msg/Odometry" else message.pose
        p, q = pose.position, pose.orientation
    return [(_stamp(message), [p.x, p.y, p.z], [q.x, q.y, q.z, q.w])]


class RosbagSource(FrameSource):
    """Frames of a ROS 1 or ROS 2 bag; see the module docstring for how topics are found."""

    def __init__(
        self,
        path: Path,
        settings: RosbagSettings,
        defaults: FileSourceDefaults,
        depth_limits: DepthLimits,
        with_depth: bool,
    ):
        self.path = bag_path(path)
        self._settings = settings
        self._depth_limits = depth_limits
        self.has_depth = with_depth
        self._reader = _open_reader(self.path)
        try:
            self.topics = find_topics(self._reader, settings, with_depth)
            self._image_times = self._stamps(self.topics.image)
            if not len(self._image_times):
                raise SourceError(f"image topic {self.topics.image} of {self.path} has no message")
            self._pairs = self._pair_with_depth(defaults.association_max_dt_s) if with_depth else None
            calibration = folder_calibration(self.path.parent, defaults)
            self.intrinsics = self._camera_info() or calibration.intrinsics
            self.fps = calibration.fps or nominal_fps(self._image_times, defaults.fps)
        except BaseException:
            self._reader.close()
            raise
        self.description = f"ROS bag {self.path} ({self.topics.image}" + (
            f" + {self.topics.depth})" if with_depth else ")"
        )

    def _stamps(self, topic: str) -> np.ndarray:
        return np.array([_stamp(message) for _, message in _messages(self._reader, [topic])])

    @property
    def _depth_topic(self) -> str:
        """The depth topic (whenever depth is read, :func:`find_topics` found one)."""
        if self.topics.depth is None:
            raise SourceError(f"{self.path} has no depth topic")
        return self.topics.depth

    def _pair_with_depth(self, max_dt: float) -> dict[int, int]:
        """Image number -> depth number of the depth nearest in time, for images with one within ``max_dt``."""
        depth_times = self._stamps(self._depth_topic)
        if not len(depth_times):
            raise SourceError(f"depth topic {self.topics.depth} of {self.path} has no message")
        nearest = np.abs(depth_times[None, :] - self._image_times[:, None]).argmin(axis=1)
        pairs = {i: int(j) for i, j in enumerate(nearest) if abs(depth_times[j] - self._image_times[i]) <= max_dt}
        if not pairs:
            raise SourceError(f"{self.path}: no depth message within {max_dt} s of any image")
        return pairs

    def _camera_info(self) -> Intrinsics | None:
        if self.topics.camera_info is None:
            return None
        for _, message in _messages(self._reader, [self.topics.camera_info]):
            return _intrinsics(message)
        return None

    @property
    def frame_count(self) -> int:
        return len(self._pairs) if self._pairs is not None else len(self._image_times)

    def ground_truth(self) -> Poses | None:
        topic = self.topics.ground_truth
        if topic is None:
            return None
        topic_type = self._reader.topics[topic].msgtype
        rows = [
            row
            for _, message in _messages(self._reader, [topic])
            for row in _ground_truth_pose(topic_type, message, self._settings.ground_truth_child_frame)
        ]
        if topic_type == TF and not self._settings.ground_truth_child_frame:
            children = sorted(
                {t.child_frame_id for _, message in _messages(self._reader, [topic]) for t in message.transforms}
            )
            if len(children) > 1:
                raise SourceError(
                    f"{topic} holds transforms to several frames ({', '.join(children)}): name the "
                    "camera's in configs/camera.toml [rosbag] ground_truth_child_frame"
                )
        if not rows:
            return None
        times, positions, quaternions = zip(*rows)
        return Poses(np.array(times), np.array(positions), np.array(quaternions)).sorted_unique()

    def frames(self) -> Iterator[Frame]:
        topics = [self.topics.image] + ([self._depth_topic] if self.has_depth else [])
        image_number = depth_number = 0
        waiting_images: dict[int, np.ndarray] = {}  # image number -> gray, waiting for its depth
        depths: dict[int, np.ndarray] = {}  # depth number -> metres, waiting for its image
        wanted = set(self._pairs.values()) if self._pairs is not None else set()
        index = 0
        for topic, message in _messages(self._reader, topics):
            where = f"{self.path} {topic} message at {_stamp(message):.6f} s"
            if topic == self.topics.image:
                number, image_number = image_number, image_number + 1
                if self._pairs is not None and number not in self._pairs:
                    continue
                waiting_images[number] = decode_image(message, where)
            else:
                number, depth_number = depth_number, depth_number + 1
                if number in wanted:
                    depths[number] = decode_depth(message, where)
            # Messages come in recording order, which may put a depth image before or after its colour image.
            for number in sorted(waiting_images):
                depth = None
                if self._pairs is not None:
                    if self._pairs[number] not in depths:
                        break
                    depth = check_depth(depths[self._pairs[number]], waiting_images[number], self._depth_limits, where)
                    # Nearest-in-time pairing is monotone: later images never use an earlier depth.
                    depths = {n: d for n, d in depths.items() if n >= self._pairs[number]}
                yield Frame(index, float(self._image_times[number]), waiting_images.pop(number), self.intrinsics, depth)
                index += 1

    def close(self) -> None:
        if self._reader.stack is not None:
            self._reader.close()
