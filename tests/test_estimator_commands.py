"""``seesys estimator`` evaluate / export / estimate and fine-tuning on sessions, on the tiny dataset's models."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from rich.progress import Progress
from testkit.deepsee import tiny_config, tiny_config_dir, write_session

from advisory.estimate_log import read_estimate_log
from estimator.artefact.onnx_model import recorded_training, training_cameras
from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.channels import judged_channels
from estimator.deepsee.checkpoint import ModelMismatch, load_model, payload_standardisation
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.data import DataError, concat, session_windows
from estimator.deepsee.evaluate import OUT_OF_DOMAIN, session_set
from estimator.deepsee.export import PARITY_TOLERANCE, OnnxModel, parity
from estimator.deepsee.finetune import finetune
from estimator.deepsee.predictors import WindowEstimates, load_predictor
from estimator.deepsee.report import (
    CALIBRATION_CSV,
    CAMERAS_CSV,
    CHANNELS_CSV,
    CONFUSION_PNG,
    DIFFERENCES_CSV,
    RELIABILITY_PNG,
    REPORT_MD,
    SCATTER_PNG,
    TIMESERIES_PNG,
    improvements,
)
from seesys.io import session_files
from seesys.io.core_settings import load_pulse_settings, load_window_config
from seesys_app.cli import main

pytestmark = pytest.mark.usefixtures("single_thread")

TRANSFORM = LabelTransform(10000.0)
REPO = Path(__file__).resolve().parent.parent


def _model(trained_runs, row="deepsee"):
    return trained_runs / "round_0" / row / "model.pt"


@pytest.mark.system
def test_evaluate_writes_the_table3_report(tiny_dataset, trained_runs, tmp_path, capsys):
    other = [write_session(tmp_path / "other_renderer" / f"s{k}", seed=100 + k, noise_scale=2.0) for k in range(2)]
    for folder in other:  # two SLAM trials of one recording: each the other's ceiling
        session_files.update_manifest(folder, source="tum:other_renderer")
    out = tmp_path / "report"
    assert (
        main(
            [
                "estimator",
                "evaluate",
                "--data",
                str(tiny_dataset.root),
                "--splits",
                str(tiny_dataset.splits),
                "--runs",
                str(trained_runs),
                "--rounds",
                "0",
                "--sessions",
                *map(str, other),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = (out / REPORT_MD).read_text()
    # The two sessions pooled, and each alone.
    each = {session_set("s0"), session_set("s1")}
    for heading in ("test trajectories", "held-out environments", "out-of-domain sessions", *sorted(each)):
        assert f"## {heading}" in report
    for label in (
        "| Baseline | Random Forest |",
        "| Baseline | LSTM |",
        "| Model Study | DeepSEE-w/o-PSD |",
        "| DeepSEE | DeepSEE |",
    ):
        assert label in report
    assert "DeepSEE vs random_forest, RMSE 1 mm–2 cm:" in report and "reduced, cpu" in report
    for png in (TIMESERIES_PNG, SCATTER_PNG, CONFUSION_PNG):
        assert (out / png).stat().st_size > 5000 and f"]({png})" in report
    scores = pd.read_csv(out / "scores.csv")
    assert set(scores.row) == {
        "deepsee",
        "wo_psd",
        "lstm",
        "random_forest",
        "constant",
        "always_top",
        "motion_isotonic",
        "ceiling",
    }
    # The tiny dataset tracked each render once: a ceiling only where the sessions are trials of one recording.
    assert set(scores[scores.row == "ceiling"].set) == {OUT_OF_DOMAIN, *each}
    by_session = scores[(scores.row == "deepsee") & scores.set.isin(each)].set_index("set").windows
    pooled = scores[(scores.row == "deepsee") & (scores.set == OUT_OF_DOMAIN)].windows.iloc[0]
    assert set(by_session.index) == each and by_session.sum() == pooled > 0
    deepsee = scores[(scores.row == "deepsee") & (scores.set == "test trajectories")].iloc[0]
    assert deepsee.windows > 100 and 0 < deepsee.rmse_cm < 2 and deepsee.spearman > 0.3
    assert 0 <= deepsee.agreement <= 1 and deepsee.bins > 10
    # DeepSEE and its ablation have the ordinal head: its agreement and recall are columns of the table; the
    # baselines have none.
    assert 0 <= deepsee.head_agreement <= 1
    assert scores[scores.row.isin(["lstm", "random_forest"])].head_agreement.isna().all()
    assert "head agreement | head κ | head recall ≥ 12 mm | head Brier | head ECE |" in report
    # The reference rows on the same windows as the models, in every set; a constant's κ and AURG are 0.
    for _, part in scores.groupby("set"):
        assert {"constant", "always_top", "motion_isotonic"} <= set(part.row)
        assert part.windows.nunique() == 1
    constant = scores[scores.row == "constant"]
    assert (constant.kappa.fillna(0).abs() < 1e-9).all() and (constant.aurg.abs() < 1e-9).all()
    assert "| Reference | motion only (isotonic) |" in report and "against the targets" in report
    # Intervals over runs beside the yardsticks; the tiny dataset's test trajectories are one run.
    assert deepsee.runs == 1 and np.isnan(deepsee.kappa_low)
    pooled = scores[(scores.row == "deepsee") & (scores.set == OUT_OF_DOMAIN)].iloc[0]
    assert pooled.runs == 2 and pooled.kappa_low <= pooled.kappa <= pooled.kappa_high
    assert -1 <= deepsee.kappa <= 1 and deepsee.ause >= 0 and np.isfinite(deepsee.partial_spearman)
    cameras = pd.read_csv(out / CAMERAS_CSV)
    assert set(cameras.row) >= {"deepsee", "motion_isotonic"} and cameras.median_ratio.notna().all()
    calibration = pd.read_csv(out / CALIBRATION_CSV)
    assert set(calibration.row) == {"deepsee", "wo_psd"} and calibration.threshold_m.nunique() == 3
    assert (out / RELIABILITY_PNG).stat().st_size > 5000
    # The geometry channels alone, per set (the sessions' too), each by the feature chosen on the training windows.
    channels = pd.read_csv(out / CHANNELS_CSV)
    assert set(channels.set) == {"test trajectories", "held-out environments", OUT_OF_DOMAIN, *each}
    assert 0 < channels[channels.set == OUT_OF_DOMAIN].windows.max() <= pooled.windows
    assert set(channels.channel) == set(judged_channels())
    chosen = channels[channels.chosen]
    assert not chosen.empty and chosen.groupby(["set", "round", "channel"]).size().eq(1).all()
    assert "The geometry channels alone" in report
    # Every trained row against the motion row and the forest, paired over runs; the forest not against itself.
    differences = pd.read_csv(out / DIFFERENCES_CSV)
    pooled_pairs = differences[differences.set == OUT_OF_DOMAIN]
    assert set(zip(pooled_pairs.row, pooled_pairs.against)) == {
        (row, against)
        for row in ("deepsee", "wo_psd", "lstm", "random_forest")
        for against in ("motion_isotonic", "random_forest")
        if row != against
    }
    deepsee_pair = pooled_pairs[(pooled_pairs.row == "deepsee") & (pooled_pairs.against == "motion_isotonic")].iloc[0]
    by_row = scores[scores.set == OUT_OF_DOMAIN].set_index("row").kappa
    assert deepsee_pair.kappa == pytest.approx(by_row["deepsee"] - by_row["motion_isotonic"])
    assert deepsee_pair.kappa_low <= deepsee_pair.kappa <= deepsee_pair.kappa_high
    assert "Paired over runs" in report


@pytest.mark.system
def test_the_lockbox_is_judged_for_a_shipped_model_only_through_its_own_command(
    tiny_dataset, trained_runs, tmp_path, capsys
):
    from estimator.dataset.build import label_run
    from estimator.dataset.config import load_dataset_config
    from estimator.dataset.splits import Lockbox, Splits
    from estimator.dataset.store import COMPLETED, RUNS_DIR, RunInfo, write_run
    from seesys.core import camera_normalisation
    from seesys.io.core_settings import load_label_config
    from slam_monitor.orbslam_settings import SlamMode

    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset.root, root)
    lockbox = load_dataset_config().lockbox
    name = f"{lockbox.environment}__traj_g__s0__rgbd__t0"
    folder = write_session(tmp_path / "sessions" / name, seed=50, frames=120)
    arrays = label_run(
        folder, SlamMode.RGBD, load_label_config(), dataclasses.replace(load_window_config(), end_stride=1)
    )
    write_run(
        root,
        RunInfo(
            name,
            name.rsplit("__", 2)[0],
            lockbox.environment,
            "patrol",
            "traj_g",
            "rgbd",
            0,
            COMPLETED,
            frames=120,
            frames_tracked=120,
            samples=len(arrays.samples),
            camera_normalisation=camera_normalisation.VERSION,
        ),
        arrays,
    )
    tiny = Splits.from_json(tiny_dataset.splits.read_text())
    splits = tmp_path / "splits.json"
    box = Lockbox(lockbox.environment, lockbox.camera_model, lockbox.sha256, [name])
    splits.write_text(dataclasses.replace(tiny, lockbox=box).to_json())

    def judge(data: Path, split_file: Path, out: Path, *fresh: Path) -> int:
        arguments = ["estimator", "lockbox", "--data", str(data), "--splits", str(split_file)]
        arguments += ["--model", str(_model(trained_runs)), "--out", str(out)]
        return main(arguments + (["--fresh", *map(str, fresh)] if fresh else []))

    out = tmp_path / "lockbox"
    assert judge(root, splits, out) == 0
    scores = pd.read_csv(out / "scores.csv")
    assert set(scores.set) == {"lockbox", f"lockbox room {lockbox.environment}"}  # no run through its camera
    assert set(scores.row) == {"deepsee", "constant", "always_top", "motion_isotonic"}
    assert (scores.windows == len(arrays.samples[arrays.samples.usable.astype(bool)])).all()
    channels = pd.read_csv(out / CHANNELS_CSV)
    assert set(channels.set) == set(scores.set) and channels.chosen.any()
    # The same run as a fresh lockbox (new renders in their own folder, beside a build whose lockbox holds none):
    # judged alone, as before.
    fresh = tmp_path / "fresh"
    shutil.copytree(root, fresh, ignore=shutil.ignore_patterns(RUNS_DIR))
    shutil.copytree(root / RUNS_DIR / name, fresh / RUNS_DIR / name)
    empty = tmp_path / "empty-box-splits.json"
    empty.write_text(dataclasses.replace(tiny, lockbox=dataclasses.replace(box, runs=[])).to_json())
    assert judge(tiny_dataset.root, empty, tmp_path / "fresh-lockbox", fresh) == 0
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "fresh-lockbox" / "scores.csv"), scores)
    capsys.readouterr()
    # A fresh run that the splits already hold, or one of another room and camera, is refused in one line.
    assert judge(root, splits, tmp_path / "stale", fresh) != 0
    error = capsys.readouterr().err.strip()
    assert f"fresh run {name} is a run of the splits already" in error and len(error.splitlines()) == 1
    assert judge(tiny_dataset.root, empty, tmp_path / "other", fresh, tiny_dataset.root) != 0
    error = capsys.readouterr().err.strip()
    assert "is neither in the lockbox's room" in error and len(error.splitlines()) == 1
    # The splits of the rounds hold none: nothing to judge, said in one line.
    capsys.readouterr()
    assert (
        main(
            [
                "estimator",
                "lockbox",
                "--data",
                str(tiny_dataset.root),
                "--splits",
                str(tiny_dataset.splits),
                "--model",
                str(_model(trained_runs)),
                "--out",
                str(tmp_path / "none"),
            ]
        )
        != 0
    )
    error = capsys.readouterr().err.strip()
    assert "these splits hold no lockbox runs" in error and len(error.splitlines()) == 1


@pytest.mark.system
def test_a_render_tracked_twice_gets_a_ceiling_row_on_its_windows(tiny_dataset, trained_runs, tmp_path):
    """The tiny dataset with a second trial of its test trajectory's render: evaluate adds the ceiling row there."""
    from estimator.dataset.build import label_run
    from estimator.dataset.splits import Splits
    from estimator.dataset.store import COMPLETED, list_runs, write_run
    from seesys.core import camera_normalisation
    from seesys.io.core_settings import load_label_config
    from slam_monitor.orbslam_settings import SlamMode

    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset.root, root)
    splits = Splits.from_json(tiny_dataset.splits.read_text())
    first = next(
        i
        for i in list_runs(root)
        if i.trajectory in splits.rounds[0].test_trajectories and i.environment not in splits.heldout_environments
    )
    second = dataclasses.replace(first, run=first.run.replace("__t0", "__t1"), trial=1)
    folder = write_session(tmp_path / "sessions" / second.run, seed=77, frames=first.frames)
    arrays = label_run(
        folder, SlamMode.RGBD, load_label_config(), dataclasses.replace(load_window_config(), end_stride=1)
    )
    write_run(
        root,
        dataclasses.replace(
            second, samples=len(arrays.samples), status=COMPLETED, camera_normalisation=camera_normalisation.VERSION
        ),
        arrays,
    )
    splits.rounds[0].test.append(second.run)
    splits_path = tmp_path / "splits.json"
    splits_path.write_text(splits.to_json())
    runs = tmp_path / "runs"
    shutil.copytree(trained_runs / "round_0" / "random_forest", runs / "round_0" / "random_forest")
    out = tmp_path / "report"
    assert (
        main(
            [
                "estimator",
                "evaluate",
                "--data",
                str(root),
                "--splits",
                str(splits_path),
                "--runs",
                str(runs),
                "--rounds",
                "0",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    scores = pd.read_csv(out / "scores.csv").set_index(["set", "row"])
    ceiling = scores.loc[("test trajectories", "ceiling")]
    # Each trial's windows are judged by the other's truth: all of the set's windows where both labelled the frame.
    assert 0 < ceiling.windows <= scores.loc[("test trajectories", "random_forest")].windows
    assert ceiling.runs == 2 and -1 <= ceiling.kappa <= 1 and np.isfinite(ceiling.spearman)
    assert ("held-out environments", "ceiling") not in scores.index  # its render was tracked once
    assert "| Ceiling | another SLAM trial of the same render |" in (out / REPORT_MD).read_text()


def test_the_report_gives_deepsees_gain_on_both_rmses_per_round_and_in_the_mean():
    rows = []
    for r, (deepsee, forest) in enumerate([(0.8, 1.0), (0.95, 1.0), (0.6, 1.0)]):
        for row, range_rmse in (("deepsee", deepsee), ("random_forest", forest)):
            rows.append(
                {"set": "test trajectories", "round": r, "row": row, "rmse_cm": 10.0, "rmse_paper_range_cm": range_rmse}
            )
    targets = load_estimator_config().targets
    lines = improvements(pd.DataFrame(rows), "test trajectories", targets)
    # No LSTM in these scores: one line per RMSE, against the forest only.
    assert lines == [
        "- DeepSEE vs random_forest, RMSE: +0.0 % lower (mean over 3 rounds; target ≥ 15 %: NOT reached; "
        "per round +0 %, +0 %, +0 %, 0 of 3 reach it)",
        "- DeepSEE vs random_forest, RMSE 1 mm–2 cm: +21.7 % lower (mean over 3 rounds; target ≥ 15 %: reached; "
        "per round +20 %, +5 %, +40 %, 2 of 3 reach it)",
    ]
    assert improvements(pd.DataFrame(rows), "held-out environments", targets) == []


def test_two_out_of_domain_sessions_of_one_folder_name_are_refused(tmp_path):
    from estimator.deepsee.evaluate import session_raw_sets
    from seesys.core.errors import SeesysError

    with pytest.raises(SeesysError, match=r"two out-of-domain sessions share a folder name \(s, s\)"):
        session_raw_sets([tmp_path / "a" / "s", tmp_path / "b" / "s"], load_window_config())


@pytest.mark.system
def test_ablation_rows_start_from_the_pretrained_encoders(trained_runs):
    metrics = pd.read_csv(trained_runs / "round_0" / "wo_psd" / "metrics.csv")
    assert set(metrics.stage) == {"c_supervised_frozen", "d_finetune"}  # no second pretraining
    pretrained = torch.load(trained_runs / "round_0" / "deepsee" / "state" / "encoders.pt")["rts_encoder"]
    # Stage (c) keeps the encoders frozen: its checkpoint holds DeepSEE's pretrained RTS encoder unchanged.
    ablation_state = torch.load(
        trained_runs / "round_0" / "wo_psd" / "state" / "c_supervised_frozen.pt", weights_only=False
    )["module"]
    for name, value in pretrained.items():
        torch.testing.assert_close(ablation_state[f"rts_encoder.{name}"], value)


@pytest.mark.system
def test_export_to_onnx_then_estimate_a_session_for_the_advisory(tiny_dataset, trained_runs, tmp_path, capsys):
    """The exported file holds its weights (it works moved alone), matches PyTorch, refuses other inputs; the
    per-frame estimates of a session, from the checkpoint, the ONNX file or the forest, are a log the advisory
    reads."""
    exported = tmp_path / "export" / "deepsee.onnx"
    assert main(["estimator", "export", str(_model(trained_runs)), "--out", str(exported)]) == 0
    assert "parity with PyTorch" in capsys.readouterr().out
    assert list(exported.parent.iterdir()) == [exported]  # no side file of weights
    onnx_path = tmp_path / "elsewhere" / "m.onnx"
    onnx_path.parent.mkdir()
    exported.rename(onnx_path)
    model, payload = load_model(_model(trained_runs), TRANSFORM)
    assert parity(model, OnnxModel(onnx_path, TRANSFORM)) <= PARITY_TOLERANCE
    # The cameras of its training runs travel with it (what the app tells its user).
    cameras = payload["training"]["cameras"]
    assert cameras and OnnxModel(onnx_path, TRANSFORM).cameras == recorded_training(onnx_path).cameras == cameras
    # So does its input standardisation (fitted on its training windows).
    standardisation = payload_standardisation(payload, "model.pt")
    assert standardisation.reference is not None and OnnxModel(onnx_path, TRANSFORM).standardisation == standardisation
    with pytest.raises(ModelMismatch, match="label transform"):
        OnnxModel(onnx_path, LabelTransform(100.0))
    with pytest.raises(ModelMismatch, match="windows"):
        OnnxModel(onnx_path, TRANSFORM, dataclasses.replace(load_window_config(), rts_length=20))

    session = sorted(tiny_dataset.sessions.iterdir())[0]
    head = ["p_ge_0.004", "p_ge_0.008", "p_ge_0.012", "head_class"]
    for path, columns in (
        (_model(trained_runs), head),
        (onnx_path, head),
        (trained_runs / "round_0" / "random_forest" / "model.pkl", []),
    ):
        out = tmp_path / f"{path.suffix[1:]}.csv"
        assert main(["estimator", "estimate", str(session), "--model", str(path), "--out", str(out)]) == 0
        table = pd.read_csv(out)
        assert list(table.columns) == ["frame_index", "timestamp", "error_m"] + columns
        log = read_estimate_log(out)
        assert len(log.timestamps) == len(table) > 100 and (log.errors_m >= 0).all()
    torch_estimates = pd.read_csv(tmp_path / "pt.csv")
    onnx_estimates = pd.read_csv(tmp_path / "onnx.csv")
    np.testing.assert_allclose(onnx_estimates.error_m, torch_estimates.error_m, rtol=1e-3, atol=1e-7)
    probabilities = torch_estimates[head[:3]].to_numpy()
    assert ((probabilities >= 0) & (probabilities <= 1)).all() and (np.diff(probabilities, axis=1) <= 0).all()
    assert (torch_estimates.head_class == (probabilities >= 0.5).sum(axis=1)).all()
    assert read_estimate_log(tmp_path / "pt.csv").head_thresholds_m == (0.004, 0.008, 0.012)  # render plays it
    np.testing.assert_allclose(onnx_estimates[head[:3]], probabilities, atol=1e-4)
    assert (
        main(
            [
                "estimator",
                "estimate",
                str(session),
                "--model",
                str(tmp_path / "none.pt"),
                "--out",
                str(tmp_path / "x.csv"),
            ]
        )
        == 2
    )
    assert "model file not found" in capsys.readouterr().err


@pytest.mark.system
def test_finetune_on_a_few_sessions_lowers_the_error_on_held_out_sessions(trained_runs, tmp_path):
    """Sessions from another 'camera' (the same inputs mean 3× larger errors): fine-tuning on three of them makes the
    estimates of two others, never seen, closer to their labels."""
    sessions = [write_session(tmp_path / "lab" / f"s{k}", seed=200 + k, noise_scale=3.0) for k in range(5)]
    train, held_out = sessions[:3], sessions[3:]
    windows = load_window_config()
    truth = concat([session_windows(s, windows, labelled=True) for s in held_out])
    config = tiny_config()

    def rmse(model_path) -> float:
        predictor = load_predictor(model_path, TRANSFORM, 64)
        return float(np.sqrt(np.mean((predictor.metres(truth) - truth.error_m) ** 2)))

    base = _model(trained_runs)
    with Progress(disable=True) as progress:
        result = finetune(
            base,
            train,
            tmp_path / "lab.pt",
            tmp_path / "lab_run",
            config,
            windows,
            torch.device("cpu"),
            progress,
            {},
            held_out,
            load_pulse_settings(),
        )
        with pytest.raises(DataError, match="both fine-tuned on and held out"):
            finetune(
                base,
                train,
                tmp_path / "x.pt",
                tmp_path / "x_run",
                config,
                windows,
                torch.device("cpu"),
                progress,
                {},
                held_out[:1] + train[:1],
                load_pulse_settings(),
            )
    assert result.train_windows > 3 * result.validation_windows > 0
    assert result.rmse_after_cm < result.rmse_before_cm
    before, after = rmse(base), rmse(result.model)
    assert after < 0.8 * before, (before, after)
    # the command's own judgement of the held-out sessions is the same measurement
    assert result.held_out_before.windows == len(truth)
    assert result.held_out_before.rmse_cm == pytest.approx(100 * before, rel=1e-4)
    assert result.held_out_after.rmse_cm == pytest.approx(100 * after, rel=1e-4)
    training = load_model(result.model, TRANSFORM)[1]["training"]
    assert training["finetuned_on"] == [str(s) for s in train] and training["held_out"] == [str(s) for s in held_out]
    # The sessions' camera after the dataset's: their source as each manifest describes it (these sessions were
    # written without a source, so each is named by its folder).
    sources = [f"the camera of {s}" for s in train]
    assert training["finetuned_cameras"] == list(dict.fromkeys(sources))
    assert training_cameras(training) == training["cameras"] + list(dict.fromkeys(sources))


@pytest.mark.system
def test_windows_of_another_camera_are_refused_with_a_clear_error(trained_runs, tmp_path):
    session = write_session(tmp_path / "vga", seed=7, frames=80)
    windows = session_windows(session, load_window_config(), labelled=False)
    wide = dataclasses.replace(windows, psd=np.zeros((len(windows), 4, 64, 96, 3), np.uint8))
    predictor = load_predictor(_model(trained_runs), TRANSFORM, 64)
    assert len(predictor.metres(windows)) == len(windows)
    with pytest.raises(DataError, match="psd_height=64, psd_width=96.*another PSD grid"):
        predictor.metres(wide)
    forest = load_predictor(trained_runs / "round_0" / "random_forest" / "model.pkl", TRANSFORM, 64)
    assert len(forest.metres(wide)) == len(windows)  # the forest reads the RTS window only


@pytest.mark.system
def test_cli_trains_a_row_into_a_run_folder_and_resumes(tiny_dataset, tmp_path, capsys, monkeypatch):
    """``seesys estimator train`` with configs/estimator.toml replaced by the tiny configuration."""
    configs = tiny_config_dir(tmp_path / "configs")
    args = [
        "estimator",
        "train",
        "--data",
        str(tiny_dataset.root),
        "--splits",
        str(tiny_dataset.splits),
        "--row",
        "lstm",
        "--out",
        str(tmp_path / "run"),
        "--threads",
        "1",
    ]
    monkeypatch.setenv("SEESYS_CONFIG_DIR", str(configs))
    assert main(args) == 0
    assert "trained lstm (round 0, reduced schedule, cpu)" in capsys.readouterr().out
    assert main(args) == 0  # resumed: nothing left to train
    assert main(args[:-2] + ["--schedule", "full"]) == 2
    assert "holds a run with a different schedule" in capsys.readouterr().err
    metrics = pd.read_csv(tmp_path / "run" / "metrics.csv")
    schedule = tiny_config().schedules.reduced.lstm
    # Every epoch once (the resumed calls trained none again): all of them, or up to the early stop, which comes
    # only after `patience` epochs in a row that did not improve.
    assert set(metrics.stage) == {"lstm"} and list(metrics.epoch) == list(range(len(metrics)))
    assert schedule.patience < len(metrics) <= schedule.epochs + 1
    assert len(metrics) == schedule.epochs + 1 or not metrics.best.iloc[-schedule.patience :].any()


class _ConstantPredictor:
    """A stand-in model without a head: the same estimate for every window (the estimate log's format is under
    test, not a model)."""

    thresholds_m = ()

    def estimates(self, windows) -> WindowEstimates:
        return WindowEstimates(np.full(len(windows), 0.02), None)


def test_a_session_with_epoch_timestamps_renders_its_pulses_across_its_whole_duration(tmp_path):
    """Epoch times (a RealSense or TUM recording) keep their milliseconds in the estimate log, so the advisory's
    pulses follow the session instead of piling up at its start."""
    from testkit.deepsee import FPS

    from advisory.config import load_advisory_config
    from advisory.render import render_estimates
    from estimator.deepsee.estimate import estimate_session

    session = write_session(tmp_path / "epoch", seed=7, frames=240, t0=1305031102.175)
    out = tmp_path / "estimates.csv"
    table = estimate_session(_ConstantPredictor(), session, load_window_config(), out)
    text = out.read_text().splitlines()
    assert text[0] == "frame_index,timestamp,error_m"
    first = text[1].split(",")
    assert first[0].isdigit() and "e" not in first[1]  # an integer frame index, a timestamp in full
    log = read_estimate_log(out)
    np.testing.assert_array_equal(log.timestamps, table.timestamp.to_numpy())
    np.testing.assert_array_equal(log.frame_indices, table.frame_index.to_numpy())
    assert np.unique(log.timestamps).size == len(table) > 100
    assert np.allclose(np.diff(log.timestamps), 1 / FPS, atol=2e-6)
    cfg = load_advisory_config()
    rendering = render_estimates(log, cfg)
    duration = log.timestamps[-1] - log.timestamps[0]
    assert rendering.samples.size / cfg.audio.sample_rate >= duration
    pulsing = [d.time for d in rendering.decisions if d.n_pulses > 0]
    # A 2 cm estimate sounds on every buffer, from the first estimate to the last.
    assert pulsing[0] <= cfg.timing.cadence_s and pulsing[-1] >= duration - cfg.timing.cadence_s
    assert len(pulsing) >= duration / cfg.timing.cadence_s - 1
