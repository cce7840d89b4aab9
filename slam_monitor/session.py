"""The device's session folder, written as frames come so that a crash leaves valid files.

- ``session.json``: the manifest (source, mode, resolved configuration, package versions, start time, and at the
  end the status, frame counts and any error); rewritten atomically, never half-written.
- ``frames.csv``: ``frame_index,timestamp,state,tracked_points,track_ms`` for every frame given to SLAM.
- ``trajectory.tum``: ``timestamp tx ty tz qx qy qz qw`` (T_world_camera) for every tracked frame.
- ``groundtruth.tum``: the source's ground truth (T_world_camera), when it has one.
- ``orbslam3.yaml`` (the settings used) and ``orbslam3.log`` (ORB-SLAM3's console output).

Every row is flushed when written. Other parts of SEESys add their own files to the same folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from seesys.core.errors import SeesysError
from seesys.core.session_layout import FRAMES_CSV, FRAMES_HEADER, GROUND_TRUTH, MANIFEST, SETTINGS, TRAJECTORY
from seesys.core.trajectory import TUM_HEADER, Poses, pose_tum_line
from seesys.io.session_files import package_versions, update_manifest, utc_now
from seesys.io.trajectory_files import write_tum
from slam_monitor.tracker import TrackOutput


def prepare_session_folder(folder: Path) -> Path:
    """Create ``folder``, removing the device files of an earlier session in it (other files are kept).

    ``orbslam3.log`` is left alone: the worker process has already started it for this session.
    """
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SeesysError(f"cannot create the session folder {folder}: {e.strerror}") from None
    for name in (MANIFEST, FRAMES_CSV, TRAJECTORY, GROUND_TRUTH, SETTINGS):
        (folder / name).unlink(missing_ok=True)
    return folder


class SessionWriter:
    """Appends frames to ``frames.csv`` and ``trajectory.tum`` and keeps ``session.json`` up to date."""

    def __init__(self, folder: Path, manifest: dict[str, Any]):
        self.folder = folder
        update_manifest(folder, **manifest, status="running", start_time=utc_now(), packages=package_versions())
        self._frames = open(folder / FRAMES_CSV, "w", encoding="ascii")
        self._frames.write(FRAMES_HEADER + "\n")
        self._frames.flush()
        self._trajectory = open(folder / TRAJECTORY, "w", encoding="ascii")
        self._trajectory.write(TUM_HEADER + "\n")
        self._trajectory.flush()
        self.frames_written = 0
        self.frames_tracked = 0

    def describe_source(self, description: str, intrinsics: dict[str, Any], fps: float) -> None:
        """Record what the source turned out to be once it is open."""
        update_manifest(self.folder, source_description=description, intrinsics=intrinsics, fps=fps)

    def write_ground_truth(self, ground_truth: Poses) -> None:
        write_tum(self.folder / GROUND_TRUTH, ground_truth)

    def write_frame(self, output: TrackOutput) -> None:
        self._frames.write(
            f"{output.frame_index},{output.timestamp:.6f},{output.state.name},{output.num_tracked_points},"
            f"{output.track_ms:.3f}\n"
        )
        self._frames.flush()
        self.frames_written += 1
        if output.tracked and output.pose_wc is not None:  # a tracked frame has a pose
            self._trajectory.write(pose_tum_line(output.timestamp, output.pose_wc))
            self._trajectory.flush()
            self.frames_tracked += 1

    def finish(self, status: str, **details: Any) -> None:
        """Close the logs and record how the session ended (``completed``, ``failed``, ``interrupted``)."""
        self._frames.close()
        self._trajectory.close()
        update_manifest(
            self.folder,
            status=status,
            end_time=utc_now(),
            frames=self.frames_written,
            frames_tracked=self.frames_tracked,
            **details,
        )
