"""What a model takes and what its inputs and output mean, without PyTorch: the window shape, the compatibility
record stored with every model file (checkpoint, ONNX metadata, random-forest pickle) and its check.

Kept free of PyTorch so that serving an exported ONNX model (a service worker, ``load_predictor`` of an ``.onnx``
file) never imports it: importing torch costs seconds of start-up and hundreds of megabytes per process.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

from estimator.deepsee.transforms import LabelTransform
from seesys.core import rts_schema
from seesys.core.errors import SeesysError
from seesys.core.windows import WindowConfig

# The fields of the window definition that decide what a window holds (end_stride only says how often one is formed,
# max_missing_rts which windows are formed).
WINDOW_FIELDS = ("rts_length", "psd_samples", "psd_stride")


class ModelMismatch(SeesysError):
    """A model file was made for other inputs (RTS schema, windows, label transform) or is not a model file."""


@dataclass(frozen=True)
class InputShape:
    """What one window holds: T RTS rows of C channels, K_L PSD matrices of H × W cells."""

    rts_length: int
    channels: int
    psd_samples: int
    psd_height: int
    psd_width: int


def compatibility(windows: WindowConfig, transform: LabelTransform) -> dict:
    """What a model's inputs and output mean, as plain data."""
    return {"rts_schema_version": rts_schema.SCHEMA_VERSION, "rts_fingerprint": rts_schema.FINGERPRINT,
            "rts_channels": list(rts_schema.CHANNEL_NAMES),
            "windows": {name: getattr(windows, name) for name in WINDOW_FIELDS},
            "label_transform": transform.describe()}


def compatibility_hash(record: dict) -> str:
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()


def check_compatible(record: dict, source: str, windows: WindowConfig, transform: LabelTransform) -> None:
    """Raise :class:`ModelMismatch` naming every difference between ``record`` and this installation."""
    here = compatibility(windows, transform)
    if compatibility_hash(record) == compatibility_hash(here):
        return
    differences = []
    if (record.get("rts_schema_version"), record.get("rts_fingerprint")) != (here["rts_schema_version"],
                                                                              here["rts_fingerprint"]):
        differences.append(f"RTS schema v{record.get('rts_schema_version')} (here v{here['rts_schema_version']}, "
                           f"channels {'same' if record.get('rts_channels') == here['rts_channels'] else 'differ'})")
    if record.get("windows") != here["windows"]:
        differences.append(f"windows {record.get('windows')} (here {here['windows']})")
    if record.get("label_transform") != here["label_transform"]:
        differences.append(f"label transform {record.get('label_transform')} (here {here['label_transform']})")
    raise ModelMismatch(f"{source} was trained for other inputs: {'; '.join(differences) or 'a different record'}. "
                        f"It cannot be used here; retrain it or fine-tune a model made for this configuration")
