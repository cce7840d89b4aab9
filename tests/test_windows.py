"""Window assembly by frame index: RTS rows t−T+1..t and PSDs t−(K_L−1)τ..t, never "the latest of each"."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from seesys.core import rts_schema
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.core.windows import MISSING_PSD, MISSING_RTS, NO_PSD, WindowAssembler, WindowConfig, assemble_windows
from seesys.io.core_settings import load_window_config

CFG = WindowConfig(rts_length=30, psd_samples=4, psd_stride=10, end_stride=10, max_missing_rts=3)


def frame(i: int, state: TrackingState = TrackingState.OK) -> FeatureFrame:
    """A frame whose RTS row and PSD both carry its index, so a window shows which frames it was built from."""
    psd = np.full((96, 128, 3), i % 256, dtype=np.uint8) if i % 10 == 0 else None
    return FeatureFrame("dev", i, 100.0 + i / 30, state, np.full(rts_schema.NUM_CHANNELS, i, dtype=np.float32), psd)


def test_config_file_has_the_paper_windows():
    cfg = load_window_config()
    assert (cfg.rts_length, cfg.psd_samples, cfg.psd_stride) == (30, 4, 10)
    assert cfg.psd_stride % cfg.end_stride == 0


def test_indices():
    assert CFG.rts_frame_indices(40).tolist() == list(range(11, 41))
    assert CFG.psd_frame_indices(40).tolist() == [10, 20, 30, 40]
    assert CFG.is_psd_frame(30) and not CFG.is_psd_frame(31)


def test_windows_of_a_complete_stream():
    samples = list(assemble_windows((frame(i) for i in range(0, 61)), CFG))
    # the first window needs frame 0 (PSD) and rows 1..30: it ends at 30
    assert [s.frame_index for s in samples] == [30, 40, 50, 60]
    s = samples[-1]
    assert s.rts.shape == (30, rts_schema.NUM_CHANNELS) and s.psd.shape == (4, 96, 128, 3)
    np.testing.assert_array_equal(s.rts[:, 0], np.arange(31, 61))
    assert [int(p[0, 0, 0]) for p in s.psd] == [30, 40, 50, 60]
    assert s.timestamp == pytest.approx(102.0) and s.missing_rts == 0


def test_missing_and_untracked_rows():
    frames = [frame(i) for i in range(0, 61) if i not in (45, 46)]
    frames = [
        frame(i, TrackingState.RECENTLY_LOST) if i == 50 else f for i, f in zip([f.frame_index for f in frames], frames)
    ]
    s = {w.frame_index: w for w in assemble_windows(frames, CFG)}
    assert s[60].missing_rts == 3
    row = list(s[60].rts_frame_indices).index(45)
    assert np.isnan(s[60].rts[row]).all()  # a missing frame is a NaN row, not its neighbour's row
    assert 50 not in s  # the end frame must be tracked


def test_a_missing_row_is_never_an_older_frame_that_held_its_place():
    # Frames up to 40, then 70 and from 72: the window ending at 100 needs rows 71..100. Frame 71 never came; the frame
    # the assembler last kept in its place (40: 31 frames, the window's history + 1, earlier) must not stand in for it.
    frames = [frame(i) for i in [*range(0, 41), 70, *range(72, 101)]]
    s = {w.frame_index: w for w in assemble_windows(frames, CFG)}
    assert s[100].missing_rts == 1 and np.isnan(s[100].rts[0]).all()
    assert s[100].rts[1:, 0].tolist() == list(range(72, 101))
    assert 90 not in s  # rows 61..71 missing: more than max_missing_rts


def test_a_row_that_is_not_the_schemas_is_refused_by_name():
    for shape in [(rts_schema.NUM_CHANNELS + 1,), (1, rts_schema.NUM_CHANNELS), ()]:
        odd = dataclasses.replace(frame(3), rts=np.zeros(shape, dtype=np.float32))
        with pytest.raises(ValueError, match=re.escape(f"frame 3: an RTS row of shape {shape}, the schema has")):
            WindowAssembler(CFG).add(odd)


def test_too_many_missing_rows_or_a_missing_psd_gives_no_window():
    frames = [frame(i) for i in range(0, 61) if not 52 <= i <= 55]
    assert [s.frame_index for s in assemble_windows(frames, CFG)] == [30, 40, 50]
    frames = [frame(i) for i in range(0, 61) if i != 20]
    assert [s.frame_index for s in assemble_windows(frames, CFG)] == [60]


def test_an_assembler_that_keeps_no_psd_forms_the_same_windows_without_them():
    """For a model that reads no PSD: the same window ends and rows, whether the frames bring their PSDs or not
    (a receiver that read past them), and a missing PSD refuses nothing."""

    def windows(frames, psd):
        assembler = WindowAssembler(CFG, psd=psd)
        return [w for w in (assembler.add(f) for f in frames) if w is not None]

    with_psd = windows((frame(i) for i in range(0, 61)), psd=True)
    for frames in (
        [frame(i) for i in range(0, 61)],
        [dataclasses.replace(frame(i), psd=None) for i in range(0, 61)],
    ):
        without = windows(frames, psd=False)
        assert [w.frame_index for w in without] == [w.frame_index for w in with_psd] == [30, 40, 50, 60]
        assert all(w.psd is NO_PSD and np.array_equal(w.rts, v.rts) for w, v in zip(without, with_psd))
    no_20 = [frame(i) for i in range(0, 61) if i != 20]
    assert [w.frame_index for w in windows(no_20, psd=False)] == [30, 40, 50, 60]  # frame 20 held a row only


def test_a_window_end_refused_once_its_history_arrived_is_named():
    """A receiver counts such windows by reason; the windows before the first full history are not refusals."""

    def reasons(frames):
        assembler, out = WindowAssembler(CFG), {}
        for f in frames:
            if assembler.add(f) is None and assembler.refused is not None:
                out[f.frame_index] = assembler.refused
        return out

    assert reasons(frame(i) for i in range(0, 61)) == {}
    assert reasons(frame(i) for i in range(0, 61) if not 52 <= i <= 55) == {60: MISSING_RTS}
    assert reasons(frame(i) for i in range(0, 61) if i != 20) == {30: MISSING_PSD, 40: MISSING_PSD, 50: MISSING_PSD}
    assert reasons(frame(i) for i in range(100, 161)) == {}  # a stream that starts at frame 100


def test_the_window_rule_is_the_one_setting_of_serving_and_training():
    """max_missing_rts of windows.toml decides the windows the service serves and the samples a model trains on
    (the dataset has no rule of its own); the shipped model was trained with no missing row."""
    from estimator.dataset.config import DatasetConfig

    assert load_window_config().max_missing_rts == 0
    assert "samples" not in {f.name for f in dataclasses.fields(DatasetConfig)}


def test_rejects_inconsistent_config():
    with pytest.raises(ValueError):
        WindowConfig(rts_length=30, psd_samples=4, psd_stride=0, end_stride=1, max_missing_rts=3)
    with pytest.raises(ValueError):
        WindowConfig(rts_length=5, psd_samples=4, psd_stride=10, end_stride=10, max_missing_rts=5)
    with pytest.raises(ValueError, match="multiple of end_stride"):
        WindowConfig(rts_length=30, psd_samples=4, psd_stride=10, end_stride=4, max_missing_rts=3)


def test_end_stride_one_gives_a_window_on_every_frame_with_the_same_content():
    """With end_stride 1 a window ends on every frame; the windows that also end on a multiple of 10 are exactly
    the windows of the device's stride: only how often a window is formed changes, not what it holds."""
    every = dataclasses.replace(CFG, end_stride=1)
    frames = [
        FeatureFrame(
            "dev",
            i,
            100.0 + i / 30,
            TrackingState.OK,
            np.full(rts_schema.NUM_CHANNELS, i, dtype=np.float32),
            np.full((96, 128, 3), i % 256, dtype=np.uint8),
        )
        for i in range(0, 61)
    ]
    dense = {s.frame_index: s for s in assemble_windows(frames, every)}
    assert sorted(dense) == list(range(30, 61))
    assert dense[37].psd_frame_indices.tolist() == [7, 17, 27, 37]
    assert [int(p[0, 0, 0]) for p in dense[37].psd] == [7, 17, 27, 37]
    sparse = list(assemble_windows(frames, CFG))
    for s in sparse:
        np.testing.assert_array_equal(s.rts, dense[s.frame_index].rts)
        np.testing.assert_array_equal(s.psd, dense[s.frame_index].psd)
