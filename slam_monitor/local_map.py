"""The monitor's own local map: recently matched map points, deduplicated, bounded in age and size.

pyorbslam3 only gives the map points matched in the current frame, but the PSD map-point layer and the outlier
proxy need the map *around* the view too (ORB-SLAM3's local map is not exposed). The monitor therefore keeps
every matched point it has seen in the last ``max_age_frames`` frames. Points are keyed by a voxel of side
``voxel`` (map units): a point seen again, or moved a little by bundle adjustment within its voxel, updates its
entry instead of adding one; at most ``max_points`` are kept, the least recently seen dropped first (the lower
voxel keys first among points last seen in the same frame).

Only the PSD reads the whole map, on the frames that end a model window; the outlier proxy needs only the points
of the update before the latest. So :meth:`LocalMap.update` keeps each frame's points aside and works out the lost
points from the last two updates alone, and the map takes the kept frames in one merge when :attr:`points` or
:attr:`last_seen` is next read. The merge gives the map that merging every frame as it came would have given: a
voxel's entry is its latest point either way, and a point dropped for the size bound on the way ranks below the
``max_points`` entries that stay at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


@dataclass(frozen=True)
class _Update:
    """One frame's points, one per voxel (the frame's last point in it), sorted by voxel key."""

    keys: np.ndarray
    points: np.ndarray
    frame_index: int


class LocalMap:
    """Recently seen map points (world coordinates) with the frame index each was last matched in."""

    # Set by clear(), which also forgets them when the map moves.
    _keys: np.ndarray
    _points: np.ndarray
    _seen: np.ndarray
    _pending: list[_Update]
    _latest: _Update | None
    _lost: np.ndarray

    def __init__(self, voxel: float, max_age_frames: int, max_points: int):
        if voxel <= 0 or max_age_frames < 1 or max_points < 1:
            raise ValueError("local map needs voxel > 0, max_age_frames >= 1 and max_points >= 1")
        self.voxel = voxel
        self.max_age_frames = max_age_frames
        self.max_points = max_points
        self.clear()

    def __len__(self) -> int:
        return len(self.points)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) world positions, one per voxel (its latest point), sorted by voxel key."""
        self._merge()
        return self._points

    @property
    def last_seen(self) -> np.ndarray:
        """(N,) the frame index each entry of :attr:`points` was last matched in."""
        self._merge()
        return self._seen

    def _voxel_keys(self, points: np.ndarray) -> np.ndarray:
        # Voxel coordinates packed 21 bits per axis into one int64 (±2^20 voxels per axis, ample for a local map).
        q = np.minimum(np.maximum(np.floor(points / self.voxel).astype(np.int64) + _OFFSET, 0), _MASK)
        return (q[:, 0] << (2 * _BITS)) | (q[:, 1] << _BITS) | q[:, 2]

    def update(self, points_w: np.ndarray, frame_index: int) -> None:
        """Add or refresh the points matched in ``frame_index`` (frame indices increasing); forget old points and
        enforce the bound (both at the next read of the map)."""
        new = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        new = new[np.isfinite(new).all(axis=1)]
        # The last of the frame's points in each voxel wins: first in the reversed order.
        keys, last_in_reversed = np.unique(self._voxel_keys(new)[::-1], return_index=True)
        update = _Update(keys, new[len(new) - 1 - last_in_reversed], frame_index)
        self._lost = self._lost_since(self._latest, update)
        self._latest = update
        self._pending.append(update)

    def _lost_since(self, previous: _Update | None, update: _Update) -> np.ndarray:
        """The entries ``previous`` left in the map that ``update`` did not refresh, as the map would hold them
        after ``update``: gone when too old, and the lower keys gone first when the two updates alone exceed the
        size bound (every older entry goes before them)."""
        if previous is None or previous.frame_index <= update.frame_index - self.max_age_frames:
            return np.zeros((0, 3))
        # Of a previous update larger than the bound, the map kept the higher keys.
        keys, points = previous.keys[-self.max_points :], previous.points[-self.max_points :]
        # Both key lists are sorted: a binary search finds which of the previous voxels the update refreshed.
        at = np.minimum(np.searchsorted(update.keys, keys), max(len(update.keys) - 1, 0))
        lost = update.keys[at] != keys if len(update.keys) else np.ones(len(keys), dtype=bool)
        excess = len(update.keys) + int(np.count_nonzero(lost)) - self.max_points
        if excess > 0:
            lost[np.flatnonzero(lost)[:excess]] = False
        return points[lost]

    def _merge(self) -> None:
        """Merge the kept updates into the map, in frame order, then forget old points and enforce the bound."""
        if not self._pending:
            return
        keys = np.concatenate([self._keys] + [u.keys for u in self._pending])
        points = np.concatenate([self._points] + [u.points for u in self._pending])
        seen = np.concatenate([self._seen] + [np.full(len(u.keys), u.frame_index, np.int64) for u in self._pending])
        latest = self._pending[-1].frame_index
        self._pending = []
        # Keep the last occurrence of each voxel: later updates come after earlier ones, so they win.
        self._keys, first_in_reversed = np.unique(keys[::-1], return_index=True)
        keep = len(keys) - 1 - first_in_reversed
        points, seen = points[keep], seen[keep]
        alive = seen > latest - self.max_age_frames
        excess = int(np.count_nonzero(alive)) - self.max_points
        if excess > 0:
            alive &= ~self._least_recent(seen, alive, excess, latest)
        self._keys, self._points, self._seen = self._keys[alive], points[alive], seen[alive]

    def _least_recent(self, seen: np.ndarray, alive: np.ndarray, count: int, latest: int) -> np.ndarray:
        """The ``count`` live entries seen least recently, the lower keys first among entries seen in the same
        frame (what a stable sort by frame of the key-ordered map gives), from a count per frame of the window."""
        oldest = latest - self.max_age_frames + 1
        per_frame = np.bincount(seen[alive] - oldest, minlength=self.max_age_frames)
        cutoff = oldest + int(np.searchsorted(np.cumsum(per_frame), count))  # the frame where the count ends
        drop = alive & (seen < cutoff)
        at_cutoff = np.flatnonzero(alive & (seen == cutoff))
        drop[at_cutoff[: count - int(np.count_nonzero(drop))]] = True
        return drop

    def clear(self) -> None:
        """Forget every point (the map moved under them: loop closure, new map)."""
        self._keys = np.zeros(0, dtype=np.int64)
        self._points = np.zeros((0, 3))
        self._seen = np.zeros(0, dtype=np.int64)
        self._pending = []
        self._latest = None
        self._lost = np.zeros((0, 3))

    def lost_points(self) -> np.ndarray:
        """Points matched in the update before the latest one but not in the latest (tracks just lost)."""
        return self._lost
