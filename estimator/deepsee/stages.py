"""Training of one Table 3 row into a run folder: DeepSEE's four stages, the ablations, the LSTM and the forest.

DeepSEE (paper §5.4, here on the training runs of a cross-validation round):

(a) PSD masked reconstruction (:mod:`estimator.deepsee.ssl`), early stopping on the validation runs' loss;
(b) TS2Vec on the RTS encoder, in epochs of :data:`TS2VEC_EPOCH` iterations;
(c) supervised, both encoders frozen: their outputs for augmented draws of the training windows and for the
    validation windows are computed once and cached in the run folder (``state/cache_*.npy``, reused only for the
    same encoders, windows and draws), and only the fusion and the output layers are trained;
(d) supervised fine-tuning of the whole model on the training runs (the paper's real-data stage; on a lab's real
    sessions, ``seesys estimator finetune``).

Every stage trains on windows augmented as ``[augmentation]`` of configs/estimator.toml says
(:mod:`estimator.deepsee.augment`). Stages (c) and (d) minimise MSE of the transformed error plus λ × the ordinal
head's BCE where the model has the head (:mod:`estimator.deepsee.ordinal`; new DeepSEE rows get it when
``[ordinal_head] enabled``), the MSE alone otherwise (the LSTM).

Every stage checkpoints after every epoch (:mod:`estimator.deepsee.loop`), so the same command resumes an
interrupted run. The encoders after (b) are saved as ``state/encoders.pt``; an ablation row given a DeepSEE run
folder as ``pretrained`` starts from them and trains (c) and (d) on the ablation schedule.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import pickle
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from rich.progress import Progress
from torch import nn

from estimator.artefact.compatibility import check_normalisation
from estimator.artefact.standardisation import InputStandardisation
from estimator.artefact.transforms import LabelTransform, rts_channel_mask
from estimator.deepsee.augment import Augmenter
from estimator.deepsee.baselines import LstmBaseline
from estimator.deepsee.checkpoint import compatibility, save_atomic, save_model
from estimator.deepsee.config import AugmentationConfig, EstimatorConfig, Schedule, StageSchedule
from estimator.deepsee.data import NORMALISATION_COLUMN, Windows, limit
from estimator.deepsee.forest import fit_random_forest
from estimator.deepsee.inference import batch_tensors, predict_outputs, uses_psd
from estimator.deepsee.loop import run_stage, stage_seed
from estimator.deepsee.model import DeepSEE, PsdEncoder, exceedance_probabilities
from estimator.deepsee.ordinal import exceeded, head_thresholds, model_thresholds, training_loss, validation_loss
from estimator.deepsee.rows import LSTM, RANDOM_FOREST, Row, Variant
from estimator.deepsee.run_folder import MODEL_PT, RunFolder
from estimator.deepsee.ssl import PsdReconstruction, ts2vec_loss
from seesys.core import rts_schema
from seesys.core.errors import SeesysError
from seesys.core.windows import WindowConfig

TS2VEC_EPOCH = 100  # iterations per checkpointed TS2Vec epoch
SSL_VALIDATION_WINDOWS = 512
ENCODERS_PT = "encoders.pt"
FOREST_PICKLE = "model.pkl"


@dataclass(frozen=True)
class TrainContext:
    """What every row of a round is trained with."""

    config: EstimatorConfig
    schedule_name: str
    windows: WindowConfig
    device: torch.device
    progress: Progress
    provenance: dict  # command, data folders, splits, round: recorded in config.json and the model file

    @property
    def schedule(self) -> Schedule:
        return self.config.schedules.get(self.schedule_name)

    @property
    def transform(self) -> LabelTransform:
        return LabelTransform(self.config.label_transform.k)


def _targets(windows: Windows, transform: LabelTransform) -> np.ndarray:
    return transform.forward(windows.error_m).astype(np.float32)


def _head_targets(model: nn.Module, windows: Windows) -> np.ndarray | None:
    """The ordinal head's targets of ``windows``; None for a model without a head."""
    thresholds = model_thresholds(model)
    return exceeded(windows.error_m, thresholds) if thresholds else None


