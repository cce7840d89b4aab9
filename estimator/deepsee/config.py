"""``configs/estimator.toml`` as typed records: the model's size, the label transform, the training schedules
(``reduced`` for a 2-core CPU in about an hour, ``full`` resumable across days or on a GPU), the baselines, the
evaluation and fine-tuning settings."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seesys.core import rts_schema
from seesys.core.errors import ConfigError
from seesys.io.config import load_section


@dataclass(frozen=True)
class PsdEncoderConfig:
    """TimeSformer-style divided space-time encoder over the K_L PSD matrices of a window."""

    patch: int  # square patch side in PSD cells; H and W must be multiples of it
    depth: int
    heads: int
    mlp_ratio: float
    dropout: float


@dataclass(frozen=True)
class RtsEncoderConfig:
    """TS2Vec-style encoder: input projection, then residual blocks of dilated 1-D convolutions (dilation 2^i)."""

    hidden: int
    depth: int
    kernel: int
    dropout: float


@dataclass(frozen=True)
class FusionConfig:
    """Bidirectional cross-attention layers (pre-norm, residual, feed-forward) and the MLP head."""

    layers: int
    heads: int
    ffn_ratio: float
    head_hidden: tuple[int, ...]
    dropout: float


@dataclass(frozen=True)
class ModelConfig:
    dim: int  # width of both encoders' output tokens and of the fusion
    psd: PsdEncoderConfig
    rts: RtsEncoderConfig
    fusion: FusionConfig


@dataclass(frozen=True)
class OrdinalHeadConfig:
    """DeepSEE's ordinal head: P(error ≥ t_k) for Equation 2's class boundaries (configs/advisory.toml), trained
    with loss = MSE(y) + bce_weight · BCE(head)."""

    enabled: bool  # new DeepSEE models (and the ablations) get the head; a model's own file says whether it has one
    bce_weight: float  # λ


@dataclass(frozen=True)
class LabelTransformConfig:
    """y = log(1 + k · error_m) (paper §5.2, K_L = 10,000 there) and its inverse."""

    k: float


@dataclass(frozen=True)
class StageSchedule:
    """One supervised or masked-reconstruction stage: epochs of at most ``steps_per_epoch`` batches (0: a full
    pass), early stopping after ``patience`` epochs without a better validation loss."""

    epochs: int
    steps_per_epoch: int
    batch_size: int
    lr: float
    weight_decay: float
    patience: int


@dataclass(frozen=True)
class Ts2VecSchedule:
    """TS2Vec's hierarchical contrastive pretraining of the RTS encoder."""

    iterations: int
    batch_size: int
    lr: float
    alpha: float  # weight of the instance-wise term (1 - alpha: temporal)
    mask_probability: float  # timestamp masking on the latent


@dataclass(frozen=True)
class Schedule:
    """Everything one training run does, stage by stage."""

    max_train_samples: int  # 0: every training sample; else a seeded random subset of this many
    max_validation_samples: int
    psd_ssl: StageSchedule
    psd_mask_ratio: float
    rts_ssl: Ts2VecSchedule
    supervised_frozen: StageSchedule
    finetune: StageSchedule
    ablation_frozen: StageSchedule  # the Table 3 ablations start from the same pretrained encoders
    ablation_finetune: StageSchedule
    lstm: StageSchedule


@dataclass(frozen=True)
class Schedules:
    reduced: Schedule
    full: Schedule

    def get(self, name: str) -> Schedule:
        if name not in ("reduced", "full"):
            raise ConfigError(f"unknown training schedule {name!r} (reduced or full)")
        return getattr(self, name)


@dataclass(frozen=True)
class RandomForestConfig:
    trees: int
    min_samples_leaf: int
    max_features: float
    max_train_samples: int


@dataclass(frozen=True)
class LstmConfig:
    hidden: int
    layers: int
    head_hidden: int


@dataclass(frozen=True)
class EvaluationConfig:
    """How estimates are judged (the Table 3 metrics and what the advisory will do with the estimates)."""

    paper_range_m: tuple[float, float]  # the authors clipped labels to [1 mm, 2 cm]
    large_error_m: float  # recall of windows whose true error is at least this
    batch_size: int
    plot_runs: int  # test runs drawn as estimate-vs-truth time series
    bootstrap_resamples: int  # draws of runs with replacement for the intervals (0: none)
    confidence: float  # of the bootstrap intervals
    bootstrap_seed: int

    def __post_init__(self) -> None:
        if self.bootstrap_resamples < 0 or not 0 < self.confidence < 1:
            raise ValueError(
                f"evaluation: bootstrap_resamples must be >= 0 and confidence in (0, 1), got "
                f"{self.bootstrap_resamples} and {self.confidence}"
            )


