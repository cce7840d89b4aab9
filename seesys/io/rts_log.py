"""The monitor's part of the session folder, written as frames come and flushed, so a crash loses nothing
already written:

- ``rts.csv``: ``frame_index, timestamp, tracking_state`` (state name) and one column per RTS channel, in
  :mod:`seesys.core.rts_schema` order and units; ``nan`` where a channel has no value (e.g. motion on a frame
  without a pose). A plain CSV that pandas and R read as it is.
- ``rts.json``: the schema ``rts.csv`` was written with (``rts_schema_version``, ``rts_schema_fingerprint``, the
  channels with their units) and the device settings the features were made with (``device_settings``:
  :class:`~seesys.core.device_settings.DeviceSettings`, absent where unknown). Readers refuse an ``rts.csv``
  without it, or of another schema; frames read back carry the settings, so that a replayed session states them
  to the estimator service as the live device did.
- ``psd/psd_NNNNNN.bin``: the PSD matrices, in chunks of ``psd_chunk_records`` records. A record is
  ``u32 n | i64 frame index | f64 timestamp | n bytes`` of :func:`seesys.core.messages.pack_psd` (the zlib'd
  matrix, the same bytes as on the wire). A record cut short by a crash at the end of the last chunk
  is ignored by the reader.
"""

from __future__ import annotations

import csv
import json
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pandas as pd

from seesys.core import rts_schema, session_layout
from seesys.core.device_settings import DeviceSettings
from seesys.core.errors import SeesysError
from seesys.core.messages import FeatureFrame, MessageError, pack_psd, unpack_psd
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses

RTS_CSV = "rts.csv"
RTS_JSON = "rts.json"
PSD_DIR = "psd"
RTS_COLUMNS: tuple[str, ...] = ("frame_index", "timestamp", "tracking_state", *rts_schema.CHANNEL_NAMES)
_RECORD = struct.Struct("<Iqd")


class MonitorLogError(SeesysError):
    """A monitor log in a session folder is missing or malformed."""


def schema_metadata(settings: DeviceSettings | None = None) -> dict:
    """What ``rts.json`` records: the schema of the ``rts.csv`` beside it and the device's ``settings``."""
    meta = {
        "rts_schema_version": rts_schema.SCHEMA_VERSION,
        "rts_schema_fingerprint": rts_schema.FINGERPRINT,
        "channels": [{"name": c.name, "unit": c.unit} for c in rts_schema.CHANNELS],
    }
    if settings is not None:
        meta["device_settings"] = settings.as_record()
    return meta


class RtsCsvWriter:
    """Appends one ``rts.csv`` row per frame (and writes ``rts.json`` beside it first)."""

    def __init__(self, path: Path, settings: DeviceSettings | None = None):
        (path.parent / RTS_JSON).write_text(json.dumps(schema_metadata(settings), indent=2) + "\n")
        self._file = open(path, "w", newline="")
        self._csv = csv.writer(self._file)
        self._csv.writerow(RTS_COLUMNS)
        self._file.flush()

    def write(self, frame: FeatureFrame) -> None:
        values = [repr(float(v)) if math.isfinite(v) else "nan" for v in np.asarray(frame.rts, dtype=np.float64)]
        self._csv.writerow([frame.frame_index, repr(float(frame.timestamp)), frame.tracking_state.name, *values])
        self._file.flush()

    def close(self) -> None:
        self._file.close()