def _validator(model: nn.Module, val: Windows, ctx: TrainContext):
    """The validation loss: the training loss (:func:`estimator.deepsee.ordinal.training_loss`) on ``val``."""
    targets, exceeds = _targets(val, ctx.transform), _head_targets(model, val)

    def validate() -> float:
        y, probabilities = predict_outputs(model, val, ctx.config.evaluation.batch_size, ctx.device)
        return validation_loss(y, probabilities, targets, exceeds, ctx.config.ordinal_head.bce_weight)

    return validate


def _batch_targets(
    y: torch.Tensor, exceeds: np.ndarray | None, index: np.ndarray, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor | None]:
    return y[index].to(device), (torch.from_numpy(exceeds[index]).to(device) if exceeds is not None else None)


def _psd_ssl(
    run: RunFolder, model: DeepSEE, encoder: PsdEncoder, train: Windows, val: Windows, ctx: TrainContext
) -> None:
    """Stage (a): masked reconstruction of the PSD window by the model's PSD ``encoder``, its training batches
    augmented."""
    seed, ratio = ctx.config.seed, ctx.schedule.psd_mask_ratio
    task = PsdReconstruction(encoder, model.config.dim).to(ctx.device)
    val_index = np.arange(min(len(val), SSL_VALIDATION_WINDOWS))
    augment = Augmenter(ctx.config.augmentation)

    def step(index: np.ndarray, generator: torch.Generator) -> torch.Tensor:
        _, psd = augment(*batch_tensors(train, index, ctx.device), generator)
        return task.loss(model.psd_input(psd), ratio, generator)

    @torch.no_grad()
    def validate() -> float:
        task.eval()
        generator = torch.Generator().manual_seed(stage_seed(seed, "psd_ssl:validation", 0))
        losses = [
            float(task.loss(model.psd_input(batch_tensors(val, chunk, ctx.device)[1]), ratio, generator))
            for chunk in np.array_split(val_index, max(1, math.ceil(len(val_index) / 64)))
        ]
        task.train()
        return float(np.mean(losses))

    run_stage(
        run,
        "a_psd_ssl",
        task,
        task.parameters(),
        ctx.schedule.psd_ssl,
        len(train),
        step,
        validate if len(val_index) else None,
        seed,
        ctx.progress,
    )


def _rts_ssl(run: RunFolder, model: DeepSEE, train: Windows, ctx: TrainContext) -> None:
    """Stage (b): TS2Vec on the RTS encoder (no validation: the contrastive loss does not rank encoders), each
    window augmented by one draw that both of its crops share."""
    s = ctx.schedule.rts_ssl
    per_epoch = min(TS2VEC_EPOCH, s.iterations)
    epochs = max(1, math.ceil(s.iterations / per_epoch))
    schedule = StageSchedule(epochs, per_epoch, s.batch_size, s.lr, 0.0, epochs)
    encoder = model.rts_encoder
    augment = Augmenter(ctx.config.augmentation)

    def step(index: np.ndarray, generator: torch.Generator) -> torch.Tensor:
        rts, _ = augment(*batch_tensors(train, index, ctx.device, with_psd=False), generator)
        return ts2vec_loss(encoder, rts * model.rts_mask, s.alpha, s.mask_probability, generator)

    run_stage(
        run, "b_rts_ssl", encoder, encoder.parameters(), schedule, len(train), step, None, ctx.config.seed, ctx.progress
    )


def _encoder_state(model: DeepSEE) -> dict:
    return {
        "rts_encoder": model.rts_encoder.state_dict(),
        "psd_encoder": model.psd_encoder.state_dict() if model.psd_encoder is not None else None,
    }


def _load_encoders(model: DeepSEE, path: Path) -> None:
    if not path.is_file():
        raise SeesysError(f"no pretrained encoders at {path}: train the DeepSEE row of this round first")
    state = torch.load(path, map_location="cpu", weights_only=True)
    model.rts_encoder.load_state_dict(state["rts_encoder"])
    if model.psd_encoder is not None:
        if state["psd_encoder"] is None:
            raise SeesysError(f"{path} holds no PSD encoder")
        model.psd_encoder.load_state_dict(state["psd_encoder"])


@dataclass(frozen=True)
class _Views:
    """What :func:`_cached_encodings` caches of each window: ``count`` encodings, of the window augmented by
    ``augmentation`` (seeded per view by ``seed``), or of the window as it is when ``augmentation`` is None."""

    count: int
    augmentation: AugmentationConfig | None = None
    seed: int = 0

    def describe(self) -> str:
        return repr((self.count, self.augmentation, self.seed))