@dataclass(frozen=True)
class TargetsConfig:
    """The targets of an estimate, stated against the same set's reference rows and ceiling
    (estimator/deepsee/references.py): the one place the generated reports take them from."""

    kappa_share_of_ceiling: float  # κ at least this share of the ceiling's κ (another SLAM trial's)
    kappa_over_motion: float  # κ at least this much above the motion-only row's
    aurg_over_motion: float  # AURG at least this much above the motion-only row's
    agreement_over_constant: float  # agreement at least this much above the constant class's
    recall_share_of_ceiling: float  # recall of ≥ 12 mm bins at least this share of the ceiling's
    median_ratio_within: float  # median estimate / median truth within [1 / x, x]
    rmse_gain_over_random_forest: float  # RMSE within the paper's range below the forest's by at least this share
    rmse_gain_over_lstm: float


@dataclass(frozen=True)
class AugmentationConfig:
    """Training-time changes of what a real camera changes (estimator/deepsee/augment.py); gains are drawn
    log-uniformly in [low, high], offsets uniformly in [-x, x], once per window."""

    enabled: bool
    brightness_offset: float  # fraction of full scale
    contrast_gain: tuple[float, float]
    entropy_offset_bits: float
    laplacian_gain: tuple[float, float]  # sharpness: variance of the Laplacian
    count_gain: tuple[float, float]  # matched inliers, outliers, matches before pose optimisation
    keypoint_response_gain: tuple[float, float]  # the PSD keypoint layer (FAST response, i.e. local contrast)
    frozen_stage_views: int  # stage (c): augmented draws of every training window whose encodings are cached

    def __post_init__(self) -> None:
        if self.frozen_stage_views < 1:
            raise ValueError(f"frozen_stage_views must be at least 1, got {self.frozen_stage_views}")


@dataclass(frozen=True)
class InputStandardisationConfig:
    """The camera-dependent RTS channels whose per-camera statistics a model stores and fine-tuning refits
    (estimator/artefact/standardisation.py)."""

    camera_channels: tuple[str, ...]


@dataclass(frozen=True)
class FinetuneConfig:
    """Stage (d) on labelled session folders (``seesys estimator finetune``)."""

    validation_fraction: float  # the last part of each session, in time, judges early stopping
    schedule: StageSchedule


@dataclass(frozen=True)
class EstimatorConfig:
    seed: int
    shipped_model: str
    model: ModelConfig
    ordinal_head: OrdinalHeadConfig
    label_transform: LabelTransformConfig
    schedules: Schedules
    random_forest: RandomForestConfig
    lstm: LstmConfig
    evaluation: EvaluationConfig
    targets: TargetsConfig
    finetune: FinetuneConfig
    augmentation: AugmentationConfig
    input_standardisation: InputStandardisationConfig


#: The file of :class:`EstimatorConfig` in the configuration folder.
SECTION = "estimator"


def load_estimator_config(directory: Path | None = None) -> EstimatorConfig:
    """Load ``configs/estimator.toml``."""
    config = load_section(SECTION, EstimatorConfig, directory)
    check_model_config(config.model)
    if config.ordinal_head.bce_weight < 0:
        raise ConfigError(
            f"configs/estimator.toml: ordinal_head.bce_weight must not be negative, got "
            f"{config.ordinal_head.bce_weight}"
        )
    unknown = sorted(set(config.input_standardisation.camera_channels) - set(rts_schema.CHANNEL_NAMES))
    if unknown:
        raise ConfigError(
            f"configs/estimator.toml: input_standardisation.camera_channels names unknown RTS "
            f"channels {', '.join(unknown)}"
        )
    return config


def check_model_config(model: ModelConfig) -> None:
    """Raise :class:`ConfigError` when the widths do not divide into the attention heads."""
    for where, heads in (("psd", model.psd.heads), ("fusion", model.fusion.heads)):
        if model.dim % heads:
            raise ConfigError(
                f"configs/estimator.toml: model.dim {model.dim} is not a multiple of {where}.heads {heads}"
            )
