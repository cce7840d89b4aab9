"""The model a worker serves: an exported ONNX model (checked against this installation's RTS schema, windows,
label and device settings when loaded), its version string, the window shape it accepts, the device settings it
was made for (every device's frames are checked against them), its ordinal head's thresholds (none for a model
without a head: its estimates carry no probabilities) and the ONNX Runtime execution provider that runs it (an
untrained stand-in of the right shape: :func:`estimator.deepsee.export.export_untrained`).

Serving imports neither PyTorch nor the ``onnx`` package (:mod:`estimator.artefact.onnx_model`): a worker starts in
well under a second plus the model's load."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.artefact.compatibility import ModelSetup
from estimator.artefact.onnx_model import OnnxModel
from estimator.artefact.transforms import LabelTransform, prepare_rts_counted
from estimator.deepsee.config import load_estimator_config
from seesys.core.device_settings import DeviceSettings, settings_differences
from seesys.core.messages import Exceedance
from seesys.core.windows import WindowConfig, WindowSample


def model_version(path: Path) -> str:
    """``<file stem>-<first 12 hex digits of the file's SHA-256>``: names the exact weights an estimate came from."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return f"{Path(path).stem}-{digest[:12]}"


@dataclass(frozen=True)
class BatchEstimates:
    """One batched run: errors in metres (B,), the head's P(error ≥ t_k) (B, K) for ``thresholds_m`` (None without
    a head), and per sample how many RTS values were not finite and became 0."""

    errors_m: np.ndarray
    probabilities: np.ndarray | None
    nonfinite: np.ndarray
    thresholds_m: tuple[float, ...] = ()

    def head(self, sample: int) -> tuple[Exceedance, ...]:
        """Sample ``sample``'s head as an :class:`~seesys.core.messages.Estimate` carries it (empty: no head)."""
        if self.probabilities is None:
            return ()
        return tuple(Exceedance(t, float(p)) for t, p in zip(self.thresholds_m, self.probabilities[sample]))


@dataclass(frozen=True)
class ModelInputs:
    """A batch as the model takes it: RTS (B, T, C) float32 standardised, PSD (B, K_L, H, W, 3) uint8, and per
    window how many RTS values were not finite and became 0."""

    rts: np.ndarray
    psd: np.ndarray
    nonfinite: np.ndarray


@dataclass
class ServedModel:
    """``estimate(samples)``: errors in metres for windows of several devices, in one batched run."""

    version: str
    psd_shape: tuple[int, int, int, int]  # (K_L, H, W, 3) of one window
    provider: str  # the ONNX Runtime execution provider that runs it, e.g. CPUExecutionProvider
    device_record: dict  # the device settings it was made for (record["device"])
    _model: OnnxModel
    _transform: LabelTransform
    _zeros: dict[int, np.ndarray] = field(default_factory=dict)

    @classmethod
    def load(
        cls,
        path: Path,
        windows: WindowConfig,
        threads: int = 1,
        providers: str = "auto",
        setup: ModelSetup | None = None,
    ) -> ServedModel:
        """Load ``path`` on ``threads`` intra-op threads and the execution providers of ``providers`` (``auto``,
        ``cpu`` or ``cuda``: see :mod:`estimator.artefact.onnx_model`); raises ``ModelMismatch`` for a model made
        for other inputs (naming each field that differs from ``windows`` and ``setup``, this installation's
        configs by default) or a file that is not one, ``ConfigError`` for a provider setting that cannot be
        met."""
        transform = LabelTransform(load_estimator_config().label_transform.k)
        model = OnnxModel(Path(path), transform, windows, threads, providers, setup)
        _, layers, height, width, channels = model.session.get_inputs()[1].shape  # (batch, K_L, H, W, 3)
        return cls(
            model_version(path),
            (int(layers), int(height), int(width), int(channels)),
            model.provider,
            dict(model.record.get("device", {})),
            model,
            transform,
        )

    @property
    def reads_psd(self) -> bool:
        """Whether the model reads the PSD: without, windows are formed without PSDs and the graph's PSD input is
        fed zeros (:meth:`prepare`)."""
        return self._model.reads_psd

    def accepts(self, sample: WindowSample) -> bool:
        return not self.reads_psd or sample.psd.shape == self.psd_shape

    def settings_differences(self, settings: DeviceSettings | None) -> list[str]:
        """How a device's stated settings differ from the model's (empty: served)."""
        if settings is None:
            return ["the device states no settings"]
        return settings_differences(self.device_record, settings)

    @property
    def thresholds_m(self) -> tuple[float, ...]:
        """The ordinal head's thresholds, one per column of :attr:`BatchEstimates.probabilities`; empty: no head."""
        return self._model.thresholds_m

    def estimate(self, samples: list[WindowSample]) -> np.ndarray:
        return self.estimate_batch(samples).errors_m

    def estimate_batch(self, samples: list[WindowSample]) -> BatchEstimates:
        """The errors and head probabilities of ``samples``, and how many of each one's RTS values became 0."""
        return self.run(self.prepare(samples))

    def prepare(self, samples: list[WindowSample]) -> ModelInputs:
        """``samples`` as the model takes them: stacked, the RTS normalised and standardised (the worker times
        this apart from :meth:`run`)."""
        rts, replaced = prepare_rts_counted(np.stack([s.rts for s in samples]), self._model.rts_columns)
        if not self.reads_psd:
            psd = self._unread_psd(len(samples))
        elif len(samples) == 1:
            # One window, the most common batch below capacity, is passed as a view: its PSDs (147 kB) are not copied.
            psd = samples[0].psd[None]
        else:
            psd = np.stack([s.psd for s in samples])
        return ModelInputs(self._model.standardised(rts), psd, replaced)

    def _unread_psd(self, batch: int) -> np.ndarray:
        """Zeros for the PSD input a model declares and does not read, one array per batch size, made once."""
        psd = self._zeros.get(batch)
        if psd is None:
            psd = self._zeros[batch] = np.zeros((batch, *self.psd_shape), np.uint8)
        return psd

    def run(self, inputs: ModelInputs) -> BatchEstimates:
        """One ONNX Runtime run of prepared inputs, its outputs mapped back to metres."""
        y, probabilities = self._model.outputs(inputs.rts, inputs.psd)
        return BatchEstimates(self._transform.inverse(y), probabilities, inputs.nonfinite, self.thresholds_m)
