"""Tracking and mapping RTS channels from what pyorbslam3 exposes for one frame.

pyorbslam3 gives the pose, the SLAM's own count of matched inliers, all keypoints of the frame
(``tracked_keypoints()``, undistorted pixels) and the matched inlier map points (``tracked_map_points()``, world
coordinates) **without** the keypoint each one matched. This module recovers that pairing by projecting the map
points with the pose and the camera matrix and taking the nearest keypoint (a k-d tree), within a gate; ORB-SLAM3's
matches fall within 3 px of their keypoint for ~97 % of points. From there:

- inlier keypoints: the keypoints a matched map point projects onto (within the gate);
- reprojection error (the LocalMappingVisualError channel): mean distance, in px, from each matched map point's
  projection to its nearest keypoint. A lower bound on the residual of ORB-SLAM3's own match, measured on the
  current frame; local bundle adjustment residuals are not exposed by pyorbslam3;
- outliers (proxy): keypoints that are not inliers but onto which a *lost* map point projects within the gate,
  a lost point being one matched in the previous processed frame and not in this one: the track was there, the
  point is in view and a feature was detected where it projects, yet the tracker's final pose does not use the
  pair. ORB-SLAM3's own outlier flags are not exposed;
- matches before pose optimisation (proxy) = matched inliers + outliers;
- map-point depth statistics: mean and population variance of z of the matched points in the *current* camera.

Relative motion of frame t is taken against frame t−1 (consecutive frame indices, never a gap): the rotation
R_rel = R_wc(t−1)ᵀ·R_wc(t) as a rotation vector on the current camera's axes (pitch = x, yaw = y, roll = z,
sign-preserving, no Euler range folding), the translation R_wc(t)ᵀ·(c(t) − c(t−1)).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class RelativeMotion:
    """Camera motion from frame t−1 to frame t, in the current camera's frame (x right, y down, z forward)."""

    translation: np.ndarray
    roll: float
    pitch: float
    yaw: float

    @classmethod
    def still(cls) -> RelativeMotion:
        """No motion: used on the first frame with a pose, when frame t−1 had none (ORB-SLAM3's motion model
        starts from zero velocity there too)."""
        return cls(np.zeros(3), 0.0, 0.0, 0.0)


def relative_motion(pose_wc_prev: np.ndarray, pose_wc: np.ndarray) -> RelativeMotion:
    """Motion of the camera between two T_world_camera poses (4×4)."""
    r_prev, c_prev = pose_wc_prev[:3, :3], pose_wc_prev[:3, 3]
    r_curr, c_curr = pose_wc[:3, :3], pose_wc[:3, 3]
    rotvec, _ = cv2.Rodrigues(np.ascontiguousarray(r_prev.T @ r_curr, dtype=np.float64))
    pitch, yaw, roll = (float(v) for v in rotvec.ravel())
    return RelativeMotion(r_curr.T @ (c_curr - c_prev), roll=roll, pitch=pitch, yaw=yaw)


def to_camera(points_w: np.ndarray, pose_cw: np.ndarray) -> np.ndarray:
    """World points (N, 3) in the camera frame of T_camera_world ``pose_cw``."""
    return np.asarray(points_w, dtype=np.float64).reshape(-1, 3) @ pose_cw[:3, :3].T + pose_cw[:3, 3]


def project(points_c: np.ndarray, camera_matrix: np.ndarray) -> np.ndarray:
    """Pinhole projection (N, 2) of camera-frame points with positive depth (no distortion: the keypoints are
    undistorted)."""
    uvw = points_c @ camera_matrix.T
    return uvw[:, :2] / uvw[:, 2:3]


@dataclass(frozen=True)
class Association:
    """Each projected point's nearest keypoint and the distance to it (inf and -1 when there is no keypoint)."""

    keypoint: np.ndarray
    distance: np.ndarray


def nearest_keypoints(tree: cKDTree | None, uv: np.ndarray) -> Association:
    if tree is None or len(uv) == 0:
        return Association(np.full(len(uv), -1, dtype=np.intp), np.full(len(uv), np.inf))
    distance, keypoint = tree.query(uv, k=1)
    return Association(np.asarray(keypoint, dtype=np.intp), np.asarray(distance, dtype=np.float64))


