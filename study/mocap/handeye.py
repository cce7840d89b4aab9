"""The marker-to-camera transform (hand-eye calibration) and the calibrated ground truth.

Motion capture gives T_vicon_marker, SLAM gives T_world_camera; camera and markers are rigidly joined by the
unknown X = T_marker_camera, so every motion satisfies A X = X B with A = T_marker_i⁻¹ T_marker_j and
B = T_camera_i⁻¹ T_camera_j. X is solved by Park and Martin's method (the one OpenCV's ``calibrateHandEye``
calls ``CALIB_HAND_EYE_PARK``): the rotation aligns the rotation vectors of the B motions to those of the A
motions (scipy's ``Rotation.align_vectors``, Kabsch), the translation is the least-squares solution of
(R_A − I) t_X = R_X t_B − t_A. It is written here because the Python package of OpenCV 5.0.0.93 (the pinned
release) does not expose ``calibrateHandEye``; OpenCV has fixed the binding for its next release.

The poses used are stations every ``station_step_s`` along the SLAM trajectory, with the mocap pose interpolated
at the same instant (after the clock offset); the motions are all pairs of stations at most ``max_pair_span_s``
apart (long pairs would carry SLAM drift). Translation needs a metric SLAM scale (RGB-D); a monocular session
reuses the X of an RGB-D calibration of the same rig.

The residual report: over the station pairs, the rotation (degrees) and translation (metres) by which
A X and X B differ (median and 90th percentile).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.trajectory import Poses
from study.config import CalibrationConfig
from study.mocap.clock import CalibrationError, interpolate_poses


@dataclass(frozen=True)
class HandEye:
    """X = T_marker_camera and its residuals."""

    rotation_xyzw: list[float]
    translation_m: list[float]
    stations: int
    motions: int
    residual_rotation_deg_median: float
    residual_rotation_deg_p90: float
    residual_translation_m_median: float
    residual_translation_m_p90: float

    @property
    def matrix(self) -> np.ndarray:
        return to_matrix(Rotation.from_quat(self.rotation_xyzw), np.asarray(self.translation_m))

    def as_dict(self) -> dict:
        return asdict(self)


def to_matrix(rotation: Rotation, translation: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation.as_matrix()
    m[:3, 3] = translation
    return m


def stations(camera: Poses, mocap_on_camera_clock: Poses, cfg: CalibrationConfig) -> tuple[Poses, Poses]:
    """Camera poses every ``station_step_s`` inside the mocap's span, and the mocap poses at the same times."""
    camera = camera.sorted_unique()
    inside = (camera.timestamps >= mocap_on_camera_clock.timestamps[0]) & (
        camera.timestamps <= mocap_on_camera_clock.timestamps[-1]
    )
    camera = camera.take(inside)
    picked, last = [], -np.inf
    for i, t in enumerate(camera.timestamps):
        if t - last >= cfg.station_step_s:
            picked.append(i)
            last = t
    picked = picked[: cfg.max_stations]
    if len(picked) < 3:
        raise CalibrationError(f"only {len(picked)} stations where SLAM and mocap overlap; hand-eye needs 3 or more")
    chosen = camera.take(np.array(picked))
    return chosen, interpolate_poses(mocap_on_camera_clock, chosen.timestamps)


def calibrate_hand_eye(camera: Poses, mocap_on_camera_clock: Poses, cfg: CalibrationConfig) -> HandEye:
    """X = T_marker_camera from SLAM poses and time-aligned mocap poses (see the module docstring)."""
    cam, moc = stations(camera, mocap_on_camera_clock, cfg)
    t_world_cam, t_vicon_marker = cam.matrices, moc.matrices
    i, j = np.triu_indices(len(cam), k=1)
    keep = cam.timestamps[j] - cam.timestamps[i] <= cfg.max_pair_span_s
    i, j = i[keep], j[keep]
    a = np.linalg.inv(t_vicon_marker[i]) @ t_vicon_marker[j]
    b = np.linalg.inv(t_world_cam[i]) @ t_world_cam[j]
    alpha = Rotation.from_matrix(a[:, :3, :3]).as_rotvec()
    beta = Rotation.from_matrix(b[:, :3, :3]).as_rotvec()
    if np.linalg.matrix_rank(alpha, tol=1e-3) < 2:
        raise CalibrationError(
            "the device rotated about one axis only: the hand-eye rotation is undetermined "
            "(turn it about at least two axes)"
        )
    rotation, _ = Rotation.align_vectors(alpha, beta)
    r_x = rotation.as_matrix()
    lhs = (a[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (b[:, :3, 3] @ r_x.T - a[:, :3, 3]).reshape(-1)
    t_x = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    x = to_matrix(rotation, t_x)
    ax, xb = a @ x, x @ b
    rot_err = np.degrees(Rotation.from_matrix(np.transpose(ax[:, :3, :3], (0, 2, 1)) @ xb[:, :3, :3]).magnitude())
    trans_err = np.linalg.norm(ax[:, :3, 3] - xb[:, :3, 3], axis=1)
    return HandEye(
        rotation.as_quat().tolist(),
        t_x.tolist(),
        len(cam),
        len(i),
        float(np.median(rot_err)),
        float(np.percentile(rot_err, 90)),
        float(np.median(trans_err)),
        float(np.percentile(trans_err, 90)),
    )


def camera_ground_truth(mocap: Poses, marker_camera: np.ndarray, offset_s: float) -> Poses:
    """The mocap trajectory as camera poses on the camera clock: T_vicon_camera = T_vicon_marker X at
    ``t_mocap + offset_s``."""
    m = mocap.matrices @ marker_camera
    return Poses.from_rotations(mocap.timestamps + offset_s, m[:, :3, 3], Rotation.from_matrix(m[:, :3, :3]))