def _encodings_key(model: DeepSEE, windows: Windows, views: _Views) -> str:
    """What the cached encodings were computed from: the encoders (architecture and weights), every window's
    content (RTS, PSD when the model reads it, and which run and frame it is) and the views of it. Two sets of
    windows of the same count, encoders trained again, or other augmentation give another key."""
    digest = hashlib.sha256()
    digest.update(views.describe().encode())
    for module in model.encoder_modules():
        digest.update(repr(module).encode())
        for name, tensor in module.state_dict().items():
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    digest.update(repr((windows.rts.shape, windows.rts.dtype)).encode())
    digest.update(np.ascontiguousarray(windows.rts).tobytes())
    digest.update(windows.meta.to_csv(index=False).encode())
    if model.psd_encoder is not None:
        for i in range(len(windows)):
            digest.update(np.ascontiguousarray(windows.psd_at(i)).tobytes())
    return digest.hexdigest()


@torch.no_grad()
def _cached_encodings(
    run: RunFolder, model: DeepSEE, windows: Windows, part: str, ctx: TrainContext, views: _Views
) -> tuple[np.ndarray, np.ndarray | None]:
    """The frozen encoders' tokens of every view of every window (``views``), (V, N, ...) float16 on disk,
    computed once per run folder for the same encoders, windows and views: ``state/cache_<part>.json`` holds the
    key of what the arrays were computed from (:func:`_encodings_key`), and any other key computes them again."""
    paths = (run.state / f"cache_{part}_rts.npy", run.state / f"cache_{part}_psd.npy")
    key_path = run.state / f"cache_{part}.json"
    key = _encodings_key(model, windows, views)

    def cached() -> tuple[np.ndarray, np.ndarray | None]:
        return (
            np.load(paths[0], mmap_mode="r"),
            np.load(paths[1], mmap_mode="r") if model.psd_encoder is not None else None,
        )

    try:
        if json.loads(key_path.read_text())["key"] == key:
            return cached()
    except (OSError, ValueError, KeyError, TypeError):
        pass
    key_path.unlink(missing_ok=True)  # the arrays are rewritten below: no key may vouch for them meanwhile
    model.eval()
    rs, ps = [], []
    batch = ctx.config.evaluation.batch_size
    augment = Augmenter(views.augmentation) if views.augmentation is not None else None
    for view in range(views.count):
        generator = torch.Generator().manual_seed(stage_seed(views.seed, f"cache_{part}", view))
        r_view, p_view = [], []
        for start in range(0, len(windows), batch):
            index = np.arange(start, min(start + batch, len(windows)))
            inputs = batch_tensors(windows, index, ctx.device, uses_psd(model))
            r, p = model.encode(*(augment(*inputs, generator) if augment is not None else inputs))
            r_view.append(r.cpu().numpy().astype(np.float16))
            if p is not None:
                p_view.append(p.cpu().numpy().astype(np.float16))
        rs.append(np.concatenate(r_view))
        if p_view:
            ps.append(np.concatenate(p_view))
    model.train()
    for path, arrays in zip(paths, (rs, ps)):
        if arrays:  # a new file, not the old one rewritten: arrays mapped from the old one keep their content
            temporary = path.with_name(path.stem + ".tmp.npy")
            np.save(temporary, np.stack(arrays))
            os.replace(temporary, path)
    key_path.write_text(json.dumps({"key": key, "windows": len(windows), "views": views.count}) + "\n")
    return cached()


