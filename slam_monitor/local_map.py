"""The monitor's own local map: recently matched map points, deduplicated, bounded in age and size.

pyorbslam3 only gives the map points matched in the current frame, but the PSD map-point layer and the outlier
proxy need the map *around* the view too (ORB-SLAM3's local map is not exposed). The monitor therefore keeps
every matched point it has seen in the last ``max_age_frames`` frames. Points are keyed by a voxel of side
``voxel`` (map units): a point seen again, or moved a little by bundle adjustment within its voxel, updates its
entry instead of adding one; at most ``max_points`` are kept, the least recently seen dropped first.
"""

from __future__ import annotations

import numpy as np

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


class LocalMap:
    """Recently seen map points (world coordinates) with the frame index each was last matched in."""

    def __init__(self, voxel: float, max_age_frames: int, max_points: int):
        if voxel <= 0 or max_age_frames < 1 or max_points < 1:
            raise ValueError("local map needs voxel > 0, max_age_frames >= 1 and max_points >= 1")
        self.voxel = voxel
        self.max_age_frames = max_age_frames
        self.max_points = max_points
        self.points = np.zeros((0, 3))
        self.last_seen = np.zeros(0, dtype=np.int64)
        self._keys = np.zeros(0, dtype=np.int64)
        self._previous_update: int | None = None
        self._latest_update: int | None = None

    def __len__(self) -> int:
        return len(self.points)

    def _voxel_keys(self, points: np.ndarray) -> np.ndarray:
        # Voxel coordinates packed 21 bits per axis into one int64 (±2^20 voxels per axis, ample for a local map).
        q = np.clip(np.floor(points / self.voxel).astype(np.int64) + _OFFSET, 0, _MASK)
        return (q[:, 0] << (2 * _BITS)) | (q[:, 1] << _BITS) | q[:, 2]

    def update(self, points_w: np.ndarray, frame_index: int) -> None:
        """Add or refresh the points matched in ``frame_index``; forget old points and enforce the bound."""
        new = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        new = new[np.isfinite(new).all(axis=1)]
        keys = np.concatenate([self._keys, self._voxel_keys(new)])
        points = np.concatenate([self.points, new])
        seen = np.concatenate([self.last_seen, np.full(len(new), frame_index, dtype=np.int64)])
        # Keep the last occurrence of each voxel: new points come after old ones, so they win.
        _, first_in_reversed = np.unique(keys[::-1], return_index=True)
        keep = len(keys) - 1 - first_in_reversed
        keep = keep[seen[keep] > frame_index - self.max_age_frames]
        if len(keep) > self.max_points:
            keep = keep[np.argsort(seen[keep], kind="stable")[-self.max_points:]]
        self._keys, self.points, self.last_seen = keys[keep], points[keep], seen[keep]
        self._previous_update, self._latest_update = self._latest_update, frame_index

    def clear(self) -> None:
        """Forget every point (the map moved under them: loop closure, new map)."""
        self.points = np.zeros((0, 3))
        self.last_seen = np.zeros(0, dtype=np.int64)
        self._keys = np.zeros(0, dtype=np.int64)
        self._previous_update = self._latest_update = None

    def lost_points(self) -> np.ndarray:
        """Points matched in the update before the latest one but not in the latest (tracks just lost)."""
        if self._previous_update is None:
            return np.zeros((0, 3))
        return self.points[self.last_seen == self._previous_update]
