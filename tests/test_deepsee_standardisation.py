"""Per-camera input standardisation: a model trained here reads its input as it is, fine-tuning refits the camera's
statistics on the new camera's sessions and stores them in the model file and its ONNX export, and the shipped model
carries its training data's statistics in both its files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from rich.progress import Progress
from testkit.deepsee import tiny_config, write_session

from estimator.artefact.onnx_model import OnnxModel
from estimator.artefact.standardisation import InputStandardisation
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.checkpoint import load_model, payload_standardisation
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import session_windows
from estimator.deepsee.export import export_onnx
from estimator.deepsee.finetune import finetune
from seesys.core import rts_schema
from seesys.io.core_settings import load_window_config
from seesys.io.resources import resolve

pytestmark = pytest.mark.usefixtures("single_thread")

TRANSFORM = LabelTransform(load_estimator_config().label_transform.k)
CHANNELS = load_estimator_config().input_standardisation.camera_channels


def _windows(session):
    return session_windows(session, load_window_config(), labelled=True)


@pytest.mark.system
def test_a_model_trained_here_reads_its_input_as_it_is(trained_runs):
    _, payload = load_model(trained_runs / "round_0" / "deepsee" / "model.pt", TRANSFORM)
    standardisation = payload_standardisation(payload, "model.pt")
    assert standardisation.channels == CHANNELS and standardisation.reference == standardisation.camera
    rts = np.random.default_rng(0).normal(size=(3, 30, rts_schema.NUM_CHANNELS)).astype(np.float32)
    assert standardisation.apply(rts, rts_schema.CHANNEL_NAMES) is rts


@pytest.mark.system
def test_finetune_refits_the_camera_statistics_and_stores_them_in_the_model_and_its_export(trained_runs, tmp_path):
    """Sessions of another camera (1.6x the contrast, 2.56x the Laplacian variance of the training sessions): the
    fine-tuned model keeps the base's reference, carries the camera's statistics refitted (unlike the base's), and
    reads the camera's channels back at the reference's level."""
    sessions = [write_session(tmp_path / "cam" / f"s{k}", seed=300 + k, frames=150, camera_gain=1.6) for k in range(2)]
    base = trained_runs / "round_0" / "deepsee" / "model.pt"
    base_standardisation = payload_standardisation(load_model(base, TRANSFORM)[1], str(base))
    with Progress(disable=True) as progress:
        result = finetune(
            base,
            sessions,
            tmp_path / "cam.pt",
            tmp_path / "cam_run",
            tiny_config(),
            load_window_config(),
            torch.device("cpu"),
            progress,
            {},
        )
    model, payload = load_model(result.model, TRANSFORM)
    refitted = payload_standardisation(payload, str(result.model))
    assert refitted.channels == CHANNELS and refitted.reference == base_standardisation.reference
    assert refitted.camera != base_standardisation.camera
    contrast, laplacian = CHANNELS.index("contrast"), CHANNELS.index("laplacian")
    assert refitted.camera.median[contrast] > 1.3 * base_standardisation.camera.median[contrast]
    assert refitted.camera.median[laplacian] > base_standardisation.camera.median[laplacian]
    # Through the refitted statistics the camera's channels sit where the training data's did: the median over the
    # whole sessions (the statistics were fitted on the first 75 % of each) within a tenth of the reference's
    # interquartile range of the reference's median.
    windows = [_windows(s) for s in sessions]
    mapped = np.concatenate([refitted.apply(w.rts, rts_schema.CHANNEL_NAMES) for w in windows])
    rows = mapped.reshape(-1, rts_schema.NUM_CHANNELS)
    rows = rows[np.any(rows != 0, axis=-1)]
    for name in ("contrast", "laplacian"):
        k = CHANNELS.index(name)
        column = rts_schema.index_of(name)
        assert abs(np.median(rows[:, column]) - refitted.reference.median[k]) < 0.1 * refitted.reference.iqr[k]
    # The export carries the same values, and the served model applies them.
    exported = export_onnx(
        model,
        tmp_path / "cam.onnx",
        load_window_config(),
        TRANSFORM,
        payload["compatibility"],
        standardisation=refitted,
    )
    served = OnnxModel(exported, TRANSFORM)
    assert served.standardisation == refitted
    np.testing.assert_array_equal(
        served.standardised(windows[0].rts), refitted.apply(windows[0].rts, rts_schema.CHANNEL_NAMES)
    )


def test_the_shipped_model_records_its_training_datas_statistics_in_both_files():
    import torch as _torch

    payload = _torch.load(resolve("data/models/deepsee.pt"), map_location="cpu", weights_only=False)
    stored = payload_standardisation(payload, "deepsee.pt")
    served = OnnxModel(resolve("data/models/deepsee.onnx"), TRANSFORM).standardisation
    # Trained here: the training data's statistics are both its reference and its camera, so it reads its input as
    # it is until fine-tuning refits the camera's.
    assert stored == served and stored.channels == CHANNELS
    assert stored.reference is not None and stored.reference == stored.camera
    rts = np.random.default_rng(1).normal(size=(2, 30, rts_schema.NUM_CHANNELS)).astype(np.float32)
    assert stored.apply(rts, payload["compatibility"]["rts_channels"]) is rts
    refitted = stored.refitted(rts, payload["compatibility"]["rts_channels"])
    assert refitted.reference == stored.reference and refitted.camera != stored.camera


def test_a_malformed_record_is_refused_in_one_line():
    from estimator.artefact.standardisation import StandardisationError

    with pytest.raises(StandardisationError, match=r"^m\.onnx: malformed input standardisation record \(.*\)$"):
        InputStandardisation.from_record(
            {"channels": ["contrast"], "reference": {"median": [1, 2], "iqr": [1]}, "camera": None}, "m.onnx"
        )


@pytest.mark.system
def test_the_learning_curve_fine_tunes_each_budget_from_the_base_and_judges_it_on_held_out_sessions(
    trained_runs, tmp_path
):
    """A smoke test on tiny sessions (5 s each): budgets of 3 and 6 seconds, the base as 0 minutes."""
    from estimator.deepsee.finetune import CURVE_COLUMNS, learning_curve
    from seesys.io.core_settings import load_pulse_settings

    sessions = [write_session(tmp_path / "cam" / f"s{k}", seed=400 + k, frames=150, camera_gain=1.6) for k in range(3)]
    base = trained_runs / "round_0" / "deepsee" / "model.pt"
    with Progress(disable=True) as progress:
        table = learning_curve(
            base,
            sessions[:2],
            sessions[2:],
            [0.1, 0.05],
            tmp_path / "curve",
            tiny_config(),
            load_window_config(),
            torch.device("cpu"),
            progress,
            load_pulse_settings(),
        )
    assert list(table.columns) == list(CURVE_COLUMNS) and list(table.minutes) == [0.0, 0.05, 0.1]
    assert table.train_windows.iloc[0] == 0 and 0 < table.train_windows.iloc[1] < table.train_windows.iloc[2]
    assert table[["agreement", "median_ratio"]].notna().all().all()
    # The reference rows, fitted on each budget's own training windows: none at 0 minutes.
    assert table.iloc[0][["constant_agreement", "motion_isotonic_kappa"]].isna().all()
    assert table.iloc[1:][["constant_agreement", "always_top_agreement", "motion_isotonic_aurg"]].notna().all().all()
    assert (tmp_path / "curve" / "learning_curve.csv").is_file() and (tmp_path / "curve" / "0.1min.pt").is_file()
