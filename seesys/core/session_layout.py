"""The names and records of a session folder, the one definition shared by the device that writes it and every
part that reads it (docs/device.md, docs/advisory.md).

- ``session.json``: the device's manifest; ``frames.csv``: one row per frame given to SLAM (:data:`FRAMES_HEADER`);
  ``trajectory.tum`` / ``groundtruth.tum``: estimated and true poses; ``orbslam3.yaml`` / ``orbslam3.log``: the
  SLAM settings and console;
- ``pose_covariance.csv``: each tracked frame's predicted pose covariance (:data:`POSE_COVARIANCE_COLUMNS`);
- ``estimates.csv``: the estimates the device received, with where their time went (:data:`ESTIMATE_COLUMNS`);
- ``advisory.csv``, ``playback.csv``, ``advisory_events.csv``: the advisory's generated buffers, played buffers and
  events.
"""

import numpy as np

from seesys.core.upper_triangle import symmetric_from_upper, upper_triangle

MANIFEST = "session.json"
FRAMES_CSV = "frames.csv"
TRAJECTORY = "trajectory.tum"
GROUND_TRUTH = "groundtruth.tum"
SETTINGS = "orbslam3.yaml"
SLAM_LOG = "orbslam3.log"
FRAMES_HEADER = "frame_index,timestamp,state,tracked_points,track_ms"

POSE_COVARIANCE_CSV = "pose_covariance.csv"
# The upper triangle, row by row, of the 6×6 covariance in ROS's order: position x, y, z (m), then rotation about
# the world's fixed x, y, z axes (rad); cov_ij is row i, column j.
POSE_COVARIANCE_COLUMNS = ("frame_index", "timestamp", *(f"cov_{i}{j}" for i, j in zip(*np.triu_indices(6))))


def covariance_row(covariance: np.ndarray) -> list[float]:
    """A 6×6 covariance's upper triangle as :data:`POSE_COVARIANCE_COLUMNS` stores it."""
    return upper_triangle(covariance).tolist()


def covariance_matrices(rows: np.ndarray) -> np.ndarray:
    """(N, 21) upper triangles → (N, 6, 6) symmetric covariances."""
    return symmetric_from_upper(np.asarray(rows, np.float64).reshape(-1, len(POSE_COVARIANCE_COLUMNS) - 2))


ESTIMATES_CSV = "estimates.csv"
ESTIMATE_COLUMNS = (
    "frame_index",
    "timestamp",
    "error_m",
    "model_version",
    "server_ms",
    "received_unix",
    "tracking_ms",
    "preprocess_ms",
    "transmit_inference_ms",
    "end_to_end_ms",
    "capture_to_estimate_ms",
)

ADVISORY_CSV = "advisory.csv"
PLAYBACK_CSV = "playback.csv"
EVENTS_CSV = "advisory_events.csv"
# pulses_from: the rule that gave n_pulses ("head", "estimate", "rotation"; empty without live input).
ADVISORY_COLUMNS = (
    "wall_time",
    "time_mono",
    "condition",
    "status",
    "trigger",
    "input_value",
    "n_pulses",
    "played_pulses",
    "buffer_id",
    "arrival_mono",
    "play_at_mono",
    "pulses_from",
)
PLAYBACK_COLUMNS = (
    "wall_time",
    "buffer_id",
    "time_mono",
    "trigger",
    "n_pulses",
    "played_pulses",
    "arrival_mono",
    "received_mono",
    "play_at_mono",
    "dac_mono",
    "stream_sample",
)
EVENT_COLUMNS = ("wall_time", "time_mono", "process", "event", "detail")
