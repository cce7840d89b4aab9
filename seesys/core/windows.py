"""Model input windows, assembled by frame index (paper §4.2.1): the one definition for device logs, the
dataset builder and the estimator.

A window ends at a frame t with index ``t % s == 0`` (s = ``end_stride``; the monitor computes the PSD on exactly
these frames) and holds

- the RTS rows of frames t−T+1 … t (T = ``rts_length``), in frame order, a NaN row where a frame is missing;
- the PSD matrices of frames t−(K_L−1)·tau, …, t−tau, t (K_L = ``psd_samples``, tau = ``psd_stride``).

``psd_stride`` is a multiple of ``end_stride``, so every PSD a window needs is on a frame that ends a window. The
model sees the same window whatever ``end_stride`` is; ``end_stride`` only says how often one is formed: the device
streams PSDs (and so estimates) every ``end_stride`` frames, and the dataset builder forms a window on every
frame (``end_stride = 1``), one sample per labelled frame.

Rows and matrices are looked up by frame index, never "the latest of each": a window is only emitted when its
end frame is tracked, every PSD sample is present (for a model that reads them), and at most ``max_missing_rts`` of
the T rows are missing or untracked. (The authors pair the newest RTS window with the newest PSD window,
unsynchronised.)
``max_missing_rts`` is the one rule for every model window: the service serves and the dataset trains on the
same windows, and a model records the rule it was trained with. A window end whose whole history has arrived but
that is refused all the same is named in :attr:`WindowAssembler.refused` (:data:`MISSING_RTS`,
:data:`MISSING_PSD`), so that a receiver can count it instead of staying silent.

The configured windows are ``load_window_config()`` (``configs/windows.toml``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from seesys.core import rts_schema
from seesys.core.messages import FeatureFrame

#: Why a window end whose history has arrived was refused: too many RTS rows missing or untracked; a PSD missing.
MISSING_RTS = "missing_rts"
MISSING_PSD = "missing_psd"
#: The PSD of a window formed by an assembler that keeps none (a model that reads no PSD): no matrix at all.
NO_PSD = np.empty((0, 0, 0, 0), dtype=np.uint8)
NO_PSD.flags.writeable = False


@dataclass(frozen=True)
class WindowConfig:
    rts_length: int
    psd_samples: int
    psd_stride: int
    end_stride: int
    max_missing_rts: int

    def __post_init__(self) -> None:
        if min(self.rts_length, self.psd_samples, self.psd_stride, self.end_stride) < 1:
            raise ValueError(f"window lengths and strides must be positive: {self}")
        if self.psd_stride % self.end_stride:
            raise ValueError(f"psd_stride must be a multiple of end_stride: {self}")
        if not 0 <= self.max_missing_rts < self.rts_length:
            raise ValueError(f"max_missing_rts must be in [0, rts_length): {self}")

    def is_psd_frame(self, frame_index: int) -> bool:
        """True on the frames that end a window: their PSD is computed, logged and streamed."""
        return frame_index % self.end_stride == 0

    def rts_frame_indices(self, end: int) -> np.ndarray:
        return np.arange(end - self.rts_length + 1, end + 1)

    def psd_frame_indices(self, end: int) -> np.ndarray:
        return end - self.psd_stride * np.arange(self.psd_samples - 1, -1, -1)

    @property
    def history(self) -> int:
        """How many frames before a window's end frame the window reaches back."""
        return max(self.rts_length - 1, (self.psd_samples - 1) * self.psd_stride)


@dataclass(frozen=True)
class WindowSample:
    """One model input: RTS rows (T, C) float32 (raw, NaN where missing) and PSD matrices (K_L, H, W, 3) uint8."""

    device_id: str
    frame_index: int
    timestamp: float
    rts: np.ndarray
    rts_frame_indices: np.ndarray
    psd: np.ndarray
    psd_frame_indices: np.ndarray
    missing_rts: int