def _frozen(
    run: RunFolder, model: DeepSEE, train: Windows, val: Windows, schedule: StageSchedule, ctx: TrainContext
) -> None:
    """Stage (c): the fusion and head on the cached outputs of the frozen encoders: of augmented draws of the
    training windows (each step takes one of a window's draws at random), of the validation windows as they
    are."""
    encoders = {id(p) for m in model.encoder_modules() for p in m.parameters()}
    for m in model.encoder_modules():
        m.requires_grad_(False)
    augmentation = ctx.config.augmentation
    train_views = (
        _Views(augmentation.frozen_stage_views, augmentation, ctx.config.seed) if augmentation.enabled else _Views(1)
    )
    r_train, p_train = _cached_encodings(run, model, train, "train", ctx, train_views)
    r_val, p_val = _cached_encodings(run, model, val, "validation", ctx, _Views(1))
    y_train = torch.from_numpy(_targets(train, ctx.transform))
    y_val = _targets(val, ctx.transform)
    exceeds_train, exceeds_val = _head_targets(model, train), _head_targets(model, val)
    weight = ctx.config.ordinal_head.bce_weight

    def tokens(r: np.ndarray, p: np.ndarray | None, view: np.ndarray, index: np.ndarray):
        def as_tensor(a: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.asarray(a[view, index], np.float32)).to(ctx.device)

        return as_tensor(r), (as_tensor(p) if p is not None else None)

    def step(index: np.ndarray, generator: torch.Generator) -> torch.Tensor:
        index = np.sort(index)  # memory maps read faster in order
        view = torch.randint(train_views.count, (len(index),), generator=generator).numpy()
        return training_loss(
            model.head(*tokens(r_train, p_train, view, index)),
            *_batch_targets(y_train, exceeds_train, index, ctx.device),
            weight,
        )

    @torch.no_grad()
    def validate() -> float:
        model.eval()
        batch = ctx.config.evaluation.batch_size
        outputs = [
            model.head(*tokens(r_val, p_val, np.zeros(1, int), np.arange(s, min(s + batch, len(val)))))
            for s in range(0, len(val), batch)
        ]
        model.train()
        ys = [o[0] if isinstance(o, tuple) else o for o in outputs]  # with a head, each output is (y, logits)
        if model.ordinal is None:
            return validation_loss(torch.cat(ys).cpu().numpy(), None, y_val, None, weight)
        y = torch.cat(ys).cpu().numpy()
        logits = [o[1] for o in outputs if isinstance(o, tuple)]
        probabilities = exceedance_probabilities(torch.cat(logits)).cpu().numpy()
        return validation_loss(y, probabilities, y_val, exceeds_val, weight)

    head = [p for p in model.parameters() if id(p) not in encoders]
    run_stage(
        run,
        "c_supervised_frozen",
        model,
        head,
        schedule,
        len(train),
        step,
        validate if len(val) else None,
        ctx.config.seed,
        ctx.progress,
    )
    for m in model.encoder_modules():
        m.requires_grad_(True)


def supervised(
    run: RunFolder,
    name: str,
    model: nn.Module,
    train: Windows,
    val: Windows,
    schedule: StageSchedule,
    ctx: TrainContext,
) -> None:
    """A supervised stage on the whole model (stage (d), the LSTM, fine-tuning on sessions), its training batches
    augmented as ``[augmentation]`` of configs/estimator.toml says; the ordinal head, where the model has one, is
    trained with the rest."""
    y_train = torch.from_numpy(_targets(train, ctx.transform))
    exceeds = _head_targets(model, train)
    augment = Augmenter(ctx.config.augmentation)
    with_psd = uses_psd(model)

    def step(index: np.ndarray, generator: torch.Generator) -> torch.Tensor:
        inputs = augment(*batch_tensors(train, index, ctx.device, with_psd), generator)
        return training_loss(
            model(*inputs), *_batch_targets(y_train, exceeds, index, ctx.device), ctx.config.ordinal_head.bce_weight
        )

    validate = _validator(model, val, ctx) if len(val) else None
    run_stage(run, name, model, model.parameters(), schedule, len(train), step, validate, ctx.config.seed, ctx.progress)


def _run_config(row: Row, ctx: TrainContext, pretrained: Path | None) -> dict:
    return {
        "row": row.name,
        "schedule_name": ctx.schedule_name,
        "schedule": asdict(ctx.schedule),
        "config": asdict(ctx.config),
        "variant": asdict(row.variant),
        "ssl": row.ssl,
        "pretrained": str(pretrained) if pretrained else None,
        "compatibility": compatibility(ctx.windows, ctx.transform),
        **ctx.provenance,
    }


def _cameras(windows: Windows) -> list[str]:
    """The camera models of the dataset runs ``windows`` come from (the renderer's, docs/dataset.md)."""
    return sorted(set(windows.meta.camera_model)) if "camera_model" in windows.meta else []


