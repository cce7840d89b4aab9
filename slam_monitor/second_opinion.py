"""A second opinion on the camera's motion, independent of ORB-SLAM3's matcher and solver, and its disagreement with
ORB-SLAM3's over the label's span (RTS channel ``flow_disagreement``).

Every ``hop_frames``-th frame (a frame whose index is a multiple of it: on a device, where the model's windows end),
ORB-SLAM3's keypoints of the previous hop frame that have a measured depth (at most ``max_points``, evenly taken) are
followed into the current image by pyramidal Lucas–Kanade optical flow (``calcOpticalFlowPyrLK``, a
``window_px`` window over ``pyramid_levels`` levels), lifted to 3D with the previous hop frame's depth, and the
current camera's pose relative to that frame is fitted by PnP with RANSAC (``solvePnPRansac``, reprojection gate
``ransac_gate_px``): metric, from another matcher (flow, not ORB descriptors) and another solver (OpenCV's, not g2o's)
than ORB-SLAM3's. The keypoints' positions are shared with ORB-SLAM3: detecting corners of our own
(``goodFeaturesToTrack``) cost 7 ms a frame on the sample, and following them frame by frame 6 ms more, against
about 2.4 ms for one hop of 150 keypoints every fifth frame (docs/rts-features.md).

The disagreement at a hop frame is that of the label's span (``span_frames``, the label's ``delta_frames``): the
flow's hops over the span composed, against ORB-SLAM3's relative pose over the same frames (T_wc(k − Δ)⁻¹ T_wc(k)),
as the norm of the translation of one relative pose against the other, in metres — the same kind of quantity as the
label, with the flow standing in for the ground truth. Frames between two hop frames hold the last hop frame's value
(at most ``hop_frames`` − 1 frames old), so that every frame has the channel and a window ending on a hop frame has
it fresh. A hop the flow cannot follow (too few keypoints with depth or inliers), an untracked frame or a missing hop
frame (dropped) break the span, which then starts again: the channel has no value (NaN) until the span is whole.
Monocular flow gives only the direction of the translation, so a monocular device has no metric disagreement and no
value.
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
    """How the second opinion follows the image (``[second_opinion]`` of monitor.toml; ``span_frames`` is the
    label's ``delta_frames``, from labels.toml)."""

    hop_frames: int
    span_frames: int
    max_points: int
    window_px: int
    pyramid_levels: int
    ransac_gate_px: float
    min_depth_m: float
    max_depth_m: float

    def __post_init__(self) -> None:
        if self.hop_frames < 1 or self.span_frames % self.hop_frames:
            raise ValueError(
                f"second_opinion.hop_frames ({self.hop_frames}) must divide the label's span ({self.span_frames} "
                "frames)"
            )


def _to_pose(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rvec)[0]
    pose[:3, 3] = np.asarray(tvec, np.float64).ravel()
    return pose


def keypoint_depths(points_px: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """The depth image's value at each keypoint (N, 2), rounded to the nearest pixel; NaN outside the image."""
    points = np.asarray(points_px, np.float64).reshape(-1, 2)
    columns, rows = np.round(points).astype(int).T
    inside = (columns >= 0) & (columns < depth_m.shape[1]) & (rows >= 0) & (rows < depth_m.shape[0])
    z = np.full(len(points), np.nan)
    z[inside] = depth_m[rows[inside], columns[inside]]
    return z


def rgbd_motion(
    previous: np.ndarray,
    current: np.ndarray,
    previous_points_px: np.ndarray,
    previous_points_depth_m: np.ndarray,
    camera_matrix: np.ndarray,
    cfg: FlowConfig,
) -> np.ndarray | None:
    """The camera's motion from the previous image to the current one, T_previous_current (4×4, metres), from the
    flow of ``previous_points_px`` (N, 2: the previous image's keypoints) whose depths are
    ``previous_points_depth_m`` (N,: :func:`keypoint_depths` of the previous depth image); None where the flow
    cannot tell it."""
    points = np.asarray(previous_points_px, np.float64).reshape(-1, 2)
    z = np.asarray(previous_points_depth_m, np.float64)
    usable = np.flatnonzero(np.isfinite(z) & (z > cfg.min_depth_m) & (z < cfg.max_depth_m))
    if len(usable) < _MIN_INLIERS:
        return None
    if len(usable) > cfg.max_points:
        usable = usable[np.linspace(0, len(usable) - 1, cfg.max_points).astype(int)]
    before = points[usable].astype(np.float32).reshape(-1, 1, 2)
    after, found, _ = cv2.calcOpticalFlowPyrLK(
        previous,
        current,
        before,
        np.empty_like(before),
        winSize=(cfg.window_px, cfg.window_px),
        maxLevel=cfg.pyramid_levels,
    )
    kept = found.ravel() == 1
    if kept.sum() < _MIN_INLIERS:
        return None
    rays = np.column_stack([points[usable][kept], np.ones(kept.sum())]) @ np.linalg.inv(camera_matrix).T
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        rays * z[usable][kept, None],
        after.reshape(-1, 2)[kept].astype(np.float64),
        camera_matrix,
        None,
        reprojectionError=cfg.ransac_gate_px,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )
    if not ok or inliers is None or len(inliers) < _MIN_INLIERS:
        return None
    # PnP gives T_current_previous (previous camera's points into the current camera); the motion is its inverse.
    return np.linalg.inv(_to_pose(rvec, tvec))


@dataclass(frozen=True)
class _HopFrame:
    """The last hop frame: what the next hop's flow starts from (its image, keypoints and their depths; not the
    depth image, which a device allocates for every frame)."""

    index: int
    gray: np.ndarray
    keypoints_px: np.ndarray
    keypoint_depths_m: np.ndarray


class SecondOpinion:
    """The disagreement (metres) of the flow's motion with ORB-SLAM3's over the label's span, for an RGB-D device,
    frame by frame (see the module docstring)."""

    def __init__(self, cfg: FlowConfig):
        self._cfg = cfg
        self._hops_per_span = cfg.span_frames // cfg.hop_frames
        self._hops: deque[np.ndarray] = deque(maxlen=self._hops_per_span)
        # The span's hop frames' ORB-SLAM3 poses (index, T_wc), and the last hop frame's image: one image is kept.
        self._poses: deque[tuple[int, np.ndarray]] = deque(maxlen=self._hops_per_span + 1)
        self._last: _HopFrame | None = None
        self._value: float | None = None

    def _restart(self) -> None:
        self._hops.clear()
        self._poses.clear()
        self._last = None
        self._value = None

    def _keep(self, index: int, gray: np.ndarray, depth_m: np.ndarray, keypoints_px: np.ndarray, pose_wc: np.ndarray):
        self._poses.append((index, pose_wc))
        self._last = _HopFrame(index, gray, keypoints_px, keypoint_depths(keypoints_px, depth_m))

    def update(
        self,
        index: int,
        gray: np.ndarray,
        depth_m: np.ndarray | None,
        keypoints_px: np.ndarray,
        camera_matrix: np.ndarray,
        pose_wc: np.ndarray | None,
    ) -> float | None:
        """Add frame ``index`` (``pose_wc``: ORB-SLAM3's T_world_camera, None when untracked; ``keypoints_px``: its
        keypoints); the disagreement over the span ending at the last hop frame, or None while there is none."""
        if pose_wc is None or depth_m is None:
            self._restart()
            return None
        if index % self._cfg.hop_frames:
            return self._value
        previous = self._last
        if previous is None or previous.index != index - self._cfg.hop_frames:
            self._restart()
            self._keep(index, gray, depth_m, keypoints_px, pose_wc)
            return None
        motion = rgbd_motion(
            previous.gray, gray, previous.keypoints_px, previous.keypoint_depths_m, camera_matrix, self._cfg
        )
        if motion is None:
            self._restart()
            self._keep(index, gray, depth_m, keypoints_px, pose_wc)
            return None
        self._hops.append(motion)
        self._keep(index, gray, depth_m, keypoints_px, pose_wc)
        if len(self._hops) < self._hops_per_span:
            self._value = None
            return None
        flow = np.eye(4)
        for step in self._hops:
            flow = flow @ step
        slam = np.linalg.inv(self._poses[0][1]) @ pose_wc
        self._value = relative_translation_error(flow, slam)
        return self._value


def relative_translation_error(reference: np.ndarray, estimate: np.ndarray) -> float:
    """‖translation((reference)⁻¹ · estimate)‖: the label's error of one relative pose against another (metres)."""
    return float(np.linalg.norm((np.linalg.inv(reference) @ estimate)[:3, 3]))
