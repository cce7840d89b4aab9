"""TUM and EuRoC trajectory files: every trajectory SEESys reads or writes goes through :func:`read_tum` /
:func:`write_tum` (the format: :mod:`seesys.core.trajectory`)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from seesys.core.trajectory import TUM_HEADER, Poses, TrajectoryError, tum_line


def _read_table(path: Path, delimiter: str | None, min_columns: int, layout: str) -> np.ndarray:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # numpy warns on a file of comments only
            data = np.loadtxt(path, comments="#", delimiter=delimiter, ndmin=2)
    except FileNotFoundError:
        raise TrajectoryError(f"trajectory file not found: {path}") from None
    except (OSError, ValueError) as e:
        raise TrajectoryError(f"{path}: not a trajectory ({layout}): {e}") from None
    if data.size and data.shape[1] < min_columns:
        raise TrajectoryError(f"{path}: expected {min_columns} columns ({layout}), found {data.shape[1]}")
    if data.size and not np.all(np.isfinite(data[:, :min_columns])):
        raise TrajectoryError(f"{path}: holds non-finite numbers")
    return data


def read_tum(path: Path) -> Poses:
    """The poses of a TUM file, in file order; an empty file (or one of comments only) gives no poses."""
    data = _read_table(Path(path), None, 8, "t tx ty tz qx qy qz qw")
    if data.size == 0:
        return Poses.empty()
    if data.shape[1] != 8:
        raise TrajectoryError(f"{path}: expected 8 columns (t tx ty tz qx qy qz qw), found {data.shape[1]}")
    return Poses(data[:, 0], data[:, 1:4], data[:, 4:8])


def read_euroc_groundtruth(path: Path) -> Poses:
    """A EuRoC ground-truth CSV, ``t[ns], px, py, pz, qw, qx, qy, qz, ...`` (further columns ignored)."""
    data = _read_table(Path(path), ",", 8, "t[ns], px, py, pz, qw, qx, qy, qz")
    if data.size == 0:
        return Poses.empty()
    return Poses(data[:, 0] * 1e-9, data[:, 1:4], data[:, [5, 6, 7, 4]])


def write_tum(path: Path, poses: Poses) -> None:
    """Write ``poses`` as a TUM file with a header comment."""
    with Path(path).open("w") as out:
        out.write(TUM_HEADER + "\n")
        for t, p, q in zip(poses.timestamps, poses.positions, poses.quaternions_xyzw):
            out.write(tum_line(t, p, q))
