"""On-disk layout of the labelled dataset and its lazy reader.

A dataset folder holds one folder per SLAM run under ``runs/``; a run is one rendered sequence played once
through ORB-SLAM3 + the RTS monitor in one mode (``<sequence>__<mode>__t<trial>``)::

    runs/<run>/run.json      metadata: environment, motion group, trajectory, trial, mode, status, counts
    runs/<run>/rts.npy       (N, T, C) float32   RTS windows (raw units, NaN where a row is missing)
    runs/<run>/psd.npy       (N, K_L, H, W, 3) uint8   PSD windows
    runs/<run>/samples.csv   one row per window: frame index, timestamp, label, status, usable, ...
    runs/<run>/frames.csv    one row per frame: tracking state, label, status, fitted scale

A run folder is written under a temporary name and renamed when complete, so it either exists whole or not at
all. A run whose SLAM session crashed after logging frames is stored like a completed one with status
``partial`` (its logged frames labelled, the error kept); a run that logged no frame has only ``run.json``
(status ``crashed`` and the error). The arrays are plain ``.npy``
files opened with ``mmap_mode="r"``: training reads the samples it asks for, never the whole dataset.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from seesys.errors import SeesysError

RUNS_DIR = "runs"
RUN_JSON = "run.json"
RTS_NPY = "rts.npy"
PSD_NPY = "psd.npy"
SAMPLES_CSV = "samples.csv"
FRAMES_CSV = "frames.csv"
COMPLETED = "completed"
PARTIAL = "partial"  # ORB-SLAM3 crashed or hung after logging frames: those frames are labelled and stored
CRASHED = "crashed"  # nothing stored: the session logged no frame (bad input, a crash at start)
# Runs that have samples.
WITH_SAMPLES = (COMPLETED, PARTIAL)
# Columns of samples.csv besides the run metadata that the reader adds to its index.
SAMPLE_COLUMNS = ("sample", "frame_index", "timestamp", "error_m", "status", "scale", "missing_rts", "usable")


class DatasetError(SeesysError):
    """A dataset folder is missing, incomplete or malformed."""


@dataclass(frozen=True)
class RunInfo:
    """What a run is: its rendered sequence and how it was played."""

    run: str
    sequence: str
    environment: str
    motion_group: str
    trajectory: str
    mode: str
    trial: int
    status: str
    frames: int = 0
    frames_tracked: int = 0
    samples: int = 0
    error: str = ""
    slam_seconds: float = 0.0  # the SLAM session (ORB-SLAM3 + monitor at camera pace)
    seconds: float = 0.0  # the whole run: SLAM session, labelling and windowing


@dataclass(frozen=True)
class RunArrays:
    """The samples of one run, in memory, ready to be written."""

    rts: np.ndarray  # (N, T, C) float32
    psd: np.ndarray  # (N, K_L, H, W, 3) uint8
    samples: pd.DataFrame  # SAMPLE_COLUMNS
    frames: pd.DataFrame  # per-frame labels


def run_name(sequence: str, mode: str, trial: int) -> str:
    return f"{sequence}__{mode}__t{trial}"


def run_folder(root: Path, run: str) -> Path:
    return Path(root) / RUNS_DIR / run


def read_run_info(folder: Path) -> RunInfo | None:
    """The run's record, or None when the run has not been finished (or recorded as crashed)."""
    path = folder / RUN_JSON
    if not path.is_file():
        return None
    try:
        return RunInfo(**json.loads(path.read_text()))
    except (ValueError, TypeError) as e:
        raise DatasetError(f"{path}: not a run record: {e}") from None