@dataclass(frozen=True)
class SlamFeatures:
    """Tracking and mapping channels of one frame with a pose, plus the inlier keypoint mask for the PSD."""

    matched_inliers: int
    outliers: int
    matches_before_po: int
    motion: RelativeMotion
    avg_mp_depth: float
    var_mp_depth: float
    reprojection_error_px: float
    inlier_keypoints: np.ndarray
    # The pairing itself, for the observability channels (slam_monitor.observability): the matched points in front of
    # the camera that pair with a keypoint within the gate, in the camera (metres), that keypoint (pixels), how
    # far the point projects from it (pixels), and the projection less the keypoint (pixels, N×2).
    paired_points_c: np.ndarray
    paired_keypoints_px: np.ndarray
    paired_distances_px: np.ndarray
    paired_residuals_px: np.ndarray


def slam_features(
    *,
    pose_cw: np.ndarray,
    motion: RelativeMotion,
    matched_inliers: int,
    keypoints: np.ndarray,
    matched_points_w: np.ndarray,
    lost_points_w: np.ndarray,
    camera_matrix: np.ndarray,
    width: int,
    height: int,
    match_gate_px: float,
    min_depth: float,
) -> SlamFeatures:
    """All tracking and mapping channels of a frame that has a pose.

    ``matched_points_w`` are the frame's matched inlier map points; ``lost_points_w`` the map points matched in
    the previous processed frame but not in this one (for the outlier proxy).
    """
    kp = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    # An unbalanced tree without compacted nodes builds in half the time and finds the same nearest neighbours.
    tree = cKDTree(kp, balanced_tree=False, compact_nodes=False) if len(kp) else None
    # Matched and lost points in one pass: moved into the camera, projected, and paired by one tree query (a query
    # call costs about as much again as its points). The matched points come first and stay first.
    matched_w = np.asarray(matched_points_w, dtype=np.float64).reshape(-1, 3)
    lost_w = np.asarray(lost_points_w, dtype=np.float64).reshape(-1, 3)
    points_c = to_camera(np.concatenate([matched_w, lost_w]), pose_cw)
    in_front = points_c[:, 2] > min_depth
    depth = points_c[in_front, 2]
    uv = project(points_c[in_front], camera_matrix)
    is_matched = np.flatnonzero(in_front) < len(matched_w)
    n = int(np.count_nonzero(is_matched))
    depth = depth[:n]
    # A lost point is paired only where it lands in the image.
    paired = is_matched | ((uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height))
    nearest = nearest_keypoints(tree, uv[paired])
    matched = Association(nearest.keypoint[:n], nearest.distance[:n])
    inliers = np.zeros(len(kp), dtype=bool)
    within = matched.distance <= match_gate_px
    inliers[matched.keypoint[within]] = True
    # The keypoints a lost point lands on, each counted once: a mark per keypoint (np.unique sorts, three times the
    # cost).
    reached = np.zeros(len(kp), dtype=bool)
    reached[nearest.keypoint[n:][nearest.distance[n:] <= match_gate_px]] = True
    outliers = int(np.count_nonzero(reached & ~inliers))
    paired_keypoints = kp[matched.keypoint[within]] if tree is not None else np.zeros((0, 2))

    return SlamFeatures(
        matched_inliers=int(matched_inliers),
        outliers=outliers,
        matches_before_po=int(matched_inliers) + outliers,
        motion=motion,
        avg_mp_depth=float(depth.mean()) if len(depth) else float("nan"),
        var_mp_depth=float(depth.var()) if len(depth) else float("nan"),
        reprojection_error_px=float(matched.distance.mean()) if len(depth) and tree is not None else float("nan"),
        inlier_keypoints=inliers,
        paired_points_c=points_c[in_front][:n][within],
        paired_keypoints_px=paired_keypoints,
        paired_distances_px=matched.distance[within],
        paired_residuals_px=uv[:n][within] - paired_keypoints,
    )
