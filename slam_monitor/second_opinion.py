"""A second opinion on the camera's motion, independent of ORB-SLAM3, and its disagreement with ORB-SLAM3's.

Frame to frame, corners of the previous image (OpenCV ``goodFeaturesToTrack``) are followed into the current one by
pyramidal Lucas–Kanade optical flow (``calcOpticalFlowPyrLK``, kept where the flow back to the previous image returns
within ``max_flow_error_px``). In RGB-D the corners are lifted to 3D with the previous frame's depth and the current
camera's pose relative to the previous one is fitted by PnP with RANSAC (``solvePnPRansac``, reprojection gate
``ransac_gate_px``): metric, from other features, another matcher and another solver than ORB-SLAM3's. Monocular
flow gives the rotation and only the direction of the translation (``findEssentialMat``, ``recoverPose``), so the
monocular second opinion has no metric disagreement.

The disagreement at a frame is that of the label's span: the flow's motions over the last ``delta_frames`` frames
composed, against ORB-SLAM3's relative pose over the same frames (T_wc(k − Δ)⁻¹ T_wc(k)), as the norm of the
translation of one relative pose against the other, in metres — the same kind of quantity as the label, with the
flow standing in for the ground truth. A frame the flow cannot follow (too few corners or inliers, no depth) and an
untracked frame break the span, which then starts again. Not in the RTS schema yet (see
``slam_monitor.observability``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

# Fewer inliers than this give no motion: PnP on a handful of points is a guess.
_MIN_INLIERS = 12


@dataclass(frozen=True)
class FlowConfig:
    """How the second opinion follows the image (``[second_opinion]`` of monitor.toml)."""

    max_corners: int
    corner_quality: float
    min_corner_distance_px: float
    max_flow_error_px: float
    ransac_gate_px: float
    min_depth_m: float
    max_depth_m: float


def _to_pose(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = np.asarray(tvec, np.float64).ravel()
    return pose


def followed_corners(previous: np.ndarray, current: np.ndarray, cfg: FlowConfig) -> tuple[np.ndarray, np.ndarray]:
    """Corners of ``previous`` and where the flow puts them in ``current`` (N, 2 each, pixels), kept where the flow
    back lands within ``max_flow_error_px`` of the corner."""
    corners = cv2.goodFeaturesToTrack(previous, cfg.max_corners, cfg.corner_quality, cfg.min_corner_distance_px)
    if corners is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    ahead, found, _ = cv2.calcOpticalFlowPyrLK(previous, current, corners, np.empty_like(corners))
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(current, previous, ahead, np.empty_like(ahead))
    error = np.linalg.norm((back - corners).reshape(-1, 2), axis=1)
    keep = (found.ravel() == 1) & (found_back.ravel() == 1) & (error < cfg.max_flow_error_px)
    return corners.reshape(-1, 2)[keep].astype(np.float64), ahead.reshape(-1, 2)[keep].astype(np.float64)


def rgbd_motion(
    previous: np.ndarray, current: np.ndarray, previous_depth_m: np.ndarray, camera_matrix: np.ndarray, cfg: FlowConfig
) -> np.ndarray | None:
    """The camera's motion from the previous frame to the current one, T_previous_current (4×4, metres), or None
    where the flow cannot tell it."""
    before, after = followed_corners(previous, current, cfg)
    if len(before) < _MIN_INLIERS:
        return None
    columns, rows = np.round(before).astype(int).T
    inside = (columns >= 0) & (columns < previous_depth_m.shape[1]) & (rows >= 0) & (rows < previous_depth_m.shape[0])
    z = np.full(len(before), np.nan)
    z[inside] = previous_depth_m[rows[inside], columns[inside]]
    usable = np.isfinite(z) & (z > cfg.min_depth_m) & (z < cfg.max_depth_m)
    if usable.sum() < _MIN_INLIERS:
        return None
    k_inv = np.linalg.inv(camera_matrix)
    rays = np.column_stack([before[usable], np.ones(usable.sum())]) @ k_inv.T
    points = rays * z[usable, None]
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        points, after[usable], camera_matrix, None, reprojectionError=cfg.ransac_gate_px, flags=cv2.SOLVEPNP_ITERATIVE
    )
    if not found or inliers is None or len(inliers) < _MIN_INLIERS:
        return None
    # PnP gives T_current_previous (previous camera's points into the current camera); the motion is its inverse.
    return np.linalg.inv(_to_pose(rvec, tvec))


def mono_motion(
    previous: np.ndarray, current: np.ndarray, camera_matrix: np.ndarray, cfg: FlowConfig
) -> np.ndarray | None:
    """The camera's rotation and translation direction (unit vector) from the previous frame to the current one, as
    T_previous_current with a unit translation, or None."""
    before, after = followed_corners(previous, current, cfg)
    if len(before) < _MIN_INLIERS:
        return None
    essential, mask = cv2.findEssentialMat(before, after, camera_matrix, cv2.RANSAC, 0.999, cfg.ransac_gate_px)
    if essential is None or essential.shape != (3, 3):
        return None
    count, rotation, translation, _ = cv2.recoverPose(essential, before, after, camera_matrix, mask=mask)
    if count < _MIN_INLIERS:
        return None
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, translation.ravel()
    return np.linalg.inv(pose)


class SecondOpinion:
    """The disagreement (metres) of the flow's motion with ORB-SLAM3's over the last ``delta_frames`` frames of an
    RGB-D device, frame by frame."""

    def __init__(self, cfg: FlowConfig, delta_frames: int):
        self._cfg = cfg
        self._delta = delta_frames
        self._previous: tuple[np.ndarray, np.ndarray] | None = None  # gray and depth of the previous frame
        self._flow: deque[np.ndarray] = deque(maxlen=delta_frames)
        self._poses: deque[np.ndarray] = deque(maxlen=delta_frames + 1)

    def _restart(self) -> None:
        self._flow.clear()
        self._poses.clear()

    def update(
        self, gray: np.ndarray, depth_m: np.ndarray, camera_matrix: np.ndarray, pose_wc: np.ndarray | None
    ) -> float | None:
        """Add a frame (``pose_wc``: ORB-SLAM3's T_world_camera, None when untracked); the disagreement over the
        span ending here, or None while the span is shorter than ``delta_frames``."""
        previous, self._previous = self._previous, (gray, depth_m)
        if pose_wc is None or previous is None:
            self._restart()
            if pose_wc is not None:
                self._poses.append(pose_wc)
            return None
        motion = rgbd_motion(previous[0], gray, previous[1], camera_matrix, self._cfg)
        if motion is None:
            self._restart()
            self._poses.append(pose_wc)
            return None
        self._flow.append(motion)
        self._poses.append(pose_wc)
        if len(self._flow) < self._delta:
            return None
        flow = np.eye(4)
        for step in self._flow:
            flow = flow @ step
        slam = np.linalg.inv(self._poses[0]) @ self._poses[-1]
        return relative_translation_error(flow, slam)


def relative_translation_error(reference: np.ndarray, estimate: np.ndarray) -> float:
    """‖translation((reference)⁻¹ · estimate)‖: the label's error of one relative pose against another (metres)."""
    return float(np.linalg.norm((np.linalg.inv(reference) @ estimate)[:3, 3]))
