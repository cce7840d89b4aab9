"""Model inputs from the labelled dataset and from session folders.

Every source gives the same thing per window: the RTS window (T, C), normalised here once, the PSD matrices
(K_L, H, W, 3) uint8 (scaled inside the model, so the served model takes what the device sends), the label in
metres and the window's end frame and time. The dataset is read only through
:class:`estimator.dataset.store.DatasetReader`; a session folder (``seesys track``/``monitor run`` with ground
truth) is windowed with the protocol's :func:`seesys.core.windows.assemble_windows` and labelled with
:func:`seesys.core.labels.label_session`, the same definitions the dataset builder uses.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd

from estimator.artefact.compatibility import InputShape
from estimator.artefact.transforms import prepare_rts
from estimator.dataset.splits import Splits
from estimator.dataset.store import DatasetReader
from seesys.core import rts_schema, session_layout
from seesys.core.errors import SeesysError
from seesys.core.labels import LabelStatus
from seesys.core.windows import WindowConfig, assemble_windows
from seesys.io import session_files
from seesys.io.core_settings import load_label_config
from seesys.io.rts_log import read_feature_frames
from seesys.io.session_labels import label_session_by_frame

PARTS = ("train", "validation", "test")
#: The ``meta`` column of each window's camera normalisation version (NA where its source states none).
NORMALISATION_COLUMN = "camera_normalisation"


class DataError(SeesysError):
    """Training or evaluation data is missing or does not fit the model."""


class PsdSource(Protocol):
    """PSDs by sample: an array of them, a dataset reader (its samples carry ``psd``) or a subset of either."""

    def __getitem__(self, i: int, /) -> Any: ...


@dataclass
class Windows:
    """Model windows with their labels: ``rts`` normalised (N, T, C) float32, ``psd`` indexable by sample
    (an array, or a reader), ``error_m`` (N,), ``meta`` one row per window (run, frame_index, timestamp, …)."""

    rts: np.ndarray
    psd: PsdSource
    error_m: np.ndarray
    meta: pd.DataFrame

    def __len__(self) -> int:
        return len(self.error_m)

    def psd_at(self, i: int) -> np.ndarray:
        item = self.psd[i]
        return item.psd if hasattr(item, "psd") else np.asarray(item)

    def subset(self, index: np.ndarray) -> Windows:
        index = np.asarray(index, int)
        psd = _Subset(self.psd, index)
        return Windows(self.rts[index], psd, self.error_m[index], self.meta.iloc[index].reset_index(drop=True))

    def select_rts(self, columns: np.ndarray) -> Windows:
        """The same windows with only the RTS ``columns`` a model takes
        (:func:`estimator.artefact.compatibility.rts_columns`), in its order."""
        return self.with_rts(self.rts[..., columns])

    def with_rts(self, rts: np.ndarray) -> Windows:
        """The same windows with the RTS windows ``rts`` in place of theirs (e.g. standardised for a model)."""
        return Windows(rts, self.psd, self.error_m, self.meta)

    def input_shape(self) -> InputShape:
        if not len(self):
            raise DataError("no windows: nothing to train or evaluate on")
        t, c = self.rts.shape[1:]
        k, h, w = self.psd_at(0).shape[:3]
        return InputShape(t, c, k, h, w)


class _Subset:
    """Samples ``index`` of an indexable (a reader or an array), without reading them."""

    def __init__(self, base: PsdSource, index: np.ndarray):
        self.base, self.index = base, index

    def __getitem__(self, i: int):
        return self.base[int(self.index[i])]

    def __len__(self) -> int:
        return len(self.index)


def reader_windows(reader: DatasetReader) -> Windows:
    """The usable windows of a reader: RTS normalised in memory (small), PSD read per sample from the memory maps."""
    rts = prepare_rts(reader.rts_windows()) if len(reader) else np.zeros((0, 0, 0), np.float32)
    return Windows(rts, reader, reader.index.error_m.to_numpy(np.float64), reader.index.reset_index(drop=True))


def split_readers(
    roots: list[Path], splits: Splits, round_index: int, parts: tuple[str, ...] = PARTS
) -> dict[str, DatasetReader]:
    """Readers of the usable samples of the given parts (train, validation, test) of one cross-validation round."""
    if not 0 <= round_index < len(splits.rounds):
        raise DataError(f"round {round_index} not in the splits ({len(splits.rounds)} rounds)")
    split_round = splits.rounds[round_index]
    return {part: DatasetReader(roots, runs=getattr(split_round, part), usable_only=True) for part in parts}


def split_windows(
    roots: list[Path], splits: Splits, round_index: int, parts: tuple[str, ...] = PARTS
) -> dict[str, Windows]:
    """Usable windows of the given parts (train, validation, test) of one cross-validation round."""
    return {part: reader_windows(reader) for part, reader in split_readers(roots, splits, round_index, parts).items()}


def limit(windows: Windows, count: int, seed: int) -> Windows:
    """A seeded random subset of ``count`` windows (all of them when ``count`` is 0 or larger than the set)."""
    if count <= 0 or count >= len(windows):
        return windows
    index = np.sort(np.random.default_rng(seed).choice(len(windows), count, replace=False))
    return windows.subset(index)


def session_mode(folder: Path) -> str:
    """The SLAM mode (rgbd or mono) of a session folder, from its ``session.json``."""
    if not (folder / session_layout.MANIFEST).is_file():
        raise DataError(f"{folder} is not a session folder (no {session_layout.MANIFEST})")
    mode = session_files.read_manifest(folder).get("mode")
    if mode not in ("rgbd", "mono"):
        raise DataError(f"{folder}: session.json names no SLAM mode (rgbd or mono)")
    return mode


def session_frame_labels(folder: Path) -> pd.DataFrame:
    """Every frame's label of a session folder (its 10-frame error against the session's ground truth, as the
    dataset labels its runs, in the session's SLAM mode), indexed by frame index: ``status`` and ``error_m``."""
    return label_session_by_frame(folder, session_mode(folder) == "mono", load_label_config())


