"""A session folder as a ROS 2 bag (``seesys session export-bag``): poses, tracking states, estimates.

Standard message types only, so rviz, Foxglove and ``ros2 bag play`` read it without SEESys. Every message's log
time is the time of the frame it belongs to (the session's clock, seconds in the TUM files and CSVs). Topics,
frame ids and storage come from ``configs/export.toml``:

- poses (``trajectory.tum``): ``geometry_msgs/PoseStamped`` per tracked frame and one ``nav_msgs/Path`` of them all,
  logged at the last pose's time;
- poses with their predicted covariance (``pose_covariance.csv``, when present):
  ``geometry_msgs/PoseWithCovarianceStamped`` for each tracked frame that has both, matched by time; the
  covariance is the monitor's (``slam_monitor.observability``), row-major 6×6 in ROS's order and the world's axes;
- poses with their covariance scaled to the estimated error (``pose_covariance.csv`` and ``estimates.csv``):
  ``geometry_msgs/PoseWithCovarianceStamped`` for each estimated frame whose label pair (the frame and the frame
  ``delta_frames`` before it, labels.toml) both have a covariance and a pose: the monitor's covariance scaled so that
  the pair's σ is the estimate (:func:`seesys.core.pose_covariance.scaled_to_error`), the shape of the pose fit's
  geometry with the size of the error the model estimates;
- ground truth (``groundtruth.tum``, when present): ``geometry_msgs/PoseStamped``;
- tracking states (``frames.csv``): ``std_msgs/String`` with the state's name (``OK``, ``LOST``, ...) per frame;
  a String because ROS has no standard message for a SLAM tracking state, and a name reads the same in every tool;
- estimates (``estimates.csv``, when present): ``std_msgs/Float64``, the error in metres, at the estimated frame's
  time (the log time carries the time, as Foxglove plots a topic by it).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from seesys.core import session_layout
from seesys.core.errors import SeesysError
from seesys.core.pose_covariance import pair_covariance, scaled_to_error
from seesys.core.trajectory import Poses
from seesys.io.config import load_section
from seesys.io.logfiles import read_csv_table
from seesys.io.rts_log import PoseCovarianceLog, read_pose_covariance_log
from seesys.io.trajectory_files import read_tum

NS_PER_S = 1_000_000_000
STORAGES = ("sqlite3", "mcap")


@dataclass(frozen=True)
class ExportSettings:
    """``configs/export.toml``."""

    export_storage: str
    export_world_frame: str
    export_camera_frame: str
    export_pose_topic: str
    export_path_topic: str
    export_pose_covariance_topic: str
    export_scaled_pose_covariance_topic: str
    export_ground_truth_topic: str
    export_tracking_state_topic: str
    export_pose_error_topic: str


def load_export_settings(directory: Path | None = None) -> ExportSettings:
    """``configs/export.toml``; a storage other than sqlite3 or mcap is an error."""
    settings = load_section("export", ExportSettings, directory)
    if settings.export_storage not in STORAGES:
        raise SeesysError(
            f"export.toml: export_storage must be one of {', '.join(STORAGES)}, not {settings.export_storage!r}"
        )
    return settings


def _ns(t: float) -> int:
    return int(round(t * NS_PER_S))


class _Messages:
    """Builds the standard messages from rosbags' ROS 2 type store."""

    def __init__(self, store, settings: ExportSettings):
        self.types = store.types
        self.settings = settings

    def header(self, t: float, frame: str):
        sec = int(np.floor(t))
        stamp = self.types["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=min(int(round((t - sec) * 1e9)), NS_PER_S - 1)
        )
        return self.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def pose(self, p: np.ndarray, q: np.ndarray):
        types = self.types
        return types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=types["geometry_msgs/msg/Quaternion"](
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
            ),
        )

    def poses(self, poses: Poses) -> list:
        return [
            self.types["geometry_msgs/msg/PoseStamped"](
                header=self.header(float(t), self.settings.export_world_frame), pose=self.pose(p, q)
            )
            for t, p, q in zip(poses.timestamps, poses.positions, poses.quaternions_xyzw)
        ]

    def poses_with_covariance(self, poses: Poses, covariances: np.ndarray) -> list:
        types = self.types
        return [
            types["geometry_msgs/msg/PoseWithCovarianceStamped"](
                header=self.header(float(t), self.settings.export_world_frame),
                pose=types["geometry_msgs/msg/PoseWithCovariance"](
                    pose=self.pose(p, q), covariance=np.ascontiguousarray(c, np.float64).ravel()
                ),
            )
            for t, p, q, c in zip(poses.timestamps, poses.positions, poses.quaternions_xyzw, covariances)
        ]