class PsdLogWriter:
    """Appends PSD records to chunk files under ``<session>/psd/``."""

    def __init__(self, folder: Path, chunk_records: int):
        if chunk_records < 1:
            raise ValueError("chunk_records must be >= 1")
        self.folder = folder
        self.chunk_records = chunk_records
        folder.mkdir(parents=True, exist_ok=True)
        for stale in folder.glob("psd_*.bin"):  # an earlier session in the same folder
            stale.unlink()
        self._file: BinaryIO | None = None  # the open chunk, from the first write on
        self._records = 0
        self._chunks = 0

    def write(self, frame_index: int, timestamp: float, psd: np.ndarray) -> None:
        if self._file is None or self._records == self.chunk_records:
            self._file = self._next_chunk()
        packed = pack_psd(psd)
        self._file.write(_RECORD.pack(len(packed), frame_index, timestamp) + packed)
        self._file.flush()
        self._records += 1

    def _next_chunk(self) -> BinaryIO:
        """The next chunk file, opened (the current one closed)."""
        if self._file is not None:
            self._file.close()
        chunk = open(self.folder / f"psd_{self._chunks:06d}.bin", "wb")
        self._chunks += 1
        self._records = 0
        return chunk

    def close(self) -> None:
        if self._file is not None:
            self._file.close()


@dataclass(frozen=True)
class PsdRecord:
    frame_index: int
    timestamp: float
    psd: np.ndarray


def read_psd_log(session: Path) -> Iterator[PsdRecord]:
    """Every PSD record of a session, in the order written."""
    folder = Path(session) / PSD_DIR
    if not folder.is_dir():
        raise MonitorLogError(f"no PSD log in {session} (missing folder {folder})")
    chunks = sorted(folder.glob("psd_*.bin"))
    for n, chunk in enumerate(chunks):
        data = chunk.read_bytes()
        pos = 0
        while pos < len(data):
            if pos + _RECORD.size > len(data):
                break
            size, frame_index, timestamp = _RECORD.unpack_from(data, pos)
            body = data[pos + _RECORD.size : pos + _RECORD.size + size]
            if len(body) < size:
                break
            try:
                yield PsdRecord(frame_index, timestamp, unpack_psd(body))
            except MessageError as e:
                raise MonitorLogError(f"{chunk}: bad PSD record at byte {pos}: {e}") from None
            pos += _RECORD.size + size
        if pos < len(data) and n != len(chunks) - 1:
            raise MonitorLogError(f"{chunk}: truncated PSD record at byte {pos} in a chunk that is not the last")


def check_rts_schema(session: Path) -> DeviceSettings | None:
    """Raise :class:`MonitorLogError` unless the session's ``rts.json`` says its ``rts.csv`` has this schema; the
    device settings it records (None where it records none)."""
    session = Path(session)
    path = session / RTS_JSON
    try:
        meta = json.loads(path.read_text())
        version, fingerprint = int(meta["rts_schema_version"]), int(meta["rts_schema_fingerprint"])
    except FileNotFoundError:
        raise MonitorLogError(
            f"{session} has no {RTS_JSON}: its {RTS_CSV} was written by an older SEESys, with an "
            f"RTS schema that cannot be checked (re-run the session to log it again)"
        ) from None
    except (ValueError, KeyError, TypeError) as e:
        raise MonitorLogError(f"{path}: malformed ({e})") from None
    try:
        rts_schema.check_compatible(version, fingerprint, f"{session / RTS_CSV}")
    except rts_schema.SchemaMismatch as e:
        raise MonitorLogError(str(e)) from None
    try:
        return DeviceSettings.from_record(meta["device_settings"]) if "device_settings" in meta else None
    except (TypeError, ValueError) as e:
        raise MonitorLogError(f"{path}: malformed device_settings ({e})") from None


def read_rts_csv(session: Path) -> pd.DataFrame:
    """``rts.csv`` of a session as a DataFrame, its schema (``rts.json``) and columns checked; the device settings
    of ``rts.json`` in ``table.attrs["device_settings"]`` (None where unknown)."""
    path = Path(session) / RTS_CSV
    if not path.is_file():
        raise MonitorLogError(f"no RTS log in {session} (missing {path})")
    settings = check_rts_schema(session)
    try:
        table = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise MonitorLogError(f"cannot read {path}: {e}") from None
    if tuple(table.columns) != RTS_COLUMNS:
        raise MonitorLogError(
            f"{path}: columns {list(table.columns)} do not match RTS schema "
            f"v{rts_schema.SCHEMA_VERSION} ({', '.join(RTS_COLUMNS)})"
        )
    table.attrs["device_settings"] = settings
    return table