def train_row(out: Path, row: Row, data: dict[str, Windows], ctx: TrainContext, pretrained: Path | None = None) -> Path:
    """Train ``row`` on ``data['train']`` (early stopping on ``data['validation']``) into the run folder ``out``;
    returns the model file. ``pretrained``: a DeepSEE run folder whose encoders an ablation row starts from."""
    record = compatibility(ctx.windows, ctx.transform)
    for part in ("train", "validation"):  # the model records this SEESys's normalisation: its data must have it
        check_normalisation(record, data[part].meta.get(NORMALISATION_COLUMN, ()), f"the {part} runs")
    run = RunFolder(out, _run_config(row, ctx, pretrained), ctx.device)
    schedule, seed = ctx.schedule, ctx.config.seed
    train = limit(data["train"], schedule.max_train_samples, seed)
    val = limit(data["validation"], schedule.max_validation_samples, seed)
    torch.manual_seed(seed)
    training = {
        "row": row.name,
        "schedule": ctx.schedule_name,
        "train_windows": len(train),
        "validation_windows": len(val),
        "cameras": _cameras(train),
        **ctx.provenance,
    }
    if row.kind == RANDOM_FOREST:
        return _train_forest(run, train, ctx, training, row.variant)
    if row.kind == LSTM:
        model: nn.Module = LstmBaseline(ctx.config.lstm, train.input_shape().channels).to(ctx.device)
        supervised(run, "lstm", model, train, val, schedule.lstm, ctx)
    else:
        model = DeepSEE(ctx.config.model, train.input_shape(), row.variant, head_thresholds(ctx.config)).to(ctx.device)
        if row.ssl and pretrained is not None:
            _load_encoders(model, Path(pretrained) / "state" / ENCODERS_PT)
        elif row.ssl:
            if model.psd_encoder is not None:
                _psd_ssl(run, model, model.psd_encoder, train, val, ctx)
            _rts_ssl(run, model, train, ctx)
            save_atomic(_encoder_state(model), run.state / ENCODERS_PT)
        frozen, finetune = (
            (schedule.ablation_frozen, schedule.ablation_finetune)
            if row.ablation
            else (schedule.supervised_frozen, schedule.finetune)
        )
        _frozen(run, model, train, val, frozen, ctx)
        supervised(run, "d_finetune", model, train, val, finetune, ctx)
    # Fitted on the windows it was trained on: it serves its training cameras as they are (the identity).
    standardisation = InputStandardisation.fitted(
        train.rts, rts_schema.CHANNEL_NAMES, ctx.config.input_standardisation.camera_channels
    )
    return save_model(
        run.path / MODEL_PT,
        model.cpu(),
        ctx.windows,
        ctx.transform,
        {**training, "metrics": run.metrics().to_dict("list")},
        standardisation=standardisation,
    )


def _train_forest(run: RunFolder, train: Windows, ctx: TrainContext, training: dict, variant: Variant) -> Path:
    """The forest on the channels the row keeps: those of ``variant.drop_rts``'s categories and the channels of
    ``variant.drop_channels`` are left out of its features, and its record names only the channels it takes (a
    prediction selects them by name)."""
    path = run.path / FOREST_PICKLE
    if not path.exists():
        seen = rts_channel_mask(variant.drop_rts, drop_channels=variant.drop_channels).astype(bool)
        kept = [name for name, keep in zip(rts_schema.CHANNEL_NAMES, seen) if keep]
        forest = fit_random_forest(
            train.rts[..., seen],
            _targets(train, ctx.transform),
            ctx.config.random_forest,
            ctx.config.seed,
            jobs=max(1, torch.get_num_threads()),
        )
        record = {
            "compatibility": compatibility(ctx.windows, ctx.transform, rts_channels=kept),
            "forest": forest,
            "training": training,
        }
        temporary = path.with_name(path.name + ".tmp")
        temporary.write_bytes(pickle.dumps(record))
        temporary.replace(path)
    return path


def with_schedule(config: EstimatorConfig, name: str, schedule: Schedule) -> EstimatorConfig:
    """``config`` with schedule ``name`` replaced (tests and the command line's overrides)."""
    return replace(config, schedules=replace(config.schedules, **{name: schedule}))
