"""An exported model served by ONNX Runtime, without PyTorch (``import torch`` costs a worker seconds of start-up).

The exported graph (:mod:`estimator.deepsee.export`) takes ``rts`` (B, T, C) float32 (normalised) and ``psd``
(B, K_L, H, W, 3) uint8 and returns ``y`` (B,), the transformed error, and for a model with an ordinal head
``probabilities`` (B, K), P(error ≥ t_k) for the thresholds its record states. Its metadata carries the
compatibility record (:mod:`estimator.artefact.compatibility`); a model made for other inputs is refused when it is
loaded.

Execution providers: ``"cpu"`` runs on the CPU; ``"cuda"`` on an NVIDIA GPU (an error where this ONNX Runtime
offers none); ``"auto"`` takes CUDA when ONNX Runtime lists it (``onnxruntime.get_available_providers()``) and the
CPU otherwise. ONNX Runtime falls back to the CPU by itself when a listed CUDA provider cannot start (a missing CUDA
library): :attr:`OnnxModel.provider` names the one that actually runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort

from estimator.artefact.compatibility import (
    InputShape,
    ModelMismatch,
    ModelSetup,
    check_compatible,
    compatibility_hash,
    head_thresholds_of,
    rts_columns,
)
from estimator.artefact.standardisation import METADATA_KEY, InputStandardisation
from estimator.artefact.transforms import LabelTransform
from seesys.core.errors import ConfigError
from seesys.core.windows import WindowConfig
from seesys.io.core_settings import load_window_config

COMPATIBILITY_KEY = "seesys_compatibility"
HASH_KEY = "seesys_compatibility_hash"
# The cameras the model was trained and fine-tuned on (JSON list of names): what the app tells its user.
CAMERAS_KEY = "seesys_cameras"
# Which model the graph is (DEEPSEE_KIND, FOREST_KIND): what can be done to adapt it to a camera differs.
KIND_KEY = "seesys_model_kind"
DEEPSEE_KIND = "deepsee"
FOREST_KIND = "random_forest"
#: The graph's output names: the transformed error, and the ordinal head's probabilities (a model with a head).
Y = "y"
PROBABILITIES = "probabilities"
PROVIDER_SETTINGS = ("auto", "cpu", "cuda")
CPU = "CPUExecutionProvider"
CUDA = "CUDAExecutionProvider"


def choose_providers(setting: str, available: list[str] | None = None) -> list[str]:
    """ONNX Runtime's provider list for ``setting`` (one of :data:`PROVIDER_SETTINGS`), best first; the CPU is
    always last, as ONNX Runtime's fallback. ``available`` defaults to what this ONNX Runtime offers."""
    if setting not in PROVIDER_SETTINGS:
        raise ConfigError(f"providers must be one of {', '.join(PROVIDER_SETTINGS)}, got {setting!r}")
    available = ort.get_available_providers() if available is None else available
    if setting == "cuda" and CUDA not in available:
        raise ConfigError(
            f"providers = 'cuda', but this ONNX Runtime offers only {', '.join(available)} "
            f"(install onnxruntime-gpu, or use 'auto' or 'cpu')"
        )
    if setting != "cpu" and CUDA in available:
        return [CUDA, CPU]
    return [CPU]


def export_metadata(record: dict, kind: str, cameras: list[str] | None) -> list[tuple[str, str]]:
    """The metadata an exported model carries (:data:`COMPATIBILITY_KEY` and its hash, :data:`KIND_KEY`, and
    :data:`CAMERAS_KEY` when ``cameras`` is given), as (key, value) pairs for the ONNX file's ``metadata_props``."""
    entries = [
        (COMPATIBILITY_KEY, json.dumps(record, sort_keys=True)),
        (HASH_KEY, compatibility_hash(record)),
        (KIND_KEY, kind),
    ]
    if cameras is not None:
        entries.append((CAMERAS_KEY, json.dumps(list(cameras))))
    return entries


def training_cameras(training: dict) -> list[str] | None:
    """The cameras a checkpoint's training record says it was trained on (the dataset's camera models) and then
    fine-tuned on (the sessions' sources), in that order; None when it records none (a model made before)."""
    if "cameras" not in training and "finetuned_cameras" not in training:
        return None
    return list(dict.fromkeys(list(training.get("cameras", [])) + list(training.get("finetuned_cameras", []))))


@dataclass(frozen=True)
class RecordedTraining:
    """What an exported model records of its training, read without loading it for inference: the kind of model
    (:data:`DEEPSEE_KIND` or :data:`FOREST_KIND`; DeepSEE for a file exported before the kind was recorded) and the
    cameras it was trained and fine-tuned on (None: it records none)."""

    kind: str
    cameras: list[str] | None


