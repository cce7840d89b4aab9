"""A simulated motion-capture rig: a handheld camera's motion seen by SLAM and, through a marker body on another
clock, by the mocap; the session folder they write."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import write_tum
from study.mocap.handeye import to_matrix

# The simulated rig: camera-to-marker lever arm and mounting rotation, the SLAM world in the Vicon frame, and
# the mocap clock behind the camera clock.
MARKER_CAMERA = to_matrix(Rotation.from_euler("xyz", [20, -35, 50], degrees=True), np.array([0.05, -0.03, 0.08]))
WORLD_IN_VICON = to_matrix(Rotation.from_euler("xyz", [5, 10, -80], degrees=True), np.array([1.0, 2.0, 0.5]))
OFFSET_S = 0.1234


def camera_in_vicon(t: np.ndarray) -> np.ndarray:
    """A handheld-like smooth motion: walking-scale translation, rotation about all three axes."""
    pos = np.column_stack([0.6 * np.sin(2 * np.pi * f * t + p) for f, p in ((0.21, 0.3), (0.33, 1.1), (0.47, 2.0))])
    rv = np.column_stack(
        [
            0.5 * np.sin(2 * np.pi * f * t + p) + 0.2 * np.sin(2 * np.pi * 0.9 * t + k)
            for k, (f, p) in enumerate(((0.43, 0.3), (0.61, 1.1), (0.27, 2.0)))
        ]
    )
    m = np.tile(np.eye(4), (len(t), 1, 1))
    m[:, :3, :3] = Rotation.from_rotvec(rv).as_matrix()
    m[:, :3, 3] = pos
    return m


def noisy_poses(times: np.ndarray, m: np.ndarray, noise_m: float, noise_deg: float, rng) -> Poses:
    rotations = Rotation.from_matrix(m[:, :3, :3]) * Rotation.from_rotvec(
        rng.normal(0, np.radians(noise_deg), (len(times), 3))
    )
    return Poses.from_rotations(times, m[:, :3, 3] + rng.normal(0, noise_m, (len(times), 3)), rotations)


def write_simulated_session(folder: Path) -> Path:
    """A session folder: SLAM at ~30 Hz (1 mm / 0.1 deg noise, jittered stamps) and mocap at 100 Hz
    (0.2 mm / 0.03 deg noise) on a clock OFFSET_S behind."""
    rng = np.random.default_rng(7)
    t_cam = 1000.0 + np.arange(0, 30, 1 / 30) + rng.normal(0, 0.0005, 900)
    slam = noisy_poses(t_cam, np.linalg.inv(WORLD_IN_VICON) @ camera_in_vicon(t_cam - 1000.0), 0.001, 0.1, rng)
    t_true = 999.0 + np.arange(0, 33, 0.01)
    markers = noisy_poses(
        t_true - OFFSET_S, camera_in_vicon(t_true - 1000.0) @ np.linalg.inv(MARKER_CAMERA), 0.0002, 0.03, rng
    )
    write_tum(folder / "trajectory.tum", slam)
    write_tum(folder / "mocap.tum", markers)
    return folder