def _write_folder(folder: Path, info: RunInfo, arrays: RunArrays | None) -> None:
    """Write the run under a temporary name, then rename it into place (a run is never half there)."""
    partial = folder.with_name(folder.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    if arrays is not None:
        np.save(partial / RTS_NPY, np.ascontiguousarray(arrays.rts, dtype=np.float32))
        np.save(partial / PSD_NPY, np.ascontiguousarray(arrays.psd, dtype=np.uint8))
        arrays.samples.to_csv(partial / SAMPLES_CSV, index=False)
        arrays.frames.to_csv(partial / FRAMES_CSV, index=False)
    (partial / RUN_JSON).write_text(json.dumps(asdict(info), indent=2) + "\n")
    shutil.rmtree(folder, ignore_errors=True)
    os.replace(partial, folder)


def write_run(root: Path, info: RunInfo, arrays: RunArrays) -> Path:
    """Store a completed (or partial) run's samples."""
    if not (len(arrays.rts) == len(arrays.psd) == len(arrays.samples)):
        raise DatasetError(f"run {info.run}: {len(arrays.rts)} RTS windows, {len(arrays.psd)} PSD windows and "
                           f"{len(arrays.samples)} sample rows disagree")
    folder = run_folder(root, info.run)
    _write_folder(folder, info, arrays)
    return folder


def record_crashed_run(root: Path, info: RunInfo) -> Path:
    """Record a run whose SLAM session failed before logging a frame: no samples, the error kept, skipped on
    resume."""
    folder = run_folder(root, info.run)
    _write_folder(folder, info, None)
    return folder


def list_runs(root: Path) -> list[RunInfo]:
    """Every finished run (completed or crashed) of a dataset folder, by name."""
    runs_dir = Path(root) / RUNS_DIR
    if not runs_dir.is_dir():
        raise DatasetError(f"{root} is not a dataset folder (no {RUNS_DIR}/)")
    infos = (read_run_info(folder) for folder in sorted(runs_dir.iterdir()) if folder.is_dir())
    return [info for info in infos if info is not None]


@dataclass(frozen=True)
class Sample:
    """One model input and its label. ``meta`` is the sample's row of :attr:`DatasetReader.index`."""

    rts: np.ndarray
    psd: np.ndarray
    error_m: float
    status: str
    usable: bool
    meta: dict[str, Any]


class DatasetReader:
    """Random access to the samples of one or more dataset folders, reading arrays lazily (memory maps).

    ``index`` is one row per sample (run metadata + ``samples.csv``); ``runs`` restricts it to the named runs
    (e.g. one part of a split); ``usable_only`` keeps the samples that belong to the regression target.
    """

    def __init__(self, roots: Path | list[Path], runs: list[str] | None = None, usable_only: bool = False):
        roots = [Path(r) for r in ([roots] if isinstance(roots, (str, Path)) else roots)]
        tables = []
        self._folders: dict[str, Path] = {}
        for root in roots:
            for info in list_runs(root):
                if info.status not in WITH_SAMPLES or (runs is not None and info.run not in runs):
                    continue
                if info.run in self._folders:
                    raise DatasetError(f"run {info.run} is in two dataset folders ({self._folders[info.run]}, {root})")
                folder = run_folder(root, info.run)
                self._folders[info.run] = folder
                table = pd.read_csv(folder / SAMPLES_CSV)
                missing = set(SAMPLE_COLUMNS) - set(table.columns)
                if missing:
                    raise DatasetError(f"{folder / SAMPLES_CSV}: missing columns {sorted(missing)}")
                meta = asdict(info)
                for key in ("run", "sequence", "environment", "motion_group", "trajectory", "mode", "trial"):
                    table[key] = meta[key]
                tables.append(table)
        if runs is not None:
            unknown = sorted(set(runs) - set(self._folders))
            if unknown:
                raise DatasetError(f"runs not found (or without samples) in {', '.join(map(str, roots))}: "
                                   f"{', '.join(unknown[:5])}{' …' if len(unknown) > 5 else ''}")
        index = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame(columns=list(SAMPLE_COLUMNS))
        if usable_only:
            index = index[index.usable.astype(bool)].reset_index(drop=True)
        self.index = index
        self._arrays: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self.index)

    def _run_arrays(self, run: str) -> tuple[np.ndarray, np.ndarray]:
        if run not in self._arrays:
            folder = self._folders[run]
            try:
                self._arrays[run] = (np.load(folder / RTS_NPY, mmap_mode="r"), np.load(folder / PSD_NPY, mmap_mode="r"))
            except (OSError, ValueError) as e:
                raise DatasetError(f"cannot open the arrays of run {folder}: {e}") from None
        return self._arrays[run]

    def __getitem__(self, i: int) -> Sample:
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} out of range ({len(self)} samples)")
        row = self.index.iloc[i]
        rts, psd = self._run_arrays(row.run)
        k = int(row["sample"])
        return Sample(np.asarray(rts[k]), np.asarray(psd[k]), float(row.error_m), str(row.status), bool(row.usable),
                      row.to_dict())

    def rts_windows(self) -> np.ndarray:
        """Every indexed sample's RTS window, (N, T, C) float32 (small: the PSD windows are what is large)."""
        if not len(self):
            return np.zeros((0, 0, 0), np.float32)
        out = []
        for run, rows in self.index.groupby("run", sort=False).groups.items():
            rts, _ = self._run_arrays(run)
            out.append((rows, rts[self.index.loc[rows, "sample"].to_numpy(int)]))
        windows = np.empty((len(self), *out[0][1].shape[1:]), np.float32)
        for rows, values in out:
            windows[np.asarray(rows)] = values
        return windows

    def frame_labels(self) -> pd.DataFrame:
        """Per-frame labels of the indexed runs (every frame, not only window ends), with run metadata."""
        tables = []
        for run, folder in self._folders.items():
            table = pd.read_csv(folder / FRAMES_CSV)
            info = read_run_info(folder)
            for key in ("run", "environment", "motion_group", "trajectory", "mode", "trial"):
                table[key] = getattr(info, key)
            tables.append(table)
        return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()
