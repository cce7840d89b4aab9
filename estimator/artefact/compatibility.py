"""What a model takes and what its inputs and output mean, without PyTorch: the window shape, the compatibility
record stored with every model file (checkpoint, ONNX metadata, random-forest pickle) and its check.

The record holds the RTS channels the model takes (their names, the fingerprint of their definitions, and the schema
version they were made with: a model takes the rows of any later schema that still has them, through
:func:`rts_columns`), the windows (T, K_L, tau and the missing-row
rule ``max_missing_rts``), the label transform, the label's Δ (``delta_frames``; for a model trained on monocular
sessions also the name of the monocular label's alignment, ``mono_alignment``, checked only for such a model: a
model made under another definition is refused naming it) and the device settings the
training data was made with (:func:`seesys.core.device_settings.model_settings_record`: SLAM modes, frame rate,
ORB feature count, PSD cell size, expansion and ``near_depth``, the camera normalisation version and its reference
camera, :mod:`seesys.core.camera_normalisation`) and, for a model with an ordinal head, the head's
thresholds (``ordinal_head``: ``{"thresholds_m": [...]}``; absent without a head, so the record of a model without
one is what it always was). The thresholds are recorded, not compared: they say which threshold each of the head's
probabilities is for, and the advisory uses the head only where they are Equation 2's class boundaries. Loading a
model compares every field but the
SLAM modes and the frame rate with this installation's configs and names each one that differs; those two are a
device's own and the service checks them on every device's frames.

Kept free of PyTorch so that serving an exported ONNX model (a service worker, ``load_predictor`` of an ``.onnx``
file) never imports it: importing torch costs seconds of start-up and hundreds of megabytes per process.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import SupportsInt

import numpy as np
import pandas as pd

from estimator.artefact.transforms import LabelTransform
from seesys.core import camera_normalisation, rts_schema
from seesys.core.device_settings import MONO
from seesys.core.errors import SeesysError
from seesys.core.labels import BEFORE_MONO_ALIGNMENT, MONO_ALIGNMENT
from seesys.core.windows import WindowConfig
from seesys.io.core_settings import load_label_config, load_model_device_record

# The fields of the window definition that decide what a window holds and which windows a model sees (end_stride
# only says how often one is formed).
WINDOW_FIELDS = ("rts_length", "psd_samples", "psd_stride", "max_missing_rts")
# The device settings every device of an installation shares (its configs), with the camera normalisation's version
# and reference camera; the SLAM mode and the frame rate are a device's own and are checked on its frames
# (seesys.core.device_settings).
INSTALLATION_DEVICE_FIELDS = (
    "orb_features",
    "psd_patch_px",
    "psd_expansion",
    "near_depth",
    "camera_normalisation",
    "reference_camera",
)
ORDINAL_HEAD = "ordinal_head"


class ModelMismatch(SeesysError):
    """A model file was made for other inputs (RTS schema, windows, label, device settings) or is not a model
    file."""


@dataclass(frozen=True)
class InputShape:
    """What one window holds: T RTS rows of C channels, K_L PSD matrices of H × W cells."""

    rts_length: int
    channels: int
    psd_samples: int
    psd_height: int
    psd_width: int


@dataclass(frozen=True)
class ModelSetup:
    """What a model depends on beyond its windows and label transform: the label's Δ (``delta_frames`` of
    labels.toml) and the device settings (:func:`seesys.core.device_settings.model_settings_record`)."""

    delta_frames: int
    device: dict

    @classmethod
    def configured(cls, directory: Path | None = None) -> ModelSetup:
        """This installation's: labels.toml, monitor.toml, slam.toml, dataset.toml and synth.toml."""
        return cls(load_label_config(directory).delta_frames, load_model_device_record(directory))


def compatibility(
    windows: WindowConfig,
    transform: LabelTransform,
    setup: ModelSetup | None = None,
    rts_channels: Sequence[str] | None = None,
    head_thresholds_m: Sequence[float] = (),
) -> dict:
    """What a model's inputs and outputs mean, as plain data (``setup``: this installation's by default;
    ``rts_channels``: the channels it takes, every channel of the schema by default; ``head_thresholds_m``: its
    ordinal head's thresholds, none without a head)."""
    setup = setup or ModelSetup.configured()
    names = list(rts_channels) if rts_channels is not None else list(rts_schema.CHANNEL_NAMES)
    channels = tuple(rts_schema.CHANNELS[rts_schema.index_of(name)] for name in names)
    record = {
        "rts_schema_version": rts_schema.SCHEMA_VERSION,
        "rts_fingerprint": rts_schema.fingerprint(channels),
        "rts_channels": names,
        "windows": {name: getattr(windows, name) for name in WINDOW_FIELDS},
        "label_transform": transform.describe(),
        "label": _label_record(setup),
        "device": dict(setup.device),
    }
    if head_thresholds_m:
        record[ORDINAL_HEAD] = {"thresholds_m": [float(t) for t in head_thresholds_m]}
    return record