def read_feature_frames(session: Path, device_id: str) -> Iterator[FeatureFrame]:
    """The session's monitor logs as :class:`FeatureFrame` records in frame order, PSD attached where logged
    (for :func:`seesys.core.windows.assemble_windows`), with the device settings ``rts.json`` records and, where
    the session has ``pose_covariance.csv``, each frame's predicted translation covariance (its block of the 6×6)."""
    psds = {r.frame_index: r.psd for r in read_psd_log(session)}
    covariances = _translation_covariances(session)
    table = read_rts_csv(session)
    settings = table.attrs["device_settings"]
    rts = table[list(rts_schema.CHANNEL_NAMES)].to_numpy(dtype=np.float32)
    for k, (index, timestamp, state) in enumerate(
        zip(table["frame_index"], table["timestamp"], table["tracking_state"])
    ):
        try:
            tracking_state = TrackingState[state]
        except KeyError:
            raise MonitorLogError(f"{session}/{RTS_CSV}: unknown tracking state {state!r} at frame {index}") from None
        yield FeatureFrame(
            device_id,
            int(index),
            float(timestamp),
            tracking_state,
            rts[k],
            psds.get(int(index)),
            settings=settings,
            translation_covariance=covariances.get(int(index)),
        )


# The most a frame's time may differ between a session's logs and still be the same frame (they write it with
# different precisions; frames are a camera period, tens of ms, apart).
SAME_FRAME_S = 1e-4


@dataclass(frozen=True)
class PoseCovarianceLog:
    """A session's ``pose_covariance.csv``: each logged frame's index, time and 6×6 world-axes covariance."""

    frame_index: np.ndarray
    timestamps: np.ndarray
    matrices: np.ndarray  # (N, 6, 6)

    def by_frame(self) -> dict[int, np.ndarray]:
        """frame index → 6×6 covariance."""
        return {int(i): m for i, m in zip(self.frame_index, self.matrices)}

    def matched(self, trajectory: Poses) -> tuple[np.ndarray, np.ndarray]:
        """The frames both this log and ``trajectory`` (the session's ``trajectory.tum``) hold: their indices into
        ``trajectory`` and into this log. A frame is the same frame in both when its times differ by at most
        :data:`SAME_FRAME_S` (evo's time association: the two files write a frame's time with different
        precisions)."""
        from evo.core import sync

        pose_index, log_index = sync.matching_time_indices(trajectory.timestamps, self.timestamps, SAME_FRAME_S)
        return np.asarray(pose_index, int), np.asarray(log_index, int)

    def positions(self, trajectory: Poses) -> dict[int, np.ndarray]:
        """frame index → the camera position of ``trajectory`` at the logged frame's time (:meth:`matched`), for
        the frames it holds."""
        pose_index, log_index = self.matched(trajectory)
        return {int(self.frame_index[k]): trajectory.positions[p] for p, k in zip(pose_index, log_index)}


def read_pose_covariance_log(session: Path) -> PoseCovarianceLog | None:
    """The session's ``pose_covariance.csv``, None without one; raises :class:`MonitorLogError` for a malformed
    file."""
    path = session / session_layout.POSE_COVARIANCE_CSV
    if not path.is_file():
        return None
    try:
        table = pd.read_csv(path)
        matrices = session_layout.covariance_matrices(table[list(session_layout.POSE_COVARIANCE_COLUMNS[2:])])
        return PoseCovarianceLog(table.frame_index.to_numpy(int), table.timestamp.to_numpy(float), matrices)
    except (OSError, KeyError, ValueError, pd.errors.ParserError, pd.errors.EmptyDataError) as e:
        raise MonitorLogError(f"{path}: {e}") from None


def _translation_covariances(session: Path) -> dict[int, np.ndarray]:
    """frame index → 3×3 translation covariance from the session's ``pose_covariance.csv`` (empty without one)."""
    log = read_pose_covariance_log(session)
    return {} if log is None else {i: m[:3, :3] for i, m in log.by_frame().items()}
