"""On-disk layout of the labelled dataset and its lazy reader.

A dataset folder holds one folder per SLAM run under ``runs/``; a run is one rendered sequence played once
through ORB-SLAM3 + the RTS monitor in one mode (``<sequence>__<mode>__t<trial>``). Each RTS row and each PSD
matrix the monitor logged is stored once; a sample (a model window) is a list of rows into them::

    runs/<run>/run.json             metadata: format version, environment, motion group, trajectory, trial, mode,
                                    status, counts
    runs/<run>/rts.npy              (R, C) float32   the monitor's RTS rows, one per logged frame (raw units)
    runs/<run>/rts_frames.npy       (R,) int64       frame index of each RTS row
    runs/<run>/psd.npy              (P, H, W, 3) uint8   the logged PSD matrices, in frame order
    runs/<run>/psd_frames.npy       (P,) int64       frame index of each PSD matrix
    runs/<run>/sample_rts_rows.npy  (N, T) int32     per sample, the rows of rts.npy of its window (−1: not logged)
    runs/<run>/sample_psd_rows.npy  (N, K_L) int32   per sample, the rows of psd.npy of its window
    runs/<run>/samples.csv          one row per window: frame index, timestamp, label, status, usable, ...
    runs/<run>/frames.csv           one row per frame: tracking state, label, status, fitted scale

Windows overlap (a dataset build forms one on every frame), so storing each PSD once instead of K_L copies per
sample is what keeps a run of 900 samples at about 33 MB. The reader gives a sample as before: its RTS window
(T, C) with NaN rows for frames the monitor did not log, and its PSD window (K_L, H, W, 3).

A run folder is written under a temporary name and renamed when complete, so it either exists whole or not at
all. A run whose SLAM session crashed after logging frames is stored like a completed one with status
``partial`` (its logged frames labelled, the error kept); a run that logged no frame has only ``run.json``
(status ``crashed`` and the error). The arrays are plain ``.npy``
files opened with ``mmap_mode="r"``: training reads the samples it asks for, never the whole dataset.

``run.json`` carries :data:`FORMAT_VERSION`; a run of another format (format 1 stored a copy of every window per
sample) is refused with a :class:`DatasetError` that says to rebuild it.
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

from seesys.core import rts_schema
from seesys.core.camera_normalisation import BEFORE_NORMALISATION
from seesys.core.device_settings import MONO
from seesys.core.errors import SeesysError
from seesys.core.labels import BEFORE_MONO_ALIGNMENT, MONO_ALIGNMENT, LabelConfig
from seesys.io.core_settings import load_label_config

RUNS_DIR = "runs"
RUN_JSON = "run.json"
# The layout of a run folder; bumped whenever it changes, so that a reader never misreads an older run.
FORMAT_VERSION = 2
FORMAT_KEY = "format_version"
RTS_NPY = "rts.npy"
RTS_FRAMES_NPY = "rts_frames.npy"
PSD_NPY = "psd.npy"
PSD_FRAMES_NPY = "psd_frames.npy"
SAMPLE_RTS_ROWS_NPY = "sample_rts_rows.npy"
SAMPLE_PSD_ROWS_NPY = "sample_psd_rows.npy"
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
    camera_model: str = "ideal"  # the renderer's camera model of the sequence (configs/synth.toml)
    # The camera normalisation version of its features (seesys.core.camera_normalisation); a run.json without one
    # was built before camera normalisation.
    camera_normalisation: int = BEFORE_NORMALISATION


@dataclass(frozen=True)
class RunArrays:
    """The samples of one run, in memory, ready to be written."""

    rts: np.ndarray  # (R, C) float32, one row per logged frame
    rts_frames: np.ndarray  # (R,) frame index of each row
    psd: np.ndarray  # (P, H, W, 3) uint8, one matrix per logged PSD
    psd_frames: np.ndarray  # (P,) frame index of each matrix
    sample_rts_rows: np.ndarray  # (N, T) rows of ``rts`` per sample, −1 where the frame was not logged
    sample_psd_rows: np.ndarray  # (N, K_L) rows of ``psd`` per sample
    samples: pd.DataFrame  # SAMPLE_COLUMNS
    frames: pd.DataFrame  # per-frame labels

    def check(self, run: str) -> None:
        """Raise :class:`DatasetError` when the arrays do not describe one consistent run."""
        n = len(self.samples)
        problems = []
        if len(self.rts) != len(self.rts_frames) or len(self.psd) != len(self.psd_frames):
            problems.append(
                f"{len(self.rts)} RTS rows for {len(self.rts_frames)} frame indices, "
                f"{len(self.psd)} PSD matrices for {len(self.psd_frames)}"
            )
        if len(self.sample_rts_rows) != n or len(self.sample_psd_rows) != n:
            problems.append(
                f"{len(self.sample_rts_rows)} RTS and {len(self.sample_psd_rows)} PSD windows for {n} sample rows"
            )
        if n and (
            self.sample_rts_rows.max() >= len(self.rts)
            or self.sample_psd_rows.max() >= len(self.psd)
            or self.sample_rts_rows.min() < -1
            or self.sample_psd_rows.min() < 0
        ):
            problems.append("a window points outside the stored rows")
        if problems:
            raise DatasetError(f"run {run}: {'; '.join(problems)}")


#: The dataset folder's description (:mod:`estimator.dataset.build` writes it).
DATASET_JSON = "dataset.json"


def label_definition(label_config: LabelConfig) -> dict[str, Any]:
    """What a dataset's labels are, as ``dataset.json`` records it: the label's settings and the monocular
    alignment's name."""
    return {**asdict(label_config), "mono_alignment": MONO_ALIGNMENT}


