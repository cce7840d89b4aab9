"""Any trained model file as one thing that maps windows to estimates: a PyTorch checkpoint (DeepSEE, an
ablation, the LSTM), an exported ONNX model, or the random forest's pickle. Each is checked against this
installation's RTS schema, windows and label transform before it is used. A DeepSEE with an ordinal head (a
checkpoint or its ONNX export) also gives its head's probabilities P(error ≥ t_k); every other model gives None.

PyTorch and scikit-learn are imported only for the kinds that need them: loading an ONNX model imports neither.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator.artefact.compatibility import (
    InputShape,
    ModelMismatch,
    check_compatible,
    check_normalisation,
    rts_columns,
)
from estimator.artefact.onnx_model import OnnxModel
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.data import NORMALISATION_COLUMN, DataError, Windows
from seesys.core.windows import WindowConfig
from seesys.io.core_settings import load_window_config

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class WindowEstimates:
    """A model's estimates of N windows: metres (N,), and its head's P(error ≥ t_k) (N, K) or None."""

    metres: np.ndarray
    probabilities: np.ndarray | None


@dataclass
class Predictor:
    """``transformed(windows)``: outputs on the transformed scale; ``metres(windows)``: estimates in metres;
    ``estimates(windows)``: both the metres and the head's probabilities from one run. ``shape``: the window the
    model was made for (PSD sizes 0: a model of the RTS window only); ``columns``: the RTS channels it takes, as
    columns of this schema's rows; ``record``: its compatibility record; ``thresholds_m``: its head's thresholds,
    one per column of the probabilities (empty: no head)."""

    path: Path
    kind: str
    transform: LabelTransform
    _run: Callable[[Windows], tuple[np.ndarray, np.ndarray | None]]  # → (transformed outputs, head probabilities)
    shape: InputShape
    columns: np.ndarray
    record: dict
    thresholds_m: tuple[float, ...] = ()

    def outputs(self, windows: Windows) -> tuple[np.ndarray, np.ndarray | None]:
        """Transformed-scale outputs and head probabilities (None without a head); raises ``DataError`` for
        windows of another shape than the model's and ``ModelMismatch`` for windows of another camera
        normalisation."""
        if NORMALISATION_COLUMN in windows.meta:
            check_normalisation(self.record, windows.meta[NORMALISATION_COLUMN], f"windows of {_runs(windows)}")
        windows = windows.select_rts(self.columns)
        if len(windows):
            self.check(windows.input_shape())
        return self._run(windows)

    def transformed(self, windows: Windows) -> np.ndarray:
        return self.outputs(windows)[0]

    def estimates(self, windows: Windows) -> WindowEstimates:
        y, probabilities = self.outputs(windows)
        return WindowEstimates(self.transform.inverse(y), probabilities)

    def check(self, shape: InputShape) -> None:
        """Raise :class:`DataError` when windows of ``shape`` are not what the model takes (another PSD grid)."""
        expected = (
            self.shape
            if self.shape.psd_samples
            else InputShape(
                self.shape.rts_length, self.shape.channels, shape.psd_samples, shape.psd_height, shape.psd_width
            )
        )
        if shape != expected:
            raise DataError(
                f"{self.path} takes windows of {expected}, these are {shape}: another PSD grid (another "
                f"reference camera or PSD cell size, or made before camera normalisation at the camera "
                f"resolution); record them again, or train a model for them"
            )

    def metres(self, windows: Windows) -> np.ndarray:
        return self.transform.inverse(self.transformed(windows))


def _runs(windows: Windows) -> str:
    """The runs or sessions ``windows`` come from, for a message."""
    runs = sorted(set(windows.meta.get("run", [])))
    return ", ".join(runs[:3]) + (f" and {len(runs) - 3} more" if len(runs) > 3 else "")


def _onnx_runner(model: OnnxModel, batch_size: int) -> Callable[[Windows], tuple[np.ndarray, np.ndarray | None]]:
    def run(windows: Windows) -> tuple[np.ndarray, np.ndarray | None]:
        out = [
            model.outputs(
                model.standardised(windows.rts[s : s + batch_size]),
                np.stack([windows.psd_at(i) for i in range(s, min(s + batch_size, len(windows)))]),
            )
            for s in range(0, len(windows), batch_size)
        ]
        y = np.concatenate([o[0] for o in out]) if out else np.zeros(0, np.float32)
        if not model.thresholds_m:
            return y, None
        return y, (np.concatenate([o[1] for o in out]) if out else np.zeros((0, len(model.thresholds_m)), np.float32))

    return run


def read_forest(path: Path, windows: WindowConfig, transform: LabelTransform) -> dict:
    """A random forest's model file (``model.pkl``: ``forest``, ``compatibility``, ``training``), checked against
    this installation; raises :class:`ModelMismatch` for a missing file, another kind of file or a forest made for
    other inputs."""
    try:
        record = pickle.loads(Path(path).read_bytes())
    except FileNotFoundError:
        raise ModelMismatch(f"model file not found: {path}") from None
    except (pickle.UnpicklingError, EOFError, AttributeError) as e:
        raise ModelMismatch(f"{path} is not a random-forest model file: {e}") from None
    if not isinstance(record, dict) or "forest" not in record or "compatibility" not in record:
        raise ModelMismatch(f"{path} is not a random-forest model file: no forest and compatibility record")
    check_compatible(record["compatibility"], str(path), windows, transform)
    return record


def load_predictor(
    path: Path,
    transform: LabelTransform,
    batch_size: int,
    device: torch.device | None = None,
    windows: WindowConfig | None = None,
) -> Predictor:
    """The model of ``path`` by its suffix: ``.onnx``, ``.pkl`` (random forest), else a PyTorch checkpoint."""
    path = Path(path)
    windows = windows or load_window_config()
    if path.suffix == ".onnx":
        onnx = OnnxModel(path, transform, windows)
        return Predictor(
            path,
            "onnx",
            transform,
            _onnx_runner(onnx, batch_size),
            onnx.shape,
            onnx.rts_columns,
            onnx.record,
            onnx.thresholds_m,
        )
    if path.suffix == ".pkl":
        from estimator.deepsee.forest import window_statistics

        record = read_forest(path, windows, transform)
        forest = record["forest"]
        columns = rts_columns(record["compatibility"], str(path))
        return Predictor(
            path,
            "random_forest",
            transform,
            lambda w: (forest.predict(window_statistics(w.rts)).astype(np.float32), None),
            InputShape(windows.rts_length, len(columns), 0, 0, 0),
            columns,
            record["compatibility"],
        )
    import torch

    from estimator.deepsee.baselines import LstmBaseline
    from estimator.deepsee.checkpoint import load_model, payload_standardisation
    from estimator.deepsee.inference import predict_outputs
    from estimator.deepsee.model import DeepSEE
    from estimator.deepsee.ordinal import model_thresholds

    device = device or torch.device("cpu")
    model, payload = load_model(path, transform, windows)
    model = model.to(device)
    if isinstance(model, DeepSEE):
        shape = model.shape
    elif isinstance(model, LstmBaseline):  # a model of the RTS window only
        shape = InputShape(windows.rts_length, model.channels, 0, 0, 0)
    else:  # load_model builds no other kind
        raise TypeError(f"cannot predict with a {type(model).__name__}")
    standardisation = payload_standardisation(payload, str(path))
    channels = payload["compatibility"]["rts_channels"]
    return Predictor(
        path,
        payload["model"]["kind"],
        transform,
        lambda w: predict_outputs(model, w.with_rts(standardisation.apply(w.rts, channels)), batch_size, device),
        shape,
        rts_columns(payload["compatibility"], str(path)),
        payload["compatibility"],
        model_thresholds(model),
    )
