"""How windows are read from labelled sessions and from the tiny dataset made of them (``testkit.deepsee``)."""

from __future__ import annotations

import numpy as np
import pytest
from testkit.deepsee import PSD_SHAPE

from estimator.dataset.splits import read_splits
from estimator.dataset.store import DatasetReader
from estimator.deepsee.data import session_windows, split_windows
from seesys.core import rts_schema
from seesys.io.core_settings import load_window_config

pytestmark = pytest.mark.usefixtures("single_thread")


@pytest.mark.system
def test_tiny_dataset_has_a_sample_for_every_labelled_frame(tiny_dataset):
    reader = DatasetReader(tiny_dataset.root, usable_only=True)
    frames = DatasetReader(tiny_dataset.root).frame_labels()
    # Every labelled frame with a full window history (K_L PSD matrices tau apart) ends a usable sample.
    history = load_window_config().history
    assert len(reader) == ((frames.status == "labelled") & (frames.frame_index >= history)).sum() > 1000
    parts = split_windows([tiny_dataset.root], read_splits(tiny_dataset.splits, [tiny_dataset.root]), 0)
    assert {p: len(w) > 100 for p, w in parts.items()} == {"train": True, "validation": True, "test": True}
    shape = parts["train"].input_shape()
    assert (shape.rts_length, shape.channels, shape.psd_height, shape.psd_width) == (
        30,
        rts_schema.NUM_CHANNELS,
        *PSD_SHAPE,
    )
    assert np.isfinite(parts["train"].rts).all() and np.abs(parts["train"].rts).max() < 20


@pytest.mark.system
def test_session_windows_match_the_dataset_samples(tiny_dataset):
    """The same session read directly (finetune, estimate) gives the dataset builder's windows and labels."""
    run = sorted(p.name for p in tiny_dataset.sessions.iterdir())[0]
    direct = session_windows(tiny_dataset.sessions / run, load_window_config(), labelled=True)
    stored = DatasetReader(tiny_dataset.root, runs=[run], usable_only=True)
    assert list(direct.meta.frame_index) == list(stored.index.frame_index)
    np.testing.assert_allclose(direct.error_m, stored.index.error_m)
    np.testing.assert_array_equal(direct.psd_at(5), stored[5].psd)
    unlabelled = session_windows(tiny_dataset.sessions / run, load_window_config(), labelled=False)
    assert len(unlabelled) == len(direct) and np.isnan(unlabelled.error_m).all()  # every frame is tracked
