"""The served model: ONNX export with the weights inside the one file, a parity check against PyTorch, and an
ONNX Runtime session that refuses a model made for other inputs.

The exported graph takes ``rts`` (B, T, C) float32 (normalised) and ``psd`` (B, K_L, H, W, 3) uint8 and returns
``y`` (B,), the transformed error; the batch size is dynamic. The checkpoint's compatibility record and hash
(:mod:`estimator.deepsee.checkpoint`) are stored in the ONNX metadata. Weights are never written to a side file:
a copied ``.onnx`` with a stale ``.onnx.data`` beside it once served other weights silently.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

from estimator.deepsee.checkpoint import ModelMismatch, check_compatible, compatibility, compatibility_hash
from estimator.deepsee.model import InputShape
from estimator.deepsee.transforms import LabelTransform
from seesys.protocol.windows import WindowConfig, load_window_config

COMPATIBILITY_KEY = "seesys_compatibility"
HASH_KEY = "seesys_compatibility_hash"
PARITY_TOLERANCE = 1e-4


def example_inputs(shape, batch: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Random inputs of the model's shape: normalised-looking RTS rows and sparse PSD matrices."""
    g = torch.Generator().manual_seed(seed)
    rts = torch.randn(batch, shape.rts_length, shape.channels, generator=g)
    cells = torch.rand(batch, shape.psd_samples, shape.psd_height, shape.psd_width, 3, generator=g)
    psd = torch.where(cells < 0.3, (cells * 850).clamp(1, 255), torch.zeros(())).to(torch.uint8)
    return rts, psd


def export_onnx(model: nn.Module, path: Path, windows: WindowConfig, transform: LabelTransform) -> Path:
    """Write ``model`` (a DeepSEE) as one self-contained ONNX file with its compatibility record."""
    model = model.eval().cpu()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    batch = torch.export.Dim("batch", min=1, max=4096)
    with contextlib.redirect_stdout(io.StringIO()):  # the exporter narrates every step
        program = torch.onnx.export(model, example_inputs(model.shape, 2), dynamo=True, external_data=False,
                                    input_names=["rts", "psd"], output_names=["y"],
                                    dynamic_shapes=({0: batch}, {0: batch}), optimize=True)
    proto = program.model_proto
    record = compatibility(windows, transform)
    for key, value in ((COMPATIBILITY_KEY, json.dumps(record, sort_keys=True)), (HASH_KEY, compatibility_hash(record))):
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save_model(proto, str(path), save_as_external_data=False)
    return path


class OnnxModel:
    """An ONNX Runtime session of an exported model on ``threads`` intra-op threads (1: the serving setting; a
    second thread helps little and, with anything else running, costs more than it gives)."""

    def __init__(self, path: Path, transform: LabelTransform, windows: WindowConfig | None = None, threads: int = 1):
        path = Path(path)
        try:
            proto = onnx.load_model(str(path), load_external_data=False)
        except FileNotFoundError:
            raise ModelMismatch(f"model file not found: {path}") from None
        except Exception as e:  # onnx raises DecodeError and others on a file that is not a model
            raise ModelMismatch(f"{path} is not an ONNX model: {e}") from None
        meta = {p.key: p.value for p in proto.metadata_props}
        if COMPATIBILITY_KEY not in meta:
            raise ModelMismatch(f"{path} carries no SEESys compatibility record: not exported by seesys estimator")
        check_compatible(json.loads(meta[COMPATIBILITY_KEY]), str(path), windows or load_window_config(), transform)
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self.session = ort.InferenceSession(proto.SerializeToString(), options, providers=["CPUExecutionProvider"])
        rts, psd = (i.shape[1:] for i in self.session.get_inputs())
        self.shape = InputShape(*rts, *psd[:3])

    def __call__(self, rts: np.ndarray, psd: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"rts": np.ascontiguousarray(rts, np.float32),
                                       "psd": np.ascontiguousarray(psd, np.uint8)})[0]


def parity(model: nn.Module, onnx_model: OnnxModel, batches: tuple[int, ...] = (1, 7)) -> float:
    """Largest absolute difference between PyTorch and ONNX Runtime outputs (transformed scale) on random inputs."""
    model = model.eval().cpu()
    worst = 0.0
    for k, batch in enumerate(batches):
        rts, psd = example_inputs(model.shape, batch, seed=k + 1)
        with torch.no_grad():
            expected = model(rts, psd).numpy()
        worst = max(worst, float(np.abs(onnx_model(rts.numpy(), psd.numpy()) - expected).max()))
    return worst
