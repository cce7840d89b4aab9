"""Motion-capture trajectories from files: Vicon Nexus / Tracker CSV exports and TUM files.

A Vicon CSV export is a stack of blocks (``Segments``, ``Trajectories``, ...). A block is a title line, a line
with the frame rate, a row naming ``Subject:Segment`` above the first column of each group, a column row
(``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ``), a units row (``,,deg,deg,deg,mm,mm,mm``), data rows (empty fields where
the body was occluded) and a blank line. Segment rotations are helical (axis-angle) components RX RY RZ in
degrees; translations are in millimetres. The time of frame f is ``(f - 1) / rate`` from the start of the
capture: the clock offset to the camera is found by the calibration (``study.mocap.clock``). Occluded frames are
left out.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from seesys.core.errors import SeesysError
from seesys.core.trajectory import Poses
from seesys.io.trajectory_files import read_tum

UNIT_SCALE_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
ANGLE_SCALE_RAD = {"deg": np.pi / 180.0, "rad": 1.0}


class MocapImportError(SeesysError):
    """A motion-capture file is missing, malformed, or lacks the requested body."""


def _block(
    rows: list[list[str]], title: str, path: Path
) -> tuple[float, list[str], list[str], list[str], list[list[str]]]:
    starts = [i for i, row in enumerate(rows) if row and row[0].strip() == title]
    if not starts:
        raise MocapImportError(
            f"{path}: no '{title}' block (blocks: "
            f"{', '.join(r[0] for r in rows if len(r) == 1 and r[0].strip()) or 'none'})"
        )
    i = starts[0]
    try:
        rate = float(rows[i + 1][0])
        names, columns, units = rows[i + 2], rows[i + 3], rows[i + 4]
    except (IndexError, ValueError):
        raise MocapImportError(f"{path}: the '{title}' block has no frame rate and header rows") from None
    data = []
    for row in rows[i + 5 :]:
        if not row or not any(field.strip() for field in row):
            break
        data.append(row)
    return rate, names, columns, units, data


def _group_start(names: list[str], body: str, path: Path) -> int:
    """The first column of the group of ``body`` (``body:segment``, ``subject:body`` or exactly ``body``)."""
    labels = {i: name.strip() for i, name in enumerate(names) if name.strip()}
    for i, label in labels.items():
        subject, _, segment = label.partition(":")
        if body in (label, subject, segment):
            return i
    raise MocapImportError(f"{path}: no body '{body}' (bodies: {', '.join(labels.values()) or 'none'})")


def read_vicon_csv(path: Path, body: str, block: str = "Segments") -> Poses:
    """The poses T_vicon_body of ``body`` in a Vicon CSV export (time from the start of the capture)."""
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise MocapImportError(f"cannot read {path}: {e.strerror}") from None
    rate, names, columns, units, data = _block(rows, block, path)
    start = _group_start(names, body, path)
    wanted = ("RX", "RY", "RZ", "TX", "TY", "TZ")
    group = [c.strip() for c in columns[start : start + 6]]
    if group != list(wanted):
        raise MocapImportError(f"{path}: columns of '{body}' are {group}, expected {list(wanted)}")
    unit_of = [u.strip() for u in units[start : start + 6]]
    try:
        angle = ANGLE_SCALE_RAD[unit_of[0]]
        length = UNIT_SCALE_M[unit_of[3]]
    except KeyError:
        raise MocapImportError(f"{path}: unknown units {unit_of}") from None
    frame_column = [c.strip() for c in columns].index("Frame") if "Frame" in [c.strip() for c in columns] else 0
    frames, values = [], []
    for row in data:
        fields = row[start : start + 6]
        if len(fields) < 6 or any(not f.strip() for f in fields):
            continue  # occluded
        try:
            values.append([float(f) for f in fields])
            frames.append(float(row[frame_column]))
        except ValueError:
            raise MocapImportError(f"{path}: not a number in row {row}") from None
    if not values:
        return Poses.empty()
    array = np.array(values)
    rotations = Rotation.from_rotvec(array[:, :3] * angle)
    return Poses.from_rotations((np.array(frames) - 1.0) / rate, array[:, 3:] * length, rotations)


def read_mocap(path: Path, body: str) -> Poses:
    """A motion-capture trajectory from a Vicon CSV export (``.csv``) or a TUM file (anything else)."""
    path = Path(path)
    return read_vicon_csv(path, body) if path.suffix.lower() == ".csv" else read_tum(path)
