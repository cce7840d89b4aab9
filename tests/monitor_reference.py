"""Straightforward reference computations of the RTS monitor's optimised channels, and the sample's recorded monitor
inputs to hold them to (tests/test_monitor_reference.py, tests/test_monitor_local_map.py)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from slam_monitor.monitor import MonitorInput
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.replay import record_inputs

SAMPLE = Path(__file__).resolve().parent.parent / "data" / "sample"


@functools.cache
def sample_inputs() -> tuple[MonitorInput, ...]:
    """What real ORB-SLAM3 (RGB-D) hands the monitor for each frame of the embedded sample; tracked once per test
    process."""
    return tuple(record_inputs(f"tum:{SAMPLE}", SlamMode.RGBD))


class ReferenceLocalMap:
    """The local map merged frame by frame: every update concatenates, deduplicates by voxel with np.unique and
    sorts by last sighting to enforce the bound (the monitor's map before it kept frames aside)."""

    def __init__(self, voxel: float, max_age_frames: int, max_points: int):
        self.voxel, self.max_age_frames, self.max_points = voxel, max_age_frames, max_points
        self.clear()

    def clear(self) -> None:
        self.points, self.last_seen, self.keys = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        self.previous_update = self.latest_update = None

    def update(self, points_w: np.ndarray, frame_index: int) -> None:
        new = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        new = new[np.isfinite(new).all(axis=1)]
        q = np.clip(np.floor(new / self.voxel).astype(np.int64) + (1 << 20), 0, (1 << 21) - 1)
        keys = np.concatenate([self.keys, (q[:, 0] << 42) | (q[:, 1] << 21) | q[:, 2]])
        points = np.concatenate([self.points, new])
        seen = np.concatenate([self.last_seen, np.full(len(new), frame_index, dtype=np.int64)])
        _, first_in_reversed = np.unique(keys[::-1], return_index=True)
        keep = len(keys) - 1 - first_in_reversed
        keep = keep[seen[keep] > frame_index - self.max_age_frames]
        if len(keep) > self.max_points:
            keep = keep[np.argsort(seen[keep], kind="stable")[-self.max_points :]]
        self.keys, self.points, self.last_seen = keys[keep], points[keep], seen[keep]
        self.previous_update, self.latest_update = self.latest_update, frame_index

    def lost_points(self) -> np.ndarray:
        if self.previous_update is None:
            return np.zeros((0, 3))
        return self.points[self.last_seen == self.previous_update]


def same_rows(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two (N, K) arrays hold the same rows, in any order."""
    return a.shape == b.shape and np.array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])


def nearest_brute_force(uv: np.ndarray, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each position's nearest keypoint and its distance, from the full distance matrix."""
    distance = np.linalg.norm(uv[:, None, :] - keypoints[None, :, :], axis=2)
    nearest = np.argmin(distance, axis=1)
    return nearest, distance[np.arange(len(uv)), nearest]


def laplacian_variance(gray: np.ndarray) -> float:
    """Variance of the 3×3 Laplacian in float64, borders reflected without repeating the edge pixel."""
    g = np.pad(gray.astype(np.float64), 1, mode="reflect")
    lap = g[:-2, 1:-1] + g[2:, 1:-1] + g[1:-1, :-2] + g[1:-1, 2:] - 4.0 * g[1:-1, 1:-1]
    return float(lap.var())


def entropy_bits(gray: np.ndarray) -> float:
    """Shannon entropy of the whole frame's 256-bin histogram."""
    p = np.bincount(gray.ravel(), minlength=256) / gray.size
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())
