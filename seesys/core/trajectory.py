"""Timestamped camera poses and their file formats: the one pose container and TUM reader/writer of SEESys.

Every trajectory SEESys reads or writes (a session's ``trajectory.tum`` and ``groundtruth.tum``, a dataset's
ground truth, motion capture converted to the camera, the renderer's paths) is a :class:`Poses` of
T_world_camera, and every TUM file goes through :func:`read_tum` / :func:`write_tum`. The TUM format is one pose
per line, ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, a unit quaternion in x y z w order), with ``#``
comments. Metrics are evo's: :meth:`Poses.to_evo` hands a trajectory to it (evo itself refuses an empty one,
which is why this container exists beside evo's: a session that never initialised has an empty trajectory).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.errors import SeesysError

if TYPE_CHECKING:
    from evo.core.trajectory import PoseTrajectory3D

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"


class TrajectoryError(SeesysError):
    """A trajectory file is missing or malformed, or poses are inconsistent."""


@dataclass(frozen=True)
class Poses:
    """Poses T_world_camera at ``timestamps`` (N,): camera positions (N×3) and unit quaternions (N×4, x y z w)."""

    timestamps: np.ndarray
    positions: np.ndarray
    quaternions_xyzw: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.timestamps)
        if self.positions.shape != (n, 3) or self.quaternions_xyzw.shape != (n, 4):
            raise TrajectoryError(
                f"pose shapes disagree: {n} timestamps, positions {self.positions.shape}, "
                f"quaternions {self.quaternions_xyzw.shape}"
            )

    def __len__(self) -> int:
        return len(self.timestamps)

    @classmethod
    def empty(cls) -> Poses:
        return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 4)))

    @classmethod
    def from_rotations(cls, timestamps: np.ndarray, positions: np.ndarray, rotations: Rotation) -> Poses:
        return cls(np.asarray(timestamps, dtype=float), np.asarray(positions, dtype=float), rotations.as_quat())

    @classmethod
    def from_matrices(cls, timestamps: np.ndarray, matrices: np.ndarray) -> Poses:
        """Poses from (N, 4, 4) T_world_camera matrices: the inverse of :attr:`matrices`."""
        m = np.asarray(matrices, dtype=float).reshape(-1, 4, 4)
        return cls.from_rotations(timestamps, m[:, :3, 3], Rotation.from_matrix(m[:, :3, :3]))

    @property
    def rotations(self) -> Rotation:
        """R_world_camera of every pose (scipy)."""
        return Rotation.from_quat(self.quaternions_xyzw)

    @property
    def matrices(self) -> np.ndarray:
        """T_world_camera of every pose as a 4×4 matrix (N, 4, 4)."""
        m = np.tile(np.eye(4), (len(self), 1, 1))
        m[:, :3, :3] = self.rotations.as_matrix()
        m[:, :3, 3] = self.positions
        return m

    def take(self, index: np.ndarray | slice) -> Poses:
        """The poses at ``index`` (an index array, a boolean mask or a slice)."""
        return Poses(self.timestamps[index], self.positions[index], self.quaternions_xyzw[index])

    def sorted_unique(self) -> Poses:
        """The poses in time order, keeping the first of poses with equal timestamps."""
        order = np.argsort(self.timestamps, kind="stable")
        times = self.timestamps[order]
        keep = np.concatenate([[True], np.diff(times) > 0]) if len(times) else np.zeros(0, bool)
        return self.take(order[keep])

    def to_evo(self) -> PoseTrajectory3D:
        """An evo ``PoseTrajectory3D`` of these poses (evo refuses an empty trajectory)."""
        from evo.core.trajectory import PoseTrajectory3D

        if len(self) == 0:
            raise TrajectoryError("an empty trajectory has no evo form")
        return PoseTrajectory3D(
            positions_xyz=self.positions,
            orientations_quat_wxyz=self.quaternions_xyzw[:, [3, 0, 1, 2]],
            timestamps=self.timestamps,
        )


def sim3_scale(source_xyz: np.ndarray, target_xyz: np.ndarray) -> float:
    """The scale c of the Sim(3) alignment (evo's Umeyama) that best maps the positions ``source_xyz`` (N×3) onto
    ``target_xyz``: target ≈ c·R·source + t. NaN when the points are degenerate (too few, or all in a line)."""
    from evo.core.geometry import GeometryException, umeyama_alignment

    try:
        _, _, c = umeyama_alignment(np.asarray(source_xyz, float).T, np.asarray(target_xyz, float).T, with_scale=True)
    except GeometryException:
        return float("nan")
    return float(c) if np.isfinite(c) and c > 0 else float("nan")


def tum_line(timestamp: float | str, position: np.ndarray, quaternion_xyzw: np.ndarray, decimals: int = 9) -> str:
    """One TUM line, with its newline: the timestamp to the microsecond (or as given, when a string) and the pose
    with ``decimals`` decimals."""
    stamp = timestamp if isinstance(timestamp, str) else f"{timestamp:.6f}"
    values = " ".join(f"{v:.{decimals}f}" for v in (*position, *quaternion_xyzw))
    return f"{stamp} {values}\n"


def pose_tum_line(timestamp: float, pose: np.ndarray) -> str:
    """The TUM line of a 4×4 pose matrix T_world_camera."""
    return tum_line(timestamp, pose[:3, 3], Rotation.from_matrix(pose[:3, :3]).as_quat())
