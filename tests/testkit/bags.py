"""ROS bags written with ``rosbags`` from a TUM RGB-D folder (the embedded sample), as a lab would record them.

The ROS 2 bag carries raw images (mono8 colour, 32FC1 depth in metres) and a PoseStamped ground truth; the ROS 1 bag
carries the JPEG frames as CompressedImage, 16UC1 depth in millimetres and ground truth as /tf transforms, so
that both message families and both depth conventions are read.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from seesys.io.trajectory_files import read_tum
from slam_monitor.sources.base import read_timestamped_list
from slam_monitor.sources.settings import folder_calibration, load_camera_config

TUM_DEPTH_UNITS = 5000.0


def _time(typestore, t: float):
    sec = int(np.floor(t))
    return typestore.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))


def _header(typestore, t: float, frame: str, ros1: bool):
    header = typestore.types["std_msgs/msg/Header"]
    stamp = _time(typestore, t)
    return header(seq=0, stamp=stamp, frame_id=frame) if ros1 else header(stamp=stamp, frame_id=frame)


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def write_sample_bag(
    folder: Path,
    out: Path,
    ros1: bool,
    image_topic: str | None = "/camera/color/image_raw",
    with_depth: bool = True,
    with_truth: bool = True,
    tf_children: tuple[str, ...] = ("camera",),
) -> Path:
    """Write the TUM folder ``folder`` as a ROS 1 ``.bag`` (``ros1``) or a ROS 2 bag folder at ``out``
    (``image_topic`` None: without colour images; ``tf_children``: the ROS 1 bag's /tf frames, all at the camera's
    pose)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:  # rosbags' Noetic store has no tf2_msgs: register /tf's type from its ROS 1 definition
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(out)
    else:
        from rosbags.rosbag2 import Writer

        writer = Writer(out, version=9)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    types = store.types
    intrinsics = folder_calibration(folder, load_camera_config().files).intrinsics
    images = read_timestamped_list(folder / "rgb.txt")
    depths = dict(read_timestamped_list(folder / "depth.txt"))
    with writer:

        def add(topic, msgtype):
            return writer.add_connection(topic, msgtype, typestore=store)

        image_type = "sensor_msgs/msg/CompressedImage" if ros1 else "sensor_msgs/msg/Image"
        colour = add(image_topic, image_type) if image_topic else None
        info = add("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo")
        depth = add("/camera/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image") if with_depth else None
        truth_type = "tf2_msgs/msg/TFMessage" if ros1 else "geometry_msgs/msg/PoseStamped"
        truth = add("/tf" if ros1 else "/mocap/camera_pose", truth_type) if with_truth else None
        k = np.array([intrinsics.fx, 0, intrinsics.cx, 0, intrinsics.fy, intrinsics.cy, 0, 0, 1], float)
        camera_info = {
            "header": _header(store, images[0][0], "camera", ros1),
            "height": intrinsics.height,
            "width": intrinsics.width,
            "distortion_model": "plumb_bob",
            ("D" if ros1 else "d"): np.array(intrinsics.distortion, float),
            ("K" if ros1 else "k"): k,
            ("R" if ros1 else "r"): np.eye(3).ravel(),
            ("P" if ros1 else "p"): np.concatenate([k.reshape(3, 3), np.zeros((3, 1))], axis=1).ravel(),
            "binning_x": 0,
            "binning_y": 0,
            "roi": types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        }
        writer.write(
            info,
            _ns(images[0][0]),
            serialize(types["sensor_msgs/msg/CameraInfo"](**camera_info), "sensor_msgs/msg/CameraInfo"),
        )
        for t, name in images:
            header = _header(store, t, "camera", ros1)
            if ros1:
                data = np.frombuffer((folder / name).read_bytes(), np.uint8)
                message = types[image_type](header=header, format="jpeg", data=data)
            else:
                gray = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
                message = types[image_type](
                    header=header,
                    height=gray.shape[0],
                    width=gray.shape[1],
                    encoding="mono8",
                    is_bigendian=0,
                    step=gray.shape[1],
                    data=gray.ravel(),
                )
            if colour is not None:
                writer.write(colour, _ns(t), serialize(message, image_type))
            if depth is not None:
                raw = cv2.imread(str(folder / depths[t]), cv2.IMREAD_UNCHANGED).astype(np.float64) / TUM_DEPTH_UNITS
                values = np.round(raw * 1000.0).astype(np.uint16) if ros1 else raw.astype(np.float32)
                message = types["sensor_msgs/msg/Image"](
                    header=header,
                    height=values.shape[0],
                    width=values.shape[1],
                    encoding="16UC1" if ros1 else "32FC1",
                    is_bigendian=0,
                    step=values.shape[1] * values.itemsize,
                    data=values.view(np.uint8).ravel(),
                )
                writer.write(depth, _ns(t), serialize(message, "sensor_msgs/msg/Image"))
        if truth is not None:
            poses = read_tum(folder / "groundtruth.txt")
            for t, p, q in zip(poses.timestamps, poses.positions, poses.quaternions_xyzw):
                header = _header(store, t, "world", ros1)
                if ros1:
                    message = types[truth_type](
                        transforms=[
                            types["geometry_msgs/msg/TransformStamped"](
                                header=header,
                                child_frame_id=child,
                                transform=types["geometry_msgs/msg/Transform"](
                                    translation=types["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
                                    rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                                ),
                            )
                            for child in tf_children
                        ]
                    )
                else:
                    message = types[truth_type](
                        header=header,
                        pose=types["geometry_msgs/msg/Pose"](
                            position=types["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                            orientation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                        ),
                    )
                writer.write(truth, _ns(t), serialize(message, truth_type))
    return out
