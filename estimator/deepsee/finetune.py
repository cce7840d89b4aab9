"""Stage (d) on a lab's own labelled sessions (``seesys estimator finetune``): any session folder with ground truth
(a study session with motion capture, a TUM or EuRoC recording run through ``seesys monitor run``), labelled with
:func:`seesys.core.labels.label_session`, the definition the dataset uses.

Each session is split in time: its first part trains, its last ``validation_fraction`` decides early stopping and gives
the before/after figures (windows of one session are strongly correlated, so a random split would let the model see the
validation windows' neighbours). Few-shot friendly: the whole model is fine-tuned with a small learning rate from the
given model, and the best epoch on the validation part is kept (the given model itself when no epoch beats it). A model
with an ordinal head is fine-tuned on MSE + λ·BCE, its head with the rest; a model without one (the shipped model,
trained before the head) stays without one. Whole held-out sessions, never trained on, are judged before and after with
the scores of the Table 3 report (:func:`estimator.deepsee.metrics.score`): the in-session validation tail is correlated
with the training part and flatters the model. Beside the model, the held-out sessions are judged for the reference
rows of :mod:`estimator.deepsee.references` (a constant class, always the top class, the motion alone) fitted on the
same training part: what the fine-tuned model has to beat with the same minutes of data.

The per-camera input standardisation (:mod:`estimator.artefact.standardisation`) is refitted first: the camera's
statistics of the camera-dependent channels come from the training part of the sessions, the base's reference
statistics are kept, and the model is fine-tuned, judged after and stored with the refitted values (the before figures
are the base's, served as it is).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from estimator.artefact.compatibility import check_normalisation, rts_columns
from estimator.artefact.standardisation import InputStandardisation
from estimator.deepsee.checkpoint import load_model, payload_standardisation, save_model
from estimator.deepsee.config import EstimatorConfig
from estimator.deepsee.data import NORMALISATION_COLUMN, DataError, Windows, concat, session_windows
from estimator.deepsee.inference import predict, predict_outputs
from estimator.deepsee.metrics import CM_PER_M, Scores, equation2_head, score
from estimator.deepsee.ordinal import model_thresholds
from estimator.deepsee.references import (
    ALWAYS_TOP,
    CONSTANT,
    MOTION_ISOTONIC,
    fit_references,
    motion_statistic,
)
from estimator.deepsee.run_folder import RunFolder
from estimator.deepsee.stages import TrainContext, supervised
from seesys.core.equation2 import PulseSettings
from seesys.core.windows import WindowConfig
from seesys.io.session_files import read_manifest


@dataclass(frozen=True)
class FinetuneResult:
    model: Path
    train_windows: int
    validation_windows: int
    rmse_before_cm: float
    rmse_after_cm: float
    held_out_before: Scores | None  # the held-out sessions, all windows together; None without any
    held_out_after: Scores | None
    held_out_references: dict[str, Scores] | None = None  # each reference row's, fitted on the training part


def split_in_time(windows: Windows, validation_fraction: float) -> tuple[Windows, Windows]:
    """The first (1 − fraction) of a session's windows by end frame, and the rest."""
    order = np.argsort(windows.meta.frame_index.to_numpy(), kind="stable")
    cut = int(round(len(order) * (1 - validation_fraction)))
    return windows.subset(order[:cut]), windows.subset(order[cut:])


def first_seconds(sessions: list[Windows], seconds: float) -> list[Windows]:
    """The windows of the first ``seconds`` of recording of ``sessions``, taken in their order: whole sessions while
    they fit, the next one cut in time, the rest left out."""
    out, left = [], float(seconds)
    for windows in sessions:
        if left < 0 or not len(windows):
            break
        elapsed = windows.meta.timestamp.to_numpy(np.float64)
        elapsed = elapsed - elapsed.min()
        out.append(windows.subset(np.flatnonzero(elapsed <= left)))
        left -= float(elapsed.max()) + 1.0 / len(elapsed)  # the span the session's windows cover, about
    return out


def _camera_of(session: Path) -> str:
    """The camera a session was recorded with, as its manifest describes the source (``session.json``)."""
    try:
        manifest = read_manifest(Path(session))
    except (OSError, ValueError):
        return f"the camera of {session}"
    return str(manifest.get("source_description") or manifest.get("source") or f"the camera of {session}")


