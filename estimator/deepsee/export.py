"""The served model: ONNX export with the weights inside the one file and a parity check against PyTorch. The
ONNX Runtime session that serves it, without PyTorch, is :class:`estimator.artefact.onnx_model.OnnxModel`.

The exported graph takes ``rts`` (B, T, C) float32 (normalised) and ``psd`` (B, K_L, H, W, 3) uint8 and returns ``y``
(B,), the transformed error, and, for a model with an ordinal head, a second output ``probabilities`` (B, K): P(error ≥
t_k) (the sigmoid is inside the graph); the batch size is dynamic. The checkpoint's compatibility record and hash
(:mod:`estimator.deepsee.checkpoint`: windows, label, RTS schema and the device settings the model was trained with) are
stored in the ONNX metadata. Weights are never written to a side file: a copied ``.onnx`` with a stale ``.onnx.data``
beside it once served other weights silently.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from estimator.artefact.compatibility import compatibility
from estimator.artefact.onnx_model import DEEPSEE_KIND, PROBABILITIES, OnnxModel, Y, export_metadata
from estimator.artefact.standardisation import METADATA_KEY, InputStandardisation
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.config import ModelConfig, load_estimator_config
from estimator.deepsee.model import DeepSEE, InputShape, exceedance_probabilities
from seesys.core import rts_schema
from seesys.core.windows import WindowConfig

PARITY_TOLERANCE = 1e-4


def example_inputs(shape, batch: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Random inputs of the model's shape: normalised-looking RTS rows and sparse PSD matrices."""
    g = torch.Generator().manual_seed(seed)
    rts = torch.randn(batch, shape.rts_length, shape.channels, generator=g)
    cells = torch.rand(batch, shape.psd_samples, shape.psd_height, shape.psd_width, 3, generator=g)
    psd = torch.where(cells < 0.3, (cells * 850).clamp(1, 255), torch.zeros(())).to(torch.uint8)
    return rts, psd


class _WithProbabilities(nn.Module):
    """A model with an ordinal head as served: its logits turned into probabilities inside the graph."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, rts: torch.Tensor, psd: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y, logits = self.model(rts, psd)
        return y, exceedance_probabilities(logits)


def _served(model: nn.Module) -> tuple[nn.Module, list[str]]:
    """What is exported, and its output names: the model itself (``y``), or with its head's probabilities."""
    if getattr(model, "thresholds_m", ()):
        return _WithProbabilities(model).eval(), [Y, PROBABILITIES]
    return model, [Y]


def export_onnx(
    model: nn.Module,
    path: Path,
    windows: WindowConfig,
    transform: LabelTransform,
    record: dict | None = None,
    cameras: list[str] | None = None,
    standardisation: InputStandardisation | None = None,
) -> Path:
    """Write ``model`` (a DeepSEE) as one self-contained ONNX file with its compatibility record: ``record`` (a
    checkpoint's, which loading it has checked against this installation), or this installation's; and, when
    given, the ``cameras`` it was trained and fine-tuned on (:func:`estimator.artefact.onnx_model.training_cameras`)
    and its input ``standardisation`` (a checkpoint's)."""
    model = model.eval().cpu()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    batch = torch.export.Dim("batch", min=1, max=4096)
    served, outputs = _served(model)
    with contextlib.redirect_stdout(io.StringIO()):  # the exporter narrates every step
        program = torch.onnx.export(
            served,
            example_inputs(model.shape, 2),
            dynamo=True,
            external_data=False,
            input_names=["rts", "psd"],
            output_names=outputs,
            dynamic_shapes=({0: batch}, {0: batch}),
            optimize=True,
        )
    assert program is not None  # the dynamo exporter returns its program (only the legacy one returns None)
    proto = program.model_proto
    record = (
        record
        if record is not None
        else compatibility(windows, transform, head_thresholds_m=getattr(model, "thresholds_m", ()))
    )
    metadata = export_metadata(record, DEEPSEE_KIND, cameras)
    if standardisation is not None:
        metadata.append((METADATA_KEY, json.dumps(standardisation.as_record())))
    for key, value in metadata:
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save_model(proto, str(path), save_as_external_data=False)
    return path


def parity(model: nn.Module, onnx_model: OnnxModel, batches: tuple[int, ...] = (1, 7)) -> float:
    """Largest absolute difference between PyTorch and ONNX Runtime outputs on random inputs: the transformed
    error and, for a model with a head, its probabilities. A head on one side only is an infinite difference."""
    served, _ = _served(model.eval().cpu())
    worst = 0.0
    for k, batch in enumerate(batches):
        rts, psd = example_inputs(model.shape, batch, seed=k + 1)
        with torch.no_grad():
            expected = served(rts, psd)
        expected = expected if isinstance(expected, tuple) else (expected, None)
        got = onnx_model.outputs(rts.numpy(), psd.numpy())
        if (expected[1] is None) != (got[1] is None):
            return float("inf")
        for want, have in zip(expected, got):
            if want is not None:
                worst = max(worst, float(np.abs(have - want.numpy()).max()))
    return worst


def export_untrained(
    path: Path,
    windows: WindowConfig,
    psd_size: tuple[int, int],
    seed: int,
    model_config: ModelConfig | None = None,
    thresholds_m: tuple[float, ...] = (),
) -> Path:
    """Export DeepSEE of the configured size (configs/estimator.toml, or ``model_config``) with untrained weights
    (seeded), with an ordinal head of ``thresholds_m`` (none by default): the model of the right shape and cost to
    serve until a trained one ships. Its estimates mean nothing."""
    config = load_estimator_config()
    torch.manual_seed(seed)
    height, width = psd_size
    shape = InputShape(windows.rts_length, rts_schema.NUM_CHANNELS, windows.psd_samples, height, width)
    model = DeepSEE(model_config or config.model, shape, thresholds_m=thresholds_m)
    return export_onnx(model, Path(path), windows, LabelTransform(config.label_transform.k))
