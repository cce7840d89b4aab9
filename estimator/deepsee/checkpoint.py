"""The model file: weights plus what they mean, and a refusal of a model made for other inputs.

A checkpoint (``torch.save`` of a dict) holds:

- ``format``: :data:`FORMAT_VERSION` of this layout;
- ``compatibility``: the RTS schema (version and fingerprint, channel names), the window definition (T, K_L,
  tau and the missing-row rule ``max_missing_rts``: what a window contains and which windows a model sees; not how
  often one is formed), the label transform, the label's Δ and the device settings the training data was made with
  (SLAM modes, frame rate, ORB feature count, PSD cell size, expansion and ``near_depth``;
  :mod:`estimator.artefact.compatibility`), the ordinal head's thresholds where the model has one
  (``ordinal_head``), and ``compatibility_hash``, the SHA-256 of that record. A model is
  loaded only where every field matches this installation, and the service serves a device only where its own
  settings match: a model trained on other inputs reads different numbers and its estimates would be
  meaningless, silently;
- ``model``: the kind (``deepsee`` or the ``lstm`` baseline) and what rebuilds the network (configuration, input
  shape, variant, the ordinal head's thresholds ``ordinal_thresholds_m``: absent in a model without a head, such
  as every model made before the head); ``state_dict``: the weights;
- ``training``: how it was made (command, data, schedule, round, metrics), for the record;
- ``input_standardisation``: the per-camera statistics of its camera-dependent channels
  (:mod:`estimator.artefact.standardisation`); absent in a model made before them, which reads its input as it is.

The same hash is written into the exported ONNX model's metadata and checked when it is loaded.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from torch import nn

from estimator.artefact.compatibility import (
    InputShape,
    ModelMismatch,
    check_compatible,
    compatibility,
    compatibility_hash,
    rts_columns,
)
from estimator.artefact.standardisation import CHECKPOINT_KEY, InputStandardisation
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.baselines import LstmBaseline
from estimator.deepsee.config import FusionConfig, LstmConfig, ModelConfig, PsdEncoderConfig, RtsEncoderConfig
from estimator.deepsee.model import DeepSEE
from estimator.deepsee.rows import Variant
from seesys.core.windows import WindowConfig
from seesys.io.core_settings import load_window_config

FORMAT_VERSION = 1


def _spec(model: nn.Module) -> dict:
    if isinstance(model, DeepSEE):
        spec = {
            "kind": "deepsee",
            "config": asdict(model.config),
            "shape": asdict(model.shape),
            "variant": asdict(model.variant),
        }
        # Only a model with a head records thresholds: a model without one keeps the spec it always had.
        return {**spec, "ordinal_thresholds_m": list(model.thresholds_m)} if model.thresholds_m else spec
    if isinstance(model, LstmBaseline):
        return {"kind": "lstm", "config": asdict(model.config), "channels": model.channels}
    raise TypeError(f"cannot save a {type(model).__name__}")


def _build(spec: dict, rts_channels: tuple[str, ...]) -> nn.Module:
    """The untrained model of ``spec`` taking the RTS channels ``rts_channels`` (names)."""
    if spec["kind"] == "lstm":
        return LstmBaseline(LstmConfig(**spec["config"]), spec["channels"])
    # The variant's fields as the spec's JSON holds them, its lists back into the dataclass's tuples.
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["variant"].items()}
    variant = Variant(**fields)
    return DeepSEE(
        _model_config(spec["config"]),
        InputShape(**spec["shape"]),
        variant,
        tuple(spec.get("ordinal_thresholds_m", ())),
        rts_channels,
    )


def save_atomic(obj: object, path: Path) -> Path:
    """``torch.save`` through a temporary file and a rename: a process killed while saving, or another process
    waiting for the file, never sees half of it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    torch.save(obj, temporary)
    temporary.replace(path)
    return path


def save_model(
    path: Path,
    model: nn.Module,
    windows: WindowConfig,
    transform: LabelTransform,
    training: dict,
    rts_channels: list[str] | None = None,
    standardisation: InputStandardisation | None = None,
) -> Path:
    """Save ``model`` with its compatibility record and its input ``standardisation`` (none: its input as it is);
    ``rts_channels``: the RTS channels it takes (a fine-tuned model keeps its base's), every channel of the schema
    by default."""
    record = compatibility(
        windows, transform, rts_channels=rts_channels, head_thresholds_m=getattr(model, "thresholds_m", ())
    )
    payload = {
        "format": FORMAT_VERSION,
        "compatibility": record,
        "compatibility_hash": compatibility_hash(record),
        "model": _spec(model),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "training": training,
    }
    if standardisation is not None:
        payload[CHECKPOINT_KEY] = standardisation.as_record()
    return save_atomic(payload, path)


def payload_standardisation(payload: dict, source: str) -> InputStandardisation:
    """The input standardisation a model file's ``payload`` records (the identity where it records none)."""
    return InputStandardisation.from_record(payload.get(CHECKPOINT_KEY), source)


def _model_config(data: dict) -> ModelConfig:
    return ModelConfig(
        data["dim"],
        PsdEncoderConfig(**data["psd"]),
        RtsEncoderConfig(**data["rts"]),
        FusionConfig(**{**data["fusion"], "head_hidden": tuple(data["fusion"]["head_hidden"])}),
    )


def load_payload(path: Path) -> dict:
    try:
        payload = torch.load(Path(path), map_location="cpu", weights_only=False)
    except FileNotFoundError:
        raise ModelMismatch(f"model file not found: {path}") from None
    except Exception as e:  # torch raises many types for a file that is not a checkpoint
        raise ModelMismatch(f"{path} is not a DeepSEE model file: {e}") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT_VERSION:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ModelMismatch(f"{path} is not a DeepSEE model file of format {FORMAT_VERSION} (found {found!r})")
    return payload


def load_model(path: Path, transform: LabelTransform, windows: WindowConfig | None = None) -> tuple[nn.Module, dict]:
    """The model of ``path`` in eval mode, and its payload; refused (:class:`ModelMismatch`) when it was made for
    another RTS schema, window definition or label transform than ``windows`` (default: configs/windows.toml) and
    ``transform``."""
    payload = load_payload(path)
    check_compatible(payload["compatibility"], str(path), windows or load_window_config(), transform)
    rts_columns(payload["compatibility"], str(path))  # refuses channels this schema does not have as recorded
    model = _build(payload["model"], tuple(payload["compatibility"]["rts_channels"]))
    model.load_state_dict(payload["state_dict"])
    return model.eval(), payload