def finetune(
    base: Path,
    sessions: list[Path],
    out: Path,
    run_dir: Path,
    config: EstimatorConfig,
    windows: WindowConfig,
    device: torch.device,
    progress,
    provenance: dict,
    held_out: Sequence[Path] = (),
    pulses: PulseSettings | None = None,
    budget_s: float | None = None,
) -> FinetuneResult:
    """Fine-tune ``base`` on ``sessions`` into ``out`` (on their first ``budget_s`` seconds only, when given:
    :func:`first_seconds`); ``held_out`` sessions (scored with ``advisory``'s Equation 2) are only judged."""
    overlap = sorted({Path(s).resolve() for s in sessions} & {Path(s).resolve() for s in held_out})
    if overlap:
        raise DataError(f"sessions both fine-tuned on and held out: {', '.join(map(str, overlap))}")
    if held_out and pulses is None:
        raise ValueError("held-out sessions are scored with the advisory's Equation 2: pass pulses")
    test = concat([session_windows(s, windows, labelled=True) for s in held_out]) if held_out else None
    labelled = [session_windows(s, windows, labelled=True) for s in sessions]
    if budget_s is not None:
        labelled = first_seconds(labelled, budget_s)
    parts = [split_in_time(w, config.finetune.validation_fraction) for w in labelled]
    train, val = concat([p[0] for p in parts]), concat([p[1] for p in parts])
    # The motion statistic reads every channel of the schema: taken before the model's columns are selected.
    motion = motion_statistic(test.rts) if test is not None else None
    references = None
    if test is not None and pulses is not None:
        fitted = fit_references(train, pulses)
        references = {
            name: score(test.meta, estimate, test.error_m, config.evaluation, pulses, None, motion)
            for name, estimate in fitted.estimates(test).items()
        }
    if not len(val):
        raise DataError(
            "the sessions leave no validation windows: record longer sessions or raise "
            "validation_fraction in configs/estimator.toml"
        )
    ctx = TrainContext(
        config,
        "reduced",
        windows,
        device,
        progress,
        {"base_model": str(base), "sessions": [str(s) for s in sessions], **provenance},
    )
    transform = ctx.transform
    model, payload = load_model(base, transform, windows)
    model = model.to(device)
    check_normalisation(payload["compatibility"], train.meta[NORMALISATION_COLUMN], "the fine-tuning sessions")
    if test is not None:
        check_normalisation(payload["compatibility"], test.meta[NORMALISATION_COLUMN], "the held-out sessions")
    # The base model takes the RTS channels it was trained with; a later schema's rows hold them among others.
    columns = rts_columns(payload["compatibility"], str(base))
    channels = payload["compatibility"]["rts_channels"]
    train, val = train.select_rts(columns), val.select_rts(columns)
    test = test.select_rts(columns) if test is not None else None
    # Before: the base as it would serve these sessions. Then the camera's statistics refitted on the sessions it
    # trains on, and everything after seen through them, as the fine-tuned model will serve this camera.
    base_standardisation = payload_standardisation(payload, str(base))
    if not base_standardisation.channels:  # a model file made before standardisation: the configured channels
        base_standardisation = InputStandardisation(config.input_standardisation.camera_channels, None, None)
    standardisation = base_standardisation.refitted(train.rts, channels)

    def estimate_m(data: Windows, through: InputStandardisation) -> np.ndarray:
        return transform.inverse(
            predict(model, data.with_rts(through.apply(data.rts, channels)), config.evaluation.batch_size, device)
        )

    def rmse_cm(through: InputStandardisation) -> float:
        return CM_PER_M * float(np.sqrt(np.mean((estimate_m(val, through) - val.error_m) ** 2)))

    def judge(through: InputStandardisation) -> Scores | None:
        if not test or pulses is None:  # held-out sessions come with pulses (checked above)
            return None
        y, probabilities = predict_outputs(
            model, test.with_rts(through.apply(test.rts, channels)), config.evaluation.batch_size, device
        )
        return score(
            test.meta,
            transform.inverse(y),
            test.error_m,
            config.evaluation,
            pulses,
            equation2_head(probabilities, model_thresholds(model), pulses),
            motion,
        )

    before, held_out_before = rmse_cm(base_standardisation), judge(base_standardisation)
    run = RunFolder(
        run_dir,
        {
            "finetune": asdict(config.finetune),
            "base_compatibility_hash": payload["compatibility_hash"],
            **ctx.provenance,
        },
        device,
    )
    supervised(
        run,
        "finetune_sessions",
        model,
        train.with_rts(standardisation.apply(train.rts, channels)),
        val.with_rts(standardisation.apply(val.rts, channels)),
        config.finetune.schedule,
        ctx,
    )
    after, held_out_after = rmse_cm(standardisation), judge(standardisation)
    cameras = list(dict.fromkeys(payload["training"].get("finetuned_cameras", []) + [_camera_of(s) for s in sessions]))
    training = {
        **payload["training"],
        "finetuned_on": [str(s) for s in sessions],
        "finetuned_cameras": cameras,
        "train_windows": len(train),
        "validation_windows": len(val),
        "rmse_before_cm": before,
        "rmse_after_cm": after,
        "held_out": [str(s) for s in held_out],
        "held_out_before": asdict(held_out_before) if held_out_before else None,
        "held_out_after": asdict(held_out_after) if held_out_after else None,
    }
    save_model(out, model.cpu(), windows, transform, training, channels, standardisation)
    return FinetuneResult(Path(out), len(train), len(val), before, after, held_out_before, held_out_after, references)