def check_label_definition(root: Path, modes: set[str]) -> None:
    """Refuse a dataset folder whose labels of runs in ``modes`` were made under another definition than this
    installation's (``dataset.json``, written by the builder): a model trained on them would record this
    installation's definition in its compatibility record, not theirs. The RGB-D label is its settings; a monocular
    one also its alignment (a folder that names none was labelled with a Sim(3) scale on a sliding window). A
    folder without ``dataset.json`` records nothing to check. DatasetError naming the folder and what differs."""
    path = root / DATASET_JSON
    if not modes or not path.is_file():
        return
    recorded = json.loads(path.read_text()).get("labels", {})
    here = label_definition(load_label_config())
    keys = [k for k in here if k != "mono_alignment" or MONO in modes]
    defaults = {"mono_alignment": BEFORE_MONO_ALIGNMENT}
    differ = [
        f"{k} {recorded.get(k, defaults.get(k))!r} (here {here[k]!r})"
        for k in keys
        if recorded.get(k, defaults.get(k)) != here[k]
    ]
    if differ:
        raise DatasetError(
            f"{path}: its {'/'.join(sorted(modes))} labels were made under another definition: "
            f"{', '.join(differ)}; build the runs again into a new folder"
        )


def check_rts_schema(root: Path) -> None:
    """Refuse a dataset folder built with other RTS channels than this installation's (``dataset.json``): its
    ``rts.npy`` columns are not this schema's. A folder without ``dataset.json`` records nothing to check.
    DatasetError naming the folder, its schema and this one."""
    path = root / DATASET_JSON
    if not path.is_file():
        return
    recorded = json.loads(path.read_text())
    channels = recorded.get("rts_channels")
    if channels is not None and list(channels) != list(rts_schema.CHANNEL_NAMES):
        raise DatasetError(
            f"{path}: built with RTS schema v{recorded.get('rts_schema_version')} ({len(channels)} channels); this "
            f"SEESys reads v{rts_schema.SCHEMA_VERSION} ({rts_schema.NUM_CHANNELS}): build the runs again into a new "
            "folder"
        )