def _takes_mono(device: dict | None) -> bool:
    """Whether a model of this device record was trained on monocular sessions."""
    return MONO in ((device or {}).get("slam_modes") or ())


def _label_record(setup: ModelSetup) -> dict:
    """The label's Δ, and for a model trained on monocular sessions the name of the monocular label's alignment
    (an RGB-D label does not depend on it, so an RGB-D model's record is what it was before the name existed)."""
    label: dict[str, int | str] = {"delta_frames": setup.delta_frames}
    if _takes_mono(setup.device):
        label["mono_alignment"] = MONO_ALIGNMENT
    return label


def head_thresholds_of(record: dict) -> tuple[float, ...]:
    """The ordinal head's thresholds a model's ``record`` states; empty for a model without a head."""
    return tuple(float(t) for t in (record.get(ORDINAL_HEAD) or {}).get("thresholds_m", ()))


def compatibility_hash(record: dict) -> str:
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()


def _show(value: object) -> str:
    return "-" if value is None else json.dumps(value, sort_keys=True)


def rts_columns(record: dict, source: str = "the model") -> np.ndarray:
    """The columns of this schema's RTS rows that a model of ``record`` takes, in its order
    (:func:`seesys.core.rts_schema.columns_of`; raises ``SchemaMismatch`` when it takes channels this schema
    does not have as it knew them)."""
    names, fingerprint = record.get("rts_channels"), record.get("rts_fingerprint")
    if not isinstance(names, list) or not isinstance(fingerprint, int):
        raise rts_schema.SchemaMismatch(f"{source} does not record its RTS channels")
    return rts_schema.columns_of(names, fingerprint, source)


def differences(record: dict, here: dict) -> list[str]:
    """Every field of a model's ``record`` that differs from ``here`` (both :func:`compatibility` records), as
    ``"name: model VALUE, here VALUE"``; the device's SLAM modes and frame rate are left to the frames. The RTS
    channels differ only when the model takes one that this schema lacks or defines otherwise."""
    out = []
    try:
        rts_columns(record)
    except rts_schema.SchemaMismatch as e:
        out.append(
            f"RTS channels (model of schema v{record.get('rts_schema_version')}, here "
            f"v{here['rts_schema_version']}): {e}"
        )
    if record.get("label_transform") != here["label_transform"]:
        out.append(
            f"label transform: model {_show(record.get('label_transform'))}, here {_show(here['label_transform'])}"
        )
    checked = (
        [("windows", name) for name in WINDOW_FIELDS]
        + [("label", "delta_frames")]
        + [("device", name) for name in INSTALLATION_DEVICE_FIELDS]
    )
    for part, name in checked:
        model_value = (record.get(part) or {}).get(name)
        here_value = here[part][name]
        if model_value != here_value:
            out.append(f"{part}.{name}: model {_show(model_value)}, here {_show(here_value)}")
    mono_alignment = (record.get("label") or {}).get("mono_alignment", BEFORE_MONO_ALIGNMENT)
    if _takes_mono(record.get("device")) and mono_alignment != MONO_ALIGNMENT:
        out.append(f"label.mono_alignment: model {_show(mono_alignment)}, here {_show(MONO_ALIGNMENT)}")
    return out


def model_normalisation(record: dict) -> int:
    """The camera normalisation version a model of ``record`` takes (0: made before camera normalisation)."""
    return int((record.get("device") or {}).get("camera_normalisation", camera_normalisation.BEFORE_NORMALISATION))


def check_normalisation(record: dict, versions: Iterable[SupportsInt | None], source: str) -> None:
    """Raise :class:`ModelMismatch`, in one line naming both versions, when any of ``versions`` (the camera
    normalisation versions of windows from ``source``; NA/None where a source states none, which is not
    checked) is not the one a model of ``record`` takes."""
    stated = sorted({int(v) for v in versions if v is not None and not pd.isna(v)})
    expected = model_normalisation(record)
    for version in stated:
        try:
            camera_normalisation.check_version(expected, version, source)
        except camera_normalisation.CameraNormalisationMismatch as e:
            raise ModelMismatch(str(e)) from None


def check_compatible(
    record: dict, source: str, windows: WindowConfig, transform: LabelTransform, setup: ModelSetup | None = None
) -> None:
    """Raise :class:`ModelMismatch` naming every field in which ``record`` differs from this installation (its
    windows, label transform and ``setup``, this installation's configs by default)."""
    found = differences(record, compatibility(windows, transform, setup))
    if found:
        raise ModelMismatch(
            f"{source} was made for other inputs: {'; '.join(found)}. It cannot be used here; "
            f"retrain it, or fine-tune a model made for this configuration"
        )
