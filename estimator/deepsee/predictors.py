"""Any trained model file as one thing that maps windows to estimates: a PyTorch checkpoint (DeepSEE, an
ablation, the LSTM), an exported ONNX model, or the random forest's pickle. Each is checked against this
installation's RTS schema, windows and label transform before it is used."""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from estimator.deepsee.baselines import window_statistics
from estimator.deepsee.checkpoint import ModelMismatch, check_compatible, load_model
from estimator.deepsee.data import Windows
from estimator.deepsee.export import OnnxModel
from estimator.deepsee.inference import predict
from estimator.deepsee.transforms import LabelTransform
from seesys.protocol.windows import WindowConfig, load_window_config


@dataclass
class Predictor:
    """``transformed(windows)``: outputs on the transformed scale; ``metres(windows)``: estimates in metres."""

    path: Path
    kind: str
    transform: LabelTransform
    _run: object
    batch_size: int

    def transformed(self, windows: Windows) -> np.ndarray:
        return self._run(windows)

    def metres(self, windows: Windows) -> np.ndarray:
        return self.transform.inverse(self.transformed(windows))


def _onnx_runner(model: OnnxModel, batch_size: int):
    def run(windows: Windows) -> np.ndarray:
        out = [model(windows.rts[s:s + batch_size], np.stack([windows.psd_at(i) for i in
                                                              range(s, min(s + batch_size, len(windows)))]))
               for s in range(0, len(windows), batch_size)]
        return np.concatenate(out) if out else np.zeros(0, np.float32)
    return run


def load_predictor(path: Path, transform: LabelTransform, batch_size: int, device: torch.device | None = None,
                   windows: WindowConfig | None = None) -> Predictor:
    """The model of ``path`` by its suffix: ``.onnx``, ``.pkl`` (random forest), else a PyTorch checkpoint."""
    path = Path(path)
    windows = windows or load_window_config()
    if path.suffix == ".onnx":
        return Predictor(path, "onnx", transform, _onnx_runner(OnnxModel(path, transform, windows), batch_size),
                         batch_size)
    if path.suffix == ".pkl":
        try:
            record = pickle.loads(path.read_bytes())
        except FileNotFoundError:
            raise ModelMismatch(f"model file not found: {path}") from None
        except (pickle.UnpicklingError, EOFError, AttributeError) as e:
            raise ModelMismatch(f"{path} is not a random-forest model file: {e}") from None
        check_compatible(record["compatibility"], str(path), windows, transform)
        forest = record["forest"]
        return Predictor(path, "random_forest", transform,
                         lambda w: forest.predict(window_statistics(w.rts)).astype(np.float32), batch_size)
    device = device or torch.device("cpu")
    model, payload = load_model(path, transform, windows)
    model = model.to(device)
    return Predictor(path, payload["model"]["kind"], transform, lambda w: predict(model, w, batch_size, device),
                     batch_size)
