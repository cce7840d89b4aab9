"""The label transform and the input ablation masks, in one place.

Label (paper §5.2): the 10-frame RPE is heavily right-skewed, so every model regresses
``y = log(1 + k · error_m)`` (k = 10,000: 1 mm → 2.4, 1 cm → 4.6, 10 cm → 6.9) and estimates are mapped back
with ``(exp(y) − 1) / k``. Estimates below zero on the transformed scale map to negative metres; they are
clipped to 0, the smallest error there is.

Ablation masks (Table 3): a channel category of the RTS window (sensor input, tracking, mapping, ...: the categories
of :mod:`seesys.core.rts_schema`) or a layer of the PSD matrices (keypoint, inlier, map point) is set to zero,
in training and in inference alike, so the model never sees it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seesys.core import psd as psd_layers
from seesys.core import rts_schema

PSD_LAYERS = {
    "keypoint": psd_layers.KEYPOINT_LAYER,
    "inlier": psd_layers.INLIER_LAYER,
    "map_point": psd_layers.MAP_POINT_LAYER,
}


@dataclass(frozen=True)
class LabelTransform:
    """``forward(error_m) = log1p(k · error_m)``; ``inverse`` undoes it (clipped at 0 m)."""

    k: float

    def forward(self, error_m: np.ndarray | float) -> np.ndarray:
        return np.log1p(self.k * np.asarray(error_m, dtype=np.float64))

    def inverse(self, y: np.ndarray | float) -> np.ndarray:
        return np.maximum(np.expm1(np.asarray(y, dtype=np.float64)) / self.k, 0.0)

    def describe(self) -> dict:
        return {"name": "log1p_scaled", "k": self.k}


def rts_channel_mask(
    drop_categories: tuple[str, ...] = (),
    channels: tuple[str, ...] | None = None,
    drop_channels: tuple[str, ...] = (),
) -> np.ndarray:
    """(C,) float32 over ``channels`` (names; default every channel of the schema, in its order): 1 for the RTS
    channels the model sees, 0 for those of the dropped categories and for the dropped channels themselves. Raises
    ValueError naming an unknown category or channel."""
    unknown = sorted(set(drop_categories) - set(rts_schema.CATEGORIES))
    if unknown:
        raise ValueError(f"unknown RTS categories {unknown}; categories are {', '.join(rts_schema.CATEGORIES)}")
    unknown = sorted(set(drop_channels) - set(rts_schema.CHANNEL_NAMES))
    if unknown:
        raise ValueError(f"unknown RTS channels {unknown}; channels are {', '.join(rts_schema.CHANNEL_NAMES)}")
    category = {c.name: c.category for c in rts_schema.CHANNELS}
    names = rts_schema.CHANNEL_NAMES if channels is None else channels
    return np.array(
        [0.0 if category[name] in drop_categories or name in drop_channels else 1.0 for name in names], np.float32
    )


def psd_layer_mask(drop_layers: tuple[str, ...] = ()) -> np.ndarray:
    """(3,) float32: 1 for the PSD layers the model sees, 0 for the dropped ones."""
    unknown = sorted(set(drop_layers) - set(PSD_LAYERS))
    if unknown:
        raise ValueError(f"unknown PSD layers {unknown}; layers are {', '.join(PSD_LAYERS)}")
    mask = np.ones(psd_layers.NUM_LAYERS, np.float32)
    for name in drop_layers:
        mask[PSD_LAYERS[name]] = 0.0
    return mask


def prepare_rts(raw: np.ndarray) -> np.ndarray:
    """Raw RTS windows (..., T, C), NaN where missing, as the model's float32 input (schema normalisation)."""
    return rts_schema.normalise(raw)


def prepare_rts_counted(raw: np.ndarray, columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`prepare_rts` of the model's ``columns`` (all by default), and per window (shape ``raw.shape[:-2]``)
    how many of their values were not finite and became 0."""
    rts, replaced = rts_schema.normalise_counted(raw, columns)
    return rts, replaced.sum(axis=-1)
