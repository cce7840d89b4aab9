"""A symmetric matrix as its upper triangle, row by row: how covariances travel on the wire (the stream, the
estimator's envelope) and sit in session files (``pose_covariance.csv``)."""

from __future__ import annotations

import math
from functools import cache

import numpy as np


@cache
def _triangle(size: int) -> tuple[np.ndarray, np.ndarray]:
    # np.triu_indices builds a mask of the whole matrix each call: six times the cost of the indexing it serves, twice
    # a frame on a device (the covariance log and the stream).
    rows, columns = np.triu_indices(size)
    rows.flags.writeable = columns.flags.writeable = False  # shared by every call
    return rows, columns


def upper_triangle(matrix: np.ndarray) -> np.ndarray:
    """The upper triangle of a square matrix (or of each of a stack), row by row: (..., n, n) → (..., n(n+1)/2)."""
    m = np.asarray(matrix, np.float64)
    return m[..., *_triangle(m.shape[-1])]


def symmetric_from_upper(values: np.ndarray) -> np.ndarray:
    """The symmetric matrix (or stack of them) whose upper triangle, row by row, is ``values``: (..., n(n+1)/2) →
    (..., n, n). Raises ValueError when the last axis is not a triangle's length."""
    v = np.asarray(values, np.float64)
    size = (math.isqrt(8 * v.shape[-1] + 1) - 1) // 2
    if size * (size + 1) // 2 != v.shape[-1]:
        raise ValueError(f"{v.shape[-1]} values are no square matrix's upper triangle")
    rows, columns = _triangle(size)
    m = np.zeros((*v.shape[:-1], size, size))
    m[..., rows, columns] = v
    m[..., columns, rows] = v
    return m


def symmetric_3x3(xx: float, xy: float, xz: float, yy: float, yz: float, zz: float) -> np.ndarray:
    """The symmetric 3×3 matrix of these six values (its upper triangle, row by row), float64: what
    :func:`symmetric_from_upper` gives for one triangle, in about a third of its time (a receiver builds one on every
    frame that ends a window)."""
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], dtype=np.float64)
