"""Calibrate a study session's motion capture and write it as the session's ground truth.

Reads the session's SLAM trajectory (``trajectory.tum``) and its motion-capture log (``mocap.tum``, written by
the live logger, or an imported file), finds the clock offset and the marker-to-camera transform, and writes
``groundtruth.tum`` (camera poses T_vicon_camera on the camera clock, every mocap sample) and
``calibration.json`` (both results with their residual reports). The session is then a labelled session like
any other: ``seesys dataset label`` and the metrics read its ``groundtruth.tum``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from seesys.io.logfiles import write_json_atomically
from seesys.io.trajectory_files import read_tum, write_tum
from study.config import CalibrationConfig
from study.mocap.clock import ClockOffset, estimate_clock_offset, shift
from study.mocap.handeye import HandEye, calibrate_hand_eye, camera_ground_truth, to_matrix
from study.mocap.importers import read_mocap

MOCAP_LOG = "mocap.tum"
CALIBRATION_JSON = "calibration.json"
GROUND_TRUTH = "groundtruth.tum"
TRAJECTORY = "trajectory.tum"


@dataclass(frozen=True)
class SessionCalibration:
    clock: ClockOffset
    hand_eye: HandEye | None
    marker_camera: np.ndarray
    ground_truth_poses: int


def load_marker_camera(path: Path) -> np.ndarray:
    """X = T_marker_camera from an earlier session's ``calibration.json``."""
    try:
        data = json.loads(Path(path).read_text())["hand_eye"]
        return to_matrix(Rotation.from_quat(data["rotation_xyzw"]), np.asarray(data["translation_m"]))
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SeesysError(f"{path}: not a calibration with a hand-eye transform ({e})") from None


def initial_offset(camera: Poses, markers: Poses) -> float:
    """0 when the two recordings overlap in time (one clock, as with live logging); otherwise the difference of
    their start times (an export whose time starts at 0 with the capture, assumed started within
    ``max_offset_s`` of the camera)."""
    if len(camera) == 0 or len(markers) == 0:
        return 0.0
    overlap = min(camera.timestamps[-1], markers.timestamps[-1]) - max(camera.timestamps[0], markers.timestamps[0])
    return 0.0 if overlap > 0 else float(camera.timestamps[0] - markers.timestamps[0])


def calibrate_session(
    folder: Path,
    cfg: CalibrationConfig,
    body: str,
    mocap: Path | None = None,
    marker_camera_from: Path | None = None,
    monocular: bool = False,
    overwrite: bool = False,
    offset_guess_s: float | None = None,
) -> SessionCalibration:
    """Calibrate ``folder``'s mocap against its SLAM trajectory and write ``groundtruth.tum`` and
    ``calibration.json``. A monocular session needs ``marker_camera_from`` (its scale is not metric). An existing
    ``groundtruth.tum`` is kept unless ``overwrite``. The offset is searched within ``max_offset_s`` of
    ``offset_guess_s`` (default :func:`initial_offset`)."""
    folder = Path(folder)
    target = folder / GROUND_TRUTH
    if target.exists() and not overwrite:
        raise SeesysError(f"{target} exists; pass --overwrite to replace it with the calibrated mocap")
    if monocular and marker_camera_from is None:
        raise SeesysError(
            "a monocular trajectory has no metric scale for the hand-eye translation: pass the "
            "calibration.json of an RGB-D session of the same rig (--hand-eye-from)"
        )
    camera = read_tum(folder / TRAJECTORY)
    markers = read_mocap(mocap or folder / MOCAP_LOG, body).sorted_unique()
    guess = initial_offset(camera, markers) if offset_guess_s is None else offset_guess_s
    found = estimate_clock_offset(camera, shift(markers, guess), cfg)
    clock = dataclasses.replace(found, offset_s=guess + found.offset_s, searched_from_s=guess)
    if marker_camera_from is not None:
        hand_eye, x = None, load_marker_camera(marker_camera_from)
    else:
        hand_eye = calibrate_hand_eye(camera, shift(markers, clock.offset_s), cfg)
        x = hand_eye.matrix
    truth = camera_ground_truth(markers, x, clock.offset_s)
    temporary = target.with_name(target.name + ".tmp")
    write_tum(temporary, truth)
    os.replace(temporary, target)
    report = {
        "clock": clock.as_dict(),
        "hand_eye": hand_eye.as_dict()
        if hand_eye
        else {
            "rotation_xyzw": Rotation.from_matrix(x[:3, :3]).as_quat().tolist(),
            "translation_m": x[:3, 3].tolist(),
            "from": str(marker_camera_from),
        },
        "mocap": str(mocap or folder / MOCAP_LOG),
        "body": body,
        "ground_truth_poses": len(truth),
    }
    write_json_atomically(folder / CALIBRATION_JSON, report)
    return SessionCalibration(clock, hand_eye, x, len(truth))


def format_calibration(result: SessionCalibration) -> str:
    c = result.clock
    lines = [
        f"clock offset: {c.offset_s * 1e3:.2f} ms (t_camera = t_mocap + offset); correlation "
        f"{c.peak_correlation:.4f}, residual {c.residual_rms_deg_s:.2f} deg/s RMS over {c.samples} samples"
    ]
    h = result.hand_eye
    x = result.marker_camera
    angle = np.degrees(Rotation.from_matrix(x[:3, :3]).magnitude())
    lines.append(
        f"marker->camera: t = [{', '.join(f'{v * 1e3:.1f}' for v in x[:3, 3])}] mm, rotation {angle:.2f} deg"
        + ("" if h else " (from an earlier calibration)")
    )
    if h:
        lines.append(
            f"hand-eye residuals over {h.motions} motions ({h.stations} stations): rotation median "
            f"{h.residual_rotation_deg_median:.3f} deg (p90 {h.residual_rotation_deg_p90:.3f}), "
            f"translation median {h.residual_translation_m_median * 1e3:.2f} mm "
            f"(p90 {h.residual_translation_m_p90 * 1e3:.2f})"
        )
    lines.append(f"ground truth: {result.ground_truth_poses} camera poses")
    return "\n".join(lines)