class WindowAssembler:
    """Collects one device's feature frames and emits a :class:`WindowSample` whenever one is complete. With ``psd``
    False it keeps no PSD and a window needs none (for a model that reads none): the window ends at the same frames,
    its ``psd`` is :data:`NO_PSD`, and the frames may come without theirs (read past by
    ``messages.decode(..., psd=False)``). Frames come in increasing frame index (a receiver starts a new assembler
    when a device restarts); raises ValueError for a row that is not one of the schema's."""

    def __init__(self, config: WindowConfig, psd: bool = True):
        self.config = config
        self.keeps_psd = psd
        # The rows of the last history + 1 frames in a ring, a frame's row in slot index % size: a frame copies its
        # row in, and a window is one gather of its slots, where a row at a time (and forgetting the old ones) cost
        # four times as much in the service's path.
        self._size = config.history + 1
        self._ring = np.zeros((self._size, rts_schema.NUM_CHANNELS), dtype=np.float32)
        self._slot_frame = np.full(self._size, -1, dtype=np.int64)  # which frame each slot holds (-1: none yet)
        self._slot_tracked = np.zeros(self._size, dtype=bool)
        self._psds: dict[int, np.ndarray] = {}
        self._first: int | None = None
        #: Why the window ending at the last frame added was refused (:data:`MISSING_RTS`, :data:`MISSING_PSD`);
        #: None when it was emitted, when that frame ends no window, when its end frame is untracked, or when the
        #: window reaches back before the first frame this assembler saw.
        self.refused: str | None = None

    def add(self, frame: FeatureFrame) -> WindowSample | None:
        """Store ``frame``; return the window ending at it when it ends one and the window is complete."""
        index = frame.frame_index
        self.refused = None
        if self._first is None:
            self._first = index
        if np.shape(frame.rts) != (rts_schema.NUM_CHANNELS,):  # not broadcast into the ring
            raise ValueError(
                f"frame {index}: an RTS row of shape {np.shape(frame.rts)}, the schema has {rts_schema.NUM_CHANNELS} "
                "channels"
            )
        slot = index % self._size
        self._ring[slot] = frame.rts  # float32, as the window is
        self._slot_frame[slot] = index
        self._slot_tracked[slot] = frame.tracking_state.tracked
        if frame.psd is not None and self.keeps_psd:
            self._psds[index] = frame.psd
            oldest = index - self.config.history
            for old in [i for i in self._psds if i < oldest]:
                del self._psds[old]
        return self._window(frame) if self.config.is_psd_frame(index) else None

    def _window(self, end: FeatureFrame) -> WindowSample | None:
        cfg = self.config
        if not end.tracking_state.tracked or (self.keeps_psd and end.psd is None):
            return None
        psd_indices = cfg.psd_frame_indices(end.frame_index)
        history_arrived = end.frame_index - cfg.history >= (self._first or 0)
        if self.keeps_psd and any(int(i) not in self._psds for i in psd_indices):
            self.refused = MISSING_PSD if history_arrived else None
            return None
        rts_indices = cfg.rts_frame_indices(end.frame_index)
        slots = rts_indices % self._size
        arrived = self._slot_frame[slots] == rts_indices
        missing = cfg.rts_length - int(np.count_nonzero(arrived & self._slot_tracked[slots]))
        if missing > cfg.max_missing_rts:
            self.refused = MISSING_RTS if history_arrived else None
            return None
        rts = self._ring[slots]  # a copy: the ring moves on
        if missing:
            rts[~arrived] = np.nan  # an untracked frame's row stays as it came
        psd = np.stack([self._psds[int(i)] for i in psd_indices]) if self.keeps_psd else NO_PSD
        return WindowSample(end.device_id, end.frame_index, end.timestamp, rts, rts_indices, psd, psd_indices, missing)


def assemble_windows(frames: Iterable[FeatureFrame], config: WindowConfig) -> Iterator[WindowSample]:
    """Every complete window of a recorded session, given its feature frames in frame order."""
    assembler = WindowAssembler(config)
    for frame in frames:
        sample = assembler.add(frame)
        if sample is not None:
            yield sample
