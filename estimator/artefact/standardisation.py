"""Per-camera input standardisation: the camera-dependent RTS channels a camera shifts (exposure, response curve,
sharpness) moved onto the distribution the model was trained on, with statistics refitted for each camera.

For each channel of ``[input_standardisation] camera_channels`` (configs/estimator.toml) a model stores two sets
of robust statistics of its normalised values (:func:`seesys.core.rts_schema.normalise`): the median and the
interquartile range over the windows it was trained on (``reference``) and over the camera it serves
(``camera``). Its input is ``x' = (x − median_camera) · iqr_reference / iqr_camera + median_reference``: the camera's
spread of the channel onto the training data's.

- A model trained here fits both on its training windows: the camera is its training mixture and x' = x exactly
  (nothing is computed). It serves the cameras of its training data as they are.
- ``seesys estimator finetune`` refits the camera's statistics on the new camera's sessions and keeps the reference:
  the fine-tuned model reads the new camera's channels as the training camera's would read. A base model whose
  reference is unknown (``reference`` None: the shipped model, trained before standardisation, whose training data
  is not here) cannot be mapped; fine-tuning it trains on the sessions as they are, so those sessions' statistics
  become both its reference and its camera.
- A model file without a record (made before standardisation) is the identity, as it was trained.

Robust statistics, because a camera's sessions hold frames of lost or blurred tracking whose channels are extreme
(those windows are the ones whose errors matter). The standardisation does take away what a channel says of a whole
camera: a camera that is blurrier on every frame reads as sharp as the training camera. It is what makes one
camera's absolute levels comparable with another's, at that price; the rest of each channel's variation stays.
Recorded in the checkpoint (``input_standardisation``) and the ONNX metadata (``seesys_input_standardisation``) and
applied by whatever runs the model (:class:`estimator.deepsee.predictors.Predictor`, the service's
:class:`estimator.service.model.ServedModel`, fine-tuning), outside the network, so that a model file without it,
the shipped one included, keeps its graph.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from seesys.core.errors import SeesysError

#: The ONNX metadata key of the record (:meth:`InputStandardisation.as_record`).
METADATA_KEY = "seesys_input_standardisation"
#: The checkpoint's key of the record.
CHECKPOINT_KEY = "input_standardisation"
# An IQR this small is a channel that does not vary (a monocular session's depth channels): it is left as it is.
_MIN_IQR = 1e-6


class StandardisationError(SeesysError):
    """A model's input standardisation record is malformed or does not fit its channels."""


@dataclass(frozen=True)
class ChannelStatistics:
    """Median and interquartile range of each standardised channel's normalised values, in channel order."""

    median: tuple[float, ...]
    iqr: tuple[float, ...]

    @classmethod
    def of(cls, values: np.ndarray) -> ChannelStatistics:
        """Of ``values`` (N, C)."""
        if not len(values):
            raise StandardisationError("no RTS rows to fit the input standardisation on")
        low, median, high = np.percentile(np.asarray(values, np.float64), [25, 50, 75], axis=0)
        return cls(tuple(float(v) for v in median), tuple(float(v) for v in high - low))


@dataclass(frozen=True)
class InputStandardisation:
    """The standardised ``channels`` (names) with the model's ``reference`` and ``camera`` statistics; ``reference``
    None: the model's training statistics are unknown, and its input is left as it is."""

    channels: tuple[str, ...]
    reference: ChannelStatistics | None
    camera: ChannelStatistics | None

    @classmethod
    def identity(cls) -> InputStandardisation:
        """What a model made before standardisation reads: its input as it is."""
        return cls((), None, None)

    @classmethod
    def fitted(cls, rts: np.ndarray, model_channels: Sequence[str], channels: Sequence[str]) -> InputStandardisation:
        """Fitted on a model's training windows ``rts`` (N, T, C) of ``model_channels``: reference = camera."""
        stats = _statistics(rts, model_channels, channels)
        return cls(tuple(channels), stats, stats)

    def refitted(self, rts: np.ndarray, model_channels: Sequence[str]) -> InputStandardisation:
        """The camera's statistics fitted again on a new camera's windows ``rts`` (their inputs as they are, not
        standardised), the reference kept; a model without a reference gets the new statistics as both."""
        stats = _statistics(rts, model_channels, self.channels)
        return InputStandardisation(self.channels, self.reference if self.reference is not None else stats, stats)

    def apply(self, rts: np.ndarray, model_channels: Sequence[str]) -> np.ndarray:
        """The model's input: ``rts`` (..., C) of ``model_channels`` standardised (the same array where the map is
        the identity)."""
        if self.reference is None or self.camera is None or self.reference == self.camera:
            return rts
        columns = _columns(model_channels, self.channels)
        camera_median, camera_iqr = np.array(self.camera.median), np.array(self.camera.iqr)
        reference_median, reference_iqr = np.array(self.reference.median), np.array(self.reference.iqr)
        varies = (camera_iqr > _MIN_IQR) & (reference_iqr > _MIN_IQR)
        gain = np.where(varies, reference_iqr / np.where(varies, camera_iqr, 1.0), 1.0)
        offset = np.where(varies, reference_median - camera_median * gain, 0.0)
        out = np.array(rts, dtype=np.float32, copy=True)
        selected = out[..., columns]
        # missing rows stay all zero, as the model was trained to see them
        present = np.any(out != 0, axis=-1, keepdims=True)
        out[..., columns] = np.where(present, selected * gain + offset, selected).astype(np.float32)
        return out

    def as_record(self) -> dict:
        def stats(s: ChannelStatistics | None) -> dict | None:
            return None if s is None else {"median": list(s.median), "iqr": list(s.iqr)}

        return {"channels": list(self.channels), "reference": stats(self.reference), "camera": stats(self.camera)}

    @classmethod
    def from_record(cls, record: dict | None, source: str) -> InputStandardisation:
        """From :meth:`as_record`; None (a model file made before standardisation) is the identity."""
        if record is None:
            return cls.identity()
        try:
            channels = tuple(str(c) for c in record["channels"])

            def stats(data: dict | None) -> ChannelStatistics | None:
                if data is None:
                    return None
                out = ChannelStatistics(tuple(float(v) for v in data["median"]), tuple(float(v) for v in data["iqr"]))
                if len(out.median) != len(channels) or len(out.iqr) != len(channels):
                    raise ValueError(f"{len(channels)} channels but {len(out.median)} medians, {len(out.iqr)} IQRs")
                return out

            return cls(channels, stats(record["reference"]), stats(record["camera"]))
        except (KeyError, TypeError, ValueError) as e:
            raise StandardisationError(f"{source}: malformed input standardisation record ({e})") from None


def _columns(model_channels: Sequence[str], channels: Sequence[str]) -> list[int]:
    names = list(model_channels)
    missing = [c for c in channels if c not in names]
    if missing:
        raise StandardisationError(
            f"the input standardisation names channels the model does not take: {', '.join(missing)}"
        )
    return [names.index(c) for c in channels]


def _statistics(rts: np.ndarray, model_channels: Sequence[str], channels: Sequence[str]) -> ChannelStatistics:
    """Of the windows ``rts`` (N, T, C), rows that are all zero (missing rows after normalisation) left out."""
    rows = np.asarray(rts).reshape(-1, np.asarray(rts).shape[-1])
    present = rows[np.any(rows != 0, axis=-1)]
    return ChannelStatistics.of(present[:, _columns(model_channels, channels)])
