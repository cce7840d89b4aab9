"""The rows of the paper's Table 3: the baselines, the model study, the RTS and PSD ablations, DeepSEE."""

from __future__ import annotations

from dataclasses import dataclass

from seesys.core import rts_schema
from seesys.core.errors import SeesysError

DEEPSEE = "deepsee"
RANDOM_FOREST = "random_forest"
LSTM = "lstm"


@dataclass(frozen=True)
class Variant:
    """Which parts of DeepSEE a model has (the Table 3 ablations)."""

    use_psd: bool = True
    fusion: str = "cross_attention"  # or "concat": fully connected fusion of the pooled encodings (w/o CA)
    drop_rts: tuple[str, ...] = ()  # RTS channel categories set to zero
    drop_channels: tuple[str, ...] = ()  # single RTS channels set to zero (one channel's own ablation)
    drop_psd: tuple[str, ...] = ()  # PSD layers set to zero

    def __post_init__(self) -> None:
        if self.fusion not in ("cross_attention", "concat"):
            raise ValueError(f"unknown fusion {self.fusion!r}")


@dataclass(frozen=True)
class Row:
    name: str  # folder and command-line name
    label: str  # as in Table 3
    category: str
    kind: str  # deepsee, random_forest or lstm
    variant: Variant = Variant()
    ssl: bool = True  # encoders initialised by stages (a) and (b)
    ablation: bool = False  # trained on the ablation schedule, from the DeepSEE row's pretrained encoders


ROWS: tuple[Row, ...] = (
    Row(RANDOM_FOREST, "Random Forest", "Baseline", RANDOM_FOREST, ssl=False),
    Row(LSTM, "LSTM", "Baseline", LSTM, ssl=False),
    # The forest without schema v4's geometry channels: what they add to the strongest baseline.
    Row(
        "random_forest_wo_geometry",
        "Random Forest w/o Geometry",
        "RTS Ablation Study",
        RANDOM_FOREST,
        Variant(drop_rts=rts_schema.GEOMETRY_CATEGORIES),
        ssl=False,
    ),
    # The forest without schema v5's residual shear: the forest of schema v4's channels, trained on the same windows.
    Row(
        "random_forest_wo_shear",
        "Random Forest w/o Shear",
        "RTS Ablation Study",
        RANDOM_FOREST,
        Variant(drop_channels=("residual_shear",)),
        ssl=False,
    ),
    Row("wo_psd", "DeepSEE-w/o-PSD", "Model Study", DEEPSEE, Variant(use_psd=False), ablation=True),
    Row("wo_ssl", "DeepSEE-w/o-SSL", "Model Study", DEEPSEE, ssl=False, ablation=True),
    Row("wo_ca", "DeepSEE-w/o-CA", "Model Study", DEEPSEE, Variant(fusion="concat"), ablation=True),
    Row(
        "wo_sensor",
        "DeepSEE-w/o-Sensor",
        "RTS Ablation Study",
        DEEPSEE,
        Variant(drop_rts=("sensor_input",)),
        ablation=True,
    ),
    Row(
        "wo_tracking",
        "DeepSEE-w/o-Tracking",
        "RTS Ablation Study",
        DEEPSEE,
        Variant(drop_rts=("tracking",)),
        ablation=True,
    ),
    Row(
        "wo_mapping",
        "DeepSEE-w/o-Mapping",
        "RTS Ablation Study",
        DEEPSEE,
        Variant(drop_rts=("mapping",)),
        ablation=True,
    ),
    # Schema v4's geometry channels removed: what the pose observability, residuals and second opinion add.
    Row(
        "wo_geometry",
        "DeepSEE-w/o-Geometry",
        "RTS Ablation Study",
        DEEPSEE,
        Variant(drop_rts=rts_schema.GEOMETRY_CATEGORIES),
        ablation=True,
    ),
    Row(
        "wo_keypoint",
        "DeepSEE-w/o-Keypoint",
        "PSD Ablation Study",
        DEEPSEE,
        Variant(drop_psd=("keypoint",)),
        ablation=True,
    ),
    Row("wo_inlier", "DeepSEE-w/o-Inlier", "PSD Ablation Study", DEEPSEE, Variant(drop_psd=("inlier",)), ablation=True),
    Row(
        "wo_map_point",
        "DeepSEE-w/o-Mappoint",
        "PSD Ablation Study",
        DEEPSEE,
        Variant(drop_psd=("map_point",)),
        ablation=True,
    ),
    Row(DEEPSEE, "DeepSEE", "DeepSEE", DEEPSEE),
)
ROW_NAMES = tuple(r.name for r in ROWS)
_BY_NAME = {r.name: r for r in ROWS}


def row(name: str) -> Row:
    try:
        return _BY_NAME[name]
    except KeyError:
        raise SeesysError(f"unknown Table 3 row {name!r}; rows are {', '.join(ROW_NAMES)}") from None


def training_order(names: list[str]) -> list[Row]:
    """DeepSEE first (the ablations reuse its pretrained encoders), then the rest in table order."""
    chosen = [row(n) for n in dict.fromkeys(names)]
    return sorted(chosen, key=lambda r: (r.name != DEEPSEE, ROW_NAMES.index(r.name)))
