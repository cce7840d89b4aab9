"""The ``oracle`` condition's reading: the true pose error, as the label defines it, of the pair ending at a frame.

The tracker's poses of the current tracked stretch and the renderer's ground truth at the same frames go through
the label's own function (``seesys.core.labels.stretch_errors``), so the oracle hears the number the model is
trained to estimate. RGB-D needs only the last ``delta_frames`` + 1 poses (a rigid alignment leaves relative poses as
they are); monocular fits the scale on the stretch so far, which is the label's scale once the stretch has ended
(the label fits it on the whole stretch, which no causal reading can).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from seesys.core.labels import stretch_errors
from seesys.core.trajectory import Poses


class TrueError:
    """The error of the pair (k − Δ, k) at each tracked frame k, from poses and ground truth fed frame by frame."""

    def __init__(self, monocular: bool, delta_frames: int):
        self._monocular = monocular
        self._delta = delta_frames
        keep = None if monocular else delta_frames + 1
        self._times: deque[float] = deque(maxlen=keep)
        self._estimate: deque[np.ndarray] = deque(maxlen=keep)  # T_world_camera matrices
        self._truth: deque[np.ndarray] = deque(maxlen=keep)  # positions and quaternions

    def update(self, timestamp: float, pose_wc: np.ndarray | None, truth_xyz_quat: np.ndarray) -> float | None:
        """Add a frame (``pose_wc``: the tracker's T_world_camera, None when it was not tracked, which ends the
        stretch; ``truth_xyz_quat``: the ground truth's position and x y z w quaternion); the error of the pair ending
        here, or None when the stretch has no such pair yet."""
        if pose_wc is None:
            self._times.clear()
            self._estimate.clear()
            self._truth.clear()
            return None
        self._times.append(timestamp)
        self._estimate.append(np.array(pose_wc, float))
        self._truth.append(np.asarray(truth_xyz_quat, float))
        if len(self._times) <= self._delta:
            return None
        times, truth = np.array(self._times), np.array(self._truth)
        errors = stretch_errors(
            Poses.from_matrices(times, np.array(self._estimate)),
            Poses(times, truth[:, :3], truth[:, 3:]),
            self._monocular,
            self._delta,
        ).errors_m
        return float(errors[-1]) if errors.size else None