#: The reference rows of the learning curve and their figures on the held-out sessions.
CURVE_REFERENCES = (CONSTANT, ALWAYS_TOP, MOTION_ISOTONIC)
CURVE_REFERENCE_FIGURES = ("agreement", "kappa", "aurg")
#: The columns of :func:`learning_curve`'s table: the model's figures, then each reference row's
#: (``<row>_<figure>``), fitted on the same budget's training windows (NaN at 0 minutes: nothing to fit on).
CURVE_COLUMNS = (
    "minutes",
    "train_windows",
    "agreement",
    "kappa",
    "aurg",
    "median_ratio",
    "rmse_cm",
    "spearman",
    "partial_spearman",
) + tuple(f"{row}_{figure}" for row in CURVE_REFERENCES for figure in CURVE_REFERENCE_FIGURES)


def learning_curve(
    base: Path,
    sessions: list[Path],
    held_out: list[Path],
    minutes: list[float],
    out: Path,
    config: EstimatorConfig,
    windows: WindowConfig,
    device: torch.device,
    progress,
    pulses: PulseSettings,
) -> pd.DataFrame:
    """Fine-tune ``base`` on the first ``minutes`` of ``sessions`` (an unseen camera's), each budget from the base
    again, and judge every result on the ``held_out`` sessions: one row per budget (:data:`CURVE_COLUMNS`), the base
    itself as 0 minutes; written to ``out/learning_curve.csv``, the models and run folders beside it."""
    if not held_out:
        raise DataError("a learning curve is judged on held-out sessions: give some")
    rows: list[tuple] = []
    for budget in sorted(minutes):
        if budget <= 0:
            raise DataError(f"fine-tuning budgets are minutes above 0, got {budget:g}")
        name = f"{budget:g}min"
        result = finetune(
            base,
            sessions,
            out / f"{name}.pt",
            out / f"{name}_run",
            config,
            windows,
            device,
            progress,
            {"learning_curve_minutes": budget},
            held_out,
            pulses,
            budget * 60.0,
        )
        before, after = result.held_out_before, result.held_out_after
        if before is None or after is None:
            raise DataError("the held-out sessions give no windows to judge the learning curve on")
        if not rows:
            rows.append(_curve_row(0.0, 0, before, None))
        rows.append(_curve_row(budget, result.train_windows, after, result.held_out_references))
    table = pd.DataFrame(rows, columns=list(CURVE_COLUMNS))
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "learning_curve.csv", index=False)
    return table


def _curve_row(minutes: float, train_windows: int, scores: Scores, references: dict[str, Scores] | None) -> tuple:
    own = (
        minutes,
        train_windows,
        scores.agreement,
        scores.kappa,
        scores.aurg,
        scores.median_ratio,
        scores.rmse_cm,
        scores.spearman,
        scores.partial_spearman,
    )
    return own + tuple(
        getattr(references[row], figure) if references else float("nan")
        for row in CURVE_REFERENCES
        for figure in CURVE_REFERENCE_FIGURES
    )
