"""Training-time augmentation of the model's inputs: what a real camera changes and the renderer does not vary enough.

A real handheld camera gives frames of other contrast, exposure and sharpness than the renders, and more or less
texture, so more or fewer matches and stronger or weaker FAST responses. A model trained on renders alone can learn
the renderer's absolute levels of these inputs instead of how they relate to the error. Per window, one random draw
changes them consistently over the window's rows and matrices:

- RTS sensor-input channels: brightness + offset, contrast × gain, entropy + offset, Laplacian variance × gain;
- RTS match counts (matched inliers, outliers, matches before pose optimisation): × one gain;
- PSD keypoint layer (the mean FAST response of a cell): × gain, clipped to 1..255 (empty cells stay empty).

The motion, mapping and timing-free channels, the inlier and map-point layers, and missing RTS rows (all zero after
normalisation) are left as they are. The inputs are the model's own: RTS windows already normalised by
:func:`seesys.core.rts_schema.normalise` (so a gain on a ``log1p`` channel is an offset of log(gain) / scale),
PSD matrices uint8 (B, K, H, W, 3).
"""

from __future__ import annotations

import math

import torch

from estimator.deepsee.config import AugmentationConfig
from seesys.core import rts_schema
from seesys.core.psd import KEYPOINT_LAYER

COUNT_CHANNELS = ("matched_inliers", "outliers", "matches_before_po")


def _channel(name: str) -> tuple[int, float]:
    index = rts_schema.index_of(name)
    return index, rts_schema.CHANNELS[index].scale


class Augmenter:
    """Callable ``(rts, psd, generator) -> (rts, psd)`` applying :class:`AugmentationConfig` to a batch; the
    random draws come from ``generator`` (a CPU generator, so a seeded epoch draws the same on any device)."""

    def __init__(self, config: AugmentationConfig):
        self.config = config
        self._brightness = _channel("brightness")
        self._contrast = _channel("contrast")
        self._entropy = _channel("entropy")
        self._laplacian = _channel("laplacian")
        self._counts = [rts_schema.index_of(name) for name in COUNT_CHANNELS]

    @staticmethod
    def _log_uniform(bounds: tuple[float, float], n: int, generator: torch.Generator) -> torch.Tensor:
        low, high = math.log(bounds[0]), math.log(bounds[1])
        return torch.exp(low + (high - low) * torch.rand(n, generator=generator, dtype=torch.float64)).float()

    @staticmethod
    def _symmetric(half_width: float, n: int, generator: torch.Generator) -> torch.Tensor:
        return (2 * torch.rand(n, generator=generator, dtype=torch.float64) - 1).float() * half_width

    def __call__(
        self, rts: torch.Tensor, psd: torch.Tensor, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if not self.config.enabled:
            return rts, psd
        c, n = self.config, rts.shape[0]
        # every draw is made whether or not the PSD is used, so an ablation sees the same RTS changes as DeepSEE
        draws = {
            "brightness": self._symmetric(c.brightness_offset, n, generator) / self._brightness[1],
            "contrast": self._log_uniform(c.contrast_gain, n, generator),
            "entropy": self._symmetric(c.entropy_offset_bits, n, generator) / self._entropy[1],
            "laplacian": torch.log(self._log_uniform(c.laplacian_gain, n, generator)) / self._laplacian[1],
            "counts": self._log_uniform(c.count_gain, n, generator),
            "keypoint": self._log_uniform(c.keypoint_response_gain, n, generator),
        }
        draws = {k: v.to(rts.device).view(n, 1) for k, v in draws.items()}
        present = (rts != 0).any(dim=-1)  # (B, T): missing rows stay all zero
        out = rts.clone()
        out[..., self._brightness[0]] += draws["brightness"]
        out[..., self._contrast[0]] *= draws["contrast"]
        out[..., self._entropy[0]] += draws["entropy"]
        out[..., self._laplacian[0]] += draws["laplacian"]
        for index in self._counts:
            out[..., index] *= draws["counts"]
        out = torch.where(present.unsqueeze(-1), out, rts)
        if psd.ndim != 5:  # models of the RTS window only get an empty PSD tensor
            return out, psd
        layer = psd[..., KEYPOINT_LAYER].to(torch.float32)
        gain = draws["keypoint"].view(n, 1, 1, 1)
        scaled = torch.where(layer > 0, (layer * gain).round().clamp(1, 255), layer).to(torch.uint8)
        psd = psd.clone()
        psd[..., KEYPOINT_LAYER] = scaled
        return out, psd