@dataclass(frozen=True)
class _CovariancePoses:
    """The poses that have a covariance row at their time (evo's time association), those covariances and their
    frames' indices."""

    poses: Poses
    covariances: np.ndarray
    frame_index: np.ndarray

    def scaled_to_estimates(self, estimates: pd.DataFrame, delta_frames: int) -> tuple[Poses, np.ndarray]:
        """The poses of the estimated frames whose label pair has covariances and poses, with each one's
        covariance scaled to its estimate (:func:`seesys.core.pose_covariance.scaled_to_error`)."""
        by_frame = {int(f): k for k, f in enumerate(self.frame_index)}
        covariances = {f: self.covariances[k] for f, k in by_frame.items()}
        positions = {f: self.poses.positions[k] for f, k in by_frame.items()}
        kept, scaled = [], []
        for j, error_m in zip(estimates.frame_index.astype(int), estimates.error_m.astype(float)):
            pair = pair_covariance(covariances, positions, j, delta_frames)
            covariance = scaled_to_error(covariances[j], pair, error_m) if pair is not None else None
            if covariance is not None:
                kept.append(by_frame[j])
                scaled.append(covariance)
        return self.poses.take(np.asarray(kept, int)), np.asarray(scaled).reshape(-1, 6, 6)


def _covariance_poses(poses: Poses, logged: PoseCovarianceLog) -> _CovariancePoses:
    pose_index, log_index = logged.matched(poses)
    return _CovariancePoses(poses.take(pose_index), logged.matrices[log_index], logged.frame_index[log_index])


def _pose_covariance_topic(build: _Messages, poses: Poses, covariances: np.ndarray) -> tuple[str, list]:
    return (
        "geometry_msgs/msg/PoseWithCovarianceStamped",
        list(zip(map(_ns, poses.timestamps), build.poses_with_covariance(poses, covariances))),
    )


def export_session_bag(session: Path, out: Path, settings: ExportSettings, delta_frames: int) -> dict[str, int]:
    """Write ``session`` as a ROS 2 bag folder ``out``; returns the messages written per topic. ``delta_frames``:
    the label's span (labels.toml), the pair the estimate scales the covariance by.

    Fails with a :class:`SeesysError` when ``session`` is not a session folder (no ``frames.csv`` or
    ``trajectory.tum``), a file is malformed, or ``out`` exists already.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    for name in (session_layout.FRAMES_CSV, session_layout.TRAJECTORY):
        if not (session / name).is_file():
            raise SeesysError(f"{session} is not a session folder: no {name}")
    if out.exists():
        raise SeesysError(f"{out} exists already; a bag is written into a new folder")
    frames = read_csv_table(session / session_layout.FRAMES_CSV, ("timestamp", "state"))
    poses = read_tum(session / session_layout.TRAJECTORY)
    truth_file = session / session_layout.GROUND_TRUTH
    truth = read_tum(truth_file) if truth_file.is_file() else None
    estimates_file = session / session_layout.ESTIMATES_CSV
    estimates = (
        read_csv_table(estimates_file, ("frame_index", "timestamp", "error_m")) if estimates_file.is_file() else None
    )
    covariances = read_pose_covariance_log(session)

    store = get_typestore(Stores.LATEST)
    build = _Messages(store, settings)
    path_type, pose_type = "nav_msgs/msg/Path", "geometry_msgs/msg/PoseStamped"
    # topic -> (type, [(log time ns, message)])
    topics: dict[str, tuple[str, list]] = {}
    pose_messages = build.poses(poses)
    topics[settings.export_pose_topic] = (pose_type, list(zip(map(_ns, poses.timestamps), pose_messages)))
    if len(poses):
        path = store.types[path_type](
            header=build.header(float(poses.timestamps[-1]), settings.export_world_frame), poses=pose_messages
        )
        topics[settings.export_path_topic] = (path_type, [(_ns(poses.timestamps[-1]), path)])
    if covariances is not None:
        with_covariance = _covariance_poses(poses, covariances)
        topics[settings.export_pose_covariance_topic] = _pose_covariance_topic(
            build, with_covariance.poses, with_covariance.covariances
        )
        if estimates is not None:
            topics[settings.export_scaled_pose_covariance_topic] = _pose_covariance_topic(
                build, *with_covariance.scaled_to_estimates(estimates, delta_frames)
            )
    if truth is not None:
        topics[settings.export_ground_truth_topic] = (
            pose_type,
            list(zip(map(_ns, truth.timestamps), build.poses(truth))),
        )
    string, float64 = store.types["std_msgs/msg/String"], store.types["std_msgs/msg/Float64"]
    topics[settings.export_tracking_state_topic] = (
        "std_msgs/msg/String",
        [(_ns(t), string(data=str(state))) for t, state in zip(frames.timestamp, frames.state)],
    )
    if estimates is not None:
        topics[settings.export_pose_error_topic] = (
            "std_msgs/msg/Float64",
            [(_ns(t), float64(data=float(error))) for t, error in zip(estimates.timestamp, estimates.error_m)],
        )

    plugin = StoragePlugin.MCAP if settings.export_storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(out, version=9, storage_plugin=plugin) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=store) for topic, (msgtype, _) in topics.items()
        }
        # rosbag2 readers expect messages in log-time order across topics
        merged = sorted(
            ((ns, topic, i) for topic, (_, messages) in topics.items() for i, (ns, _) in enumerate(messages))
        )
        for ns, topic, i in merged:
            msgtype, messages = topics[topic]
            writer.write(connections[topic], ns, store.serialize_cdr(messages[i][1], msgtype))
    return {topic: len(messages) for topic, (_, messages) in topics.items()}
