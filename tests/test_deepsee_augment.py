"""Training-time augmentation: it changes only what a real camera changes, within the configured bounds, the same
way for the same seed, and nothing when disabled."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from estimator.deepsee.augment import COUNT_CHANNELS, Augmenter
from estimator.deepsee.config import load_estimator_config
from seesys.core import rts_schema
from seesys.core.psd import INLIER_LAYER, KEYPOINT_LAYER, MAP_POINT_LAYER

B, T, K, H, W = 16, 30, 4, 12, 16


def _batch(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    raw = np.abs(rng.normal(1.0, 0.5, (B, T, rts_schema.NUM_CHANNELS))) * 50
    raw[:, :5] = np.nan  # the first rows of every window are missing
    psd = rng.integers(0, 256, (B, K, H, W, 3)).astype(np.uint8)
    psd[rng.random(psd.shape) < 0.6] = 0
    return torch.from_numpy(rts_schema.normalise(raw)), torch.from_numpy(psd)


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_augmentation_changes_only_camera_dependent_inputs_within_bounds():
    config = load_estimator_config().augmentation
    rts, psd = _batch()
    out_rts, out_psd = Augmenter(config)(rts, psd, _gen(1))
    changed = {
        rts_schema.CHANNEL_NAMES[i] for i in range(rts.shape[-1]) if not torch.equal(out_rts[..., i], rts[..., i])
    }
    assert changed == {"brightness", "contrast", "entropy", "laplacian", *COUNT_CHANNELS}
    assert torch.equal(out_rts[:, :5], rts[:, :5])  # missing rows stay zero
    i = rts_schema.index_of("contrast")
    ratio = out_rts[:, 5:, i] / rts[:, 5:, i]
    assert ratio.min() >= config.contrast_gain[0] - 1e-5 and ratio.max() <= config.contrast_gain[1] + 1e-5
    assert torch.allclose(ratio, ratio[:, :1].expand_as(ratio))  # one draw per window, not per row
    counts = [rts_schema.index_of(n) for n in COUNT_CHANNELS]
    gains = out_rts[:, 5:, counts] / rts[:, 5:, counts]
    assert torch.allclose(gains, gains[:, :1, :1].expand_as(gains), rtol=1e-5)  # one gain for all counts
    b = rts_schema.index_of("brightness")
    shift = (out_rts[:, 5:, b] - rts[:, 5:, b]) * rts_schema.CHANNELS[b].scale
    assert shift.abs().max() <= config.brightness_offset + 1e-6 and shift.std() > 0
    for layer in (INLIER_LAYER, MAP_POINT_LAYER):
        assert torch.equal(out_psd[..., layer], psd[..., layer])
    kp, out_kp = psd[..., KEYPOINT_LAYER], out_psd[..., KEYPOINT_LAYER]
    assert torch.equal(out_kp == 0, kp == 0)  # empty cells stay empty, cells with keypoints stay non-zero
    assert not torch.equal(out_kp, kp) and out_psd.dtype == torch.uint8


def test_augmentation_is_seeded_and_can_be_disabled():
    config = load_estimator_config().augmentation
    rts, psd = _batch()
    first = Augmenter(config)(rts, psd, _gen(7))
    second = Augmenter(config)(rts, psd, _gen(7))
    other = Augmenter(config)(rts, psd, _gen(8))
    assert all(torch.equal(a, b) for a, b in zip(first, second))
    assert not torch.equal(first[0], other[0])
    off = Augmenter(dataclasses.replace(config, enabled=False))(rts, psd, _gen(7))
    assert off[0] is rts and off[1] is psd


def test_models_of_the_rts_window_only_get_their_empty_psd_back():
    rts, _ = _batch()
    empty = torch.zeros((B, 0), dtype=torch.uint8)
    out_rts, out_psd = Augmenter(load_estimator_config().augmentation)(rts, empty, _gen(3))
    assert out_psd is empty and not torch.equal(out_rts, rts)