def recorded_training(path: Path) -> RecordedTraining | None:
    """:class:`RecordedTraining` of an exported model; None for a file that is not a readable ONNX model."""
    import onnx
    from google.protobuf.message import DecodeError

    try:
        proto = onnx.load(str(path), load_external_data=False)
    except (OSError, ValueError, DecodeError):
        return None
    meta = {entry.key: entry.value for entry in proto.metadata_props}
    return RecordedTraining(
        meta.get(KIND_KEY, DEEPSEE_KIND), json.loads(meta[CAMERAS_KEY]) if CAMERAS_KEY in meta else None
    )


class OnnxModel:
    """An ONNX Runtime session of an exported model on ``threads`` intra-op threads (1: the serving setting; a
    second thread helps little and, with anything else running, costs more than it gives) and the execution
    providers of ``providers`` (see the module's docstring).

    Raises :class:`ModelMismatch` for a missing file, a file that is not an ONNX model, one exported elsewhere
    (no compatibility record), one whose outputs are not what its record says (head thresholds without a
    ``probabilities`` output of as many columns, or the reverse) or one made for other inputs (windows, label,
    device settings of ``setup``: this installation's configs by default);
    :class:`~seesys.core.errors.ConfigError` for an unknown or unavailable ``providers`` setting.
    """

    def __init__(
        self,
        path: Path,
        transform: LabelTransform,
        windows: WindowConfig | None = None,
        threads: int = 1,
        providers: str = "cpu",
        setup: ModelSetup | None = None,
    ):
        path = Path(path)
        chosen = choose_providers(providers)
        try:
            # From bytes, not the path: ONNX Runtime then cannot read weights from a side file, so a copied model
            # with a stale ``.onnx.data`` beside it is refused instead of served with other weights.
            content = path.read_bytes()
        except FileNotFoundError:
            raise ModelMismatch(f"model file not found: {path}") from None
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            session = ort.InferenceSession(content, options, providers=chosen)
        except Exception as e:  # ONNX Runtime raises InvalidProtobuf, Fail and others on a file that is not a model
            raise ModelMismatch(f"{path} is not an ONNX model: {e}") from None
        meta = session.get_modelmeta().custom_metadata_map
        if COMPATIBILITY_KEY not in meta:
            raise ModelMismatch(f"{path} carries no SEESys compatibility record: not exported by seesys estimator")
        #: The model's compatibility record (:mod:`estimator.artefact.compatibility`).
        self.record: dict = json.loads(meta[COMPATIBILITY_KEY])
        # None: a model exported before the cameras were recorded
        self.cameras: list[str] | None = json.loads(meta[CAMERAS_KEY]) if CAMERAS_KEY in meta else None
        #: Which model the graph is (:data:`DEEPSEE_KIND` for a file exported before the kind was recorded).
        self.kind: str = meta.get(KIND_KEY, DEEPSEE_KIND)
        check_compatible(self.record, str(path), windows or load_window_config(), transform, setup)
        #: The columns of this schema's RTS rows the model takes: select them before :meth:`__call__`.
        self.rts_columns: np.ndarray = rts_columns(self.record, str(path))
        #: The per-camera input standardisation to apply to the selected columns before :meth:`__call__`.
        self.standardisation = InputStandardisation.from_record(
            json.loads(meta[METADATA_KEY]) if METADATA_KEY in meta else None, str(path)
        )
        self.session = session
        self.provider: str = session.get_providers()[0]
        rts, psd = (i.shape[1:] for i in session.get_inputs())
        self.shape = InputShape(*rts, *psd[:3])
        #: The ordinal head's thresholds (metres), one per column of the probabilities; empty without a head.
        self.thresholds_m: tuple[float, ...] = head_thresholds_of(self.record)
        outputs = {o.name: o.shape for o in session.get_outputs()}
        head_columns = outputs[PROBABILITIES][1] if PROBABILITIES in outputs else 0
        if head_columns != len(self.thresholds_m):
            raise ModelMismatch(
                f"{path} records {len(self.thresholds_m)} head threshold(s) but its graph gives "
                f"{head_columns} head probabilities"
            )

    @property
    def reads_psd(self) -> bool:
        """Whether the graph reads its PSD input: a forest declares one (every exported model takes the same two
        inputs) but computes from the RTS window alone."""
        return self.kind != FOREST_KIND

    def standardised(self, rts: np.ndarray) -> np.ndarray:
        """Normalised RTS windows of the model's columns as the model takes them (its input standardisation)."""
        return self.standardisation.apply(rts, self.record["rts_channels"])

    def outputs(self, rts: np.ndarray, psd: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The transformed errors (B,) and the head's probabilities (B, K), None for a model without a head;
        ``rts``: the model's input, standardised (:meth:`standardised`)."""
        names = [Y, PROBABILITIES] if self.thresholds_m else [Y]
        out = self.session.run(
            names, {"rts": np.ascontiguousarray(rts, np.float32), "psd": np.ascontiguousarray(psd, np.uint8)}
        )
        return out[0], (out[1] if self.thresholds_m else None)

    def __call__(self, rts: np.ndarray, psd: np.ndarray) -> np.ndarray:
        """The transformed errors (B,) alone."""
        return self.outputs(rts, psd)[0]