def gather_rts(rts: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """RTS windows from stored rows: ``rows`` (..., T) of ``rts`` (R, C); a row −1 (frame not logged) is NaN."""
    out = np.asarray(rts[np.maximum(rows, 0).ravel()], dtype=np.float32).reshape(*rows.shape, rts.shape[-1])
    out[rows < 0] = np.nan
    return out


def run_name(sequence: str, mode: str, trial: int) -> str:
    return f"{sequence}__{mode}__t{trial}"


def run_folder(root: Path, run: str) -> Path:
    return Path(root) / RUNS_DIR / run


def read_run_info(folder: Path) -> RunInfo | None:
    """The run's record, or None when the run has not been finished (or recorded as crashed).

    A run stored in another format than :data:`FORMAT_VERSION` raises :class:`DatasetError`."""
    path = folder / RUN_JSON
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        version = data.pop(FORMAT_KEY, 1)  # format 1 had no version
        info = RunInfo(**data)
    except (ValueError, TypeError) as e:
        raise DatasetError(f"{path}: not a run record: {e}") from None
    if version != FORMAT_VERSION:
        raise DatasetError(
            f"{path}: run stored in dataset format {version}; this SEESys reads format "
            f"{FORMAT_VERSION} (one sample per labelled frame, each PSD stored once). Rebuild the "
            f"dataset into a new folder with `seesys dataset build`; its rendered sequences can be "
            f"reused by moving {folder.parent.parent / 'sequences'} into the new folder first"
        )
    return info


def _write_folder(folder: Path, info: RunInfo, arrays: RunArrays | None) -> None:
    """Write the run under a temporary name, then rename it into place (a run is never half there)."""
    partial = folder.with_name(folder.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    if arrays is not None:
        for name, array, dtype in (
            (RTS_NPY, arrays.rts, np.float32),
            (RTS_FRAMES_NPY, arrays.rts_frames, np.int64),
            (PSD_NPY, arrays.psd, np.uint8),
            (PSD_FRAMES_NPY, arrays.psd_frames, np.int64),
            (SAMPLE_RTS_ROWS_NPY, arrays.sample_rts_rows, np.int32),
            (SAMPLE_PSD_ROWS_NPY, arrays.sample_psd_rows, np.int32),
        ):
            np.save(partial / name, np.ascontiguousarray(array, dtype=dtype))
        arrays.samples.to_csv(partial / SAMPLES_CSV, index=False)
        arrays.frames.to_csv(partial / FRAMES_CSV, index=False)
    (partial / RUN_JSON).write_text(json.dumps({FORMAT_KEY: FORMAT_VERSION, **asdict(info)}, indent=2) + "\n")
    shutil.rmtree(folder, ignore_errors=True)
    os.replace(partial, folder)


def write_run(root: Path, info: RunInfo, arrays: RunArrays) -> Path:
    """Store a completed (or partial) run's samples."""
    arrays.check(info.run)
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
class _StoredRun:
    """One run's arrays as the reader holds them: the large ones memory-mapped, the window rows in memory."""

    rts: np.ndarray
    psd: np.ndarray
    rts_rows: np.ndarray
    psd_rows: np.ndarray


@dataclass(frozen=True)
class Sample:
    """One model input and its label: ``rts`` (T, C) float32 raw, NaN where a frame is missing; ``psd``
    (K_L, H, W, 3) uint8. ``meta`` is the sample's row of :attr:`DatasetReader.index`."""

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
            included = [
                info for info in list_runs(root) if info.status in WITH_SAMPLES and (runs is None or info.run in runs)
            ]
            check_label_definition(root, {info.mode for info in included})
            check_rts_schema(root)
            for info in included:
                if info.run in self._folders:
                    raise DatasetError(f"run {info.run} is in two dataset folders ({self._folders[info.run]}, {root})")
                folder = run_folder(root, info.run)
                self._folders[info.run] = folder
                table = pd.read_csv(folder / SAMPLES_CSV)
                missing = set(SAMPLE_COLUMNS) - set(table.columns)
                if missing:
                    raise DatasetError(f"{folder / SAMPLES_CSV}: missing columns {sorted(missing)}")
                meta = asdict(info)
                for key in (
                    "run",
                    "sequence",
                    "environment",
                    "motion_group",
                    "trajectory",
                    "mode",
                    "trial",
                    "camera_model",
                    "camera_normalisation",
                ):
                    table[key] = meta[key]
                tables.append(table)
        if runs is not None:
            unknown = sorted(set(runs) - set(self._folders))
            if unknown:
                raise DatasetError(
                    f"runs not found (or without samples) in {', '.join(map(str, roots))}: "
                    f"{', '.join(unknown[:5])}{' …' if len(unknown) > 5 else ''}"
                )
        index = pd.concat(tables, ignore_index=True) if tables else pd.DataFrame(columns=list(SAMPLE_COLUMNS))
        if usable_only:
            index = index[index.usable.astype(bool)].reset_index(drop=True)
        self.index = index
        self._arrays: dict[str, _StoredRun] = {}

    def __len__(self) -> int:
        return len(self.index)

    def _run_arrays(self, run: str) -> _StoredRun:
        if run not in self._arrays:
            folder = self._folders[run]
            try:
                self._arrays[run] = _StoredRun(
                    np.load(folder / RTS_NPY, mmap_mode="r"),
                    np.load(folder / PSD_NPY, mmap_mode="r"),
                    np.load(folder / SAMPLE_RTS_ROWS_NPY),
                    np.load(folder / SAMPLE_PSD_ROWS_NPY),
                )
            except (OSError, ValueError) as e:
                raise DatasetError(f"cannot open the arrays of run {folder}: {e}") from None
        return self._arrays[run]

    def __getitem__(self, i: int) -> Sample:
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} out of range ({len(self)} samples)")
        row = self.index.iloc[i]
        stored = self._run_arrays(row.run)
        k = int(row["sample"])
        return Sample(
            gather_rts(stored.rts, stored.rts_rows[k]),
            np.asarray(stored.psd[stored.psd_rows[k]]),
            float(row.error_m),
            str(row.status),
            bool(row.usable),
            row.to_dict(),
        )

    def rts_windows(self) -> np.ndarray:
        """Every indexed sample's RTS window, (N, T, C) float32 (small: the PSD windows are what is large)."""
        if not len(self):
            return np.zeros((0, 0, 0), np.float32)
        out = []
        for run, rows in self.index.groupby("run", sort=False).groups.items():
            stored = self._run_arrays(run)
            out.append((rows, gather_rts(stored.rts, stored.rts_rows[self.index.loc[rows, "sample"].to_numpy(int)])))
        windows = np.empty((len(self), *out[0][1].shape[1:]), np.float32)
        for rows, values in out:
            windows[np.asarray(rows)] = values
        return windows

    def frame_labels(self) -> pd.DataFrame:
        """Per-frame labels of the indexed runs (every frame, not only window ends), with run metadata."""
        tables = []
        for _run, folder in self._folders.items():
            table = pd.read_csv(folder / FRAMES_CSV)
            info = read_run_info(folder)
            for key in ("run", "environment", "motion_group", "trajectory", "mode", "trial", "camera_model"):
                table[key] = getattr(info, key)
            tables.append(table)
        return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()