def session_windows(folder: Path, windows: WindowConfig, labelled: bool) -> Windows:
    """Every window of a session folder's monitor logs (one per frame whose PSD was logged and whose history is
    complete). With ``labelled``, each gets its end frame's label and only usable windows (labelled end frame,
    no missing RTS row: the dataset's rule) are kept; without, ``error_m`` is NaN."""
    return normalised(session_raw_windows(folder, windows, labelled))


def normalised(raw: Windows) -> Windows:
    """``raw`` (windows whose ``rts`` is the raw RTS, as :func:`session_raw_windows` gives them) with the RTS
    normalised as the models read it."""
    return dataclasses.replace(raw, rts=prepare_rts(raw.rts)) if len(raw) else raw


def session_raw_windows(folder: Path, windows: WindowConfig, labelled: bool) -> Windows:
    """:func:`session_windows` with the raw RTS in ``rts`` (NaN where missing), as the channel table
    (:mod:`estimator.deepsee.channels`) reads it."""
    folder = Path(folder)
    mode = session_mode(folder)
    # Form a window wherever the PSDs were logged: every frame in a dataset build, every end_stride-th on a device.
    every_frame = dataclasses.replace(windows, end_stride=1)
    frames = list(read_feature_frames(folder, folder.name))
    # The camera normalisation its monitor stated (rts.json); unknown (NA) for a log that states no settings.
    settings = frames[0].settings if frames else None
    normalisation = settings.camera_normalisation if settings is not None else pd.NA
    rts, psd, rows = [], [], []
    for window in assemble_windows(frames, every_frame):
        rts.append(window.rts)
        psd.append(window.psd)
        rows.append((folder.name, window.frame_index, window.timestamp, window.missing_rts, normalisation))
    meta = pd.DataFrame(rows, columns=["run", "frame_index", "timestamp", "missing_rts", NORMALISATION_COLUMN])
    error = np.full(len(rows), np.nan)
    if labelled and rows:
        end = label_session_by_frame(folder, mode == "mono", load_label_config()).reindex(meta.frame_index)
        max_missing = windows.max_missing_rts
        usable = (end.status == LabelStatus.LABELLED.value).to_numpy() & (meta.missing_rts <= max_missing).to_numpy()
        error = end.error_m.to_numpy(np.float64)
        keep = np.flatnonzero(usable)
        rts, psd, error, meta = (
            [rts[k] for k in keep],
            [psd[k] for k in keep],
            error[keep],
            meta.iloc[keep].reset_index(drop=True),
        )
    if not rts:
        return Windows(
            np.zeros((0, windows.rts_length, rts_schema.NUM_CHANNELS), np.float32),
            np.zeros((0, windows.psd_samples, 0, 0, 3), np.uint8),
            error,
            meta,
        )
    return Windows(np.stack(rts), np.stack(psd), error, meta)


def concat(parts: list[Windows]) -> Windows:
    """In-memory windows of several sessions as one set."""
    parts = [p for p in parts if len(p)]
    if not parts:
        raise DataError("no usable windows in the given sessions")
    psd = np.concatenate([np.stack([p.psd_at(i) for i in range(len(p))]) for p in parts])
    return Windows(
        np.concatenate([p.rts for p in parts]),
        psd,
        np.concatenate([p.error_m for p in parts]),
        pd.concat([p.meta for p in parts], ignore_index=True),
    )
