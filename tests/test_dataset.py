"""The dataset builder end to end on a tiny dataset (3 environments × patrol × 1 trial, 60 frames of 320×240)
with real rendering, real ORB-SLAM3 + RTS monitor, evo labels; then the store, resume, a failed run,
the splits and the label report. Built once per module (about 40 s on 2 cores)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from testkit.sample import run_seesys

from estimator import dataset_commands
from estimator.dataset import build as build_module
from estimator.dataset.build import SESSIONS_DIR, DatasetBuilder, plan_from_config
from estimator.dataset.config import SplitConfig, load_dataset_config, lockbox_hash
from estimator.dataset.report import CORRELATION_PNG, HISTOGRAM_PNG, REPORT_MD, feature_correlations, write_report
from estimator.dataset.splits import SplitError, Splits, check_no_leak, make_splits, run_table
from estimator.dataset.store import (
    COMPLETED,
    CRASHED,
    DATASET_JSON,
    FORMAT_VERSION,
    PARTIAL,
    PSD_FRAMES_NPY,
    PSD_NPY,
    RTS_FRAMES_NPY,
    RTS_NPY,
    RUNS_DIR,
    SAMPLE_PSD_ROWS_NPY,
    SAMPLE_RTS_ROWS_NPY,
    DatasetError,
    DatasetReader,
    check_label_definition,
    check_rts_schema,
    gather_rts,
    label_definition,
    list_runs,
    read_run_info,
    run_folder,
)
from seesys.core import rts_schema
from seesys.core.errors import ConfigError, SeesysError
from seesys.core.labels import LabelStatus
from seesys.core.windows import assemble_windows
from seesys.io.config import CONFIG_DIR_ENV, config_dir, replace_fields
from seesys.io.core_settings import load_label_config, load_window_config
from seesys.io.rts_log import read_feature_frames
from seesys.io.session_labels import label_session
from slam_monitor.device_worker import ObserverSpec
from synth.config import load_synth_config
from synth.sequence import SequenceSpec

ENVIRONMENTS = ["lab", "office", "living_room"]
FRAMES = 60
TEMPLATE = SequenceSpec("", "", 0, FRAMES, 320, 240)
REPO = Path(__file__).resolve().parent.parent


def _builder(root: Path, config_dir: Path | None = None) -> DatasetBuilder:
    return DatasetBuilder(
        root, load_dataset_config(), load_synth_config(), load_label_config(), load_window_config(), config_dir
    )


def _plan(environments: list[str], modes: list[str] | None = None):
    return plan_from_config(
        load_dataset_config(), load_synth_config(), TEMPLATE, environments, ["patrol"], [0], modes or ["rgbd"], 1
    )


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[Path, object]:
    root = tmp_path_factory.mktemp("dataset")
    return root, _builder(root).build(_plan(ENVIRONMENTS))


@pytest.mark.system
def test_build_stores_every_run_with_windows_and_labels(tiny):
    root, result = tiny
    assert result.sequences == 3 and result.rendered_frames == 3 * FRAMES
    assert [r.status for r in result.runs_done] == [COMPLETED] * 3, [r.error for r in result.runs_done]
    log = [json.loads(line) for line in (root / "build_log.jsonl").read_text().splitlines()]
    assert [e["phase"] for e in log] == ["render", "runs"] and log[0]["rendered_frames"] == 3 * FRAMES
    windows = load_window_config()
    description = json.loads((root / DATASET_JSON).read_text())
    assert description["format_version"] == FORMAT_VERSION and description["windows"]["end_stride"] == 1
    for info in list_runs(root):
        folder = run_folder(root, info.run)
        session = root / SESSIONS_DIR / info.run
        rts = np.load(folder / RTS_NPY, mmap_mode="r")
        psd = np.load(folder / PSD_NPY, mmap_mode="r")
        rts_rows, psd_rows = np.load(folder / SAMPLE_RTS_ROWS_NPY), np.load(folder / SAMPLE_PSD_ROWS_NPY)
        samples = pd.read_csv(folder / "samples.csv")
        frames = pd.read_csv(folder / "frames.csv")
        assert json.loads((folder / "run.json").read_text())["format_version"] == FORMAT_VERSION
        assert info.environment in ENVIRONMENTS and info.motion_group == "patrol" and info.mode == "rgbd"
        # Through the camera the default draw gives its sequence (configs/dataset.toml [cameras]).
        assert (
            info.camera_model
            == load_dataset_config().cameras.cameras(0, info.environment, load_synth_config())["patrol"]
        )
        assert len(frames) == info.frames == FRAMES
        assert info.seconds >= info.slam_seconds > 0
        # RGB-D runs are paced by the camera rate only (wait_for_mapping_modes = ["mono"]).
        assert json.loads((session / "session.json").read_text())["mapping_wait_s"] == 0
        # The monitor logged a PSD on every frame, each stored once: one per RTS row.
        assert np.array_equal(np.load(folder / PSD_FRAMES_NPY), np.load(folder / RTS_FRAMES_NPY))
        assert rts.dtype == np.float32 and rts.shape == (info.frames, rts_schema.NUM_CHANNELS)
        assert psd.dtype == np.uint8 and psd.shape[0] == info.frames and psd.shape[-1] == 3
        # A window ends on every tracked frame that has its full history: a sample per labelled frame from
        # frame rts_length on.
        assert len(samples) == info.samples == len(rts_rows) == len(psd_rows)
        late = frames[(frames.frame_index >= windows.rts_length) & (frames.status == LabelStatus.LABELLED.value)]
        assert set(late.frame_index) <= set(samples.frame_index) and len(samples) >= FRAMES - windows.rts_length - 5
        assert rts_rows.shape[1] == windows.rts_length and psd_rows.shape[1] == windows.psd_samples
        # Each sample carries the label of its end frame, as labelled from the session folder.
        labels = label_session(session, False, load_label_config()).to_frame()
        expected = labels.error_m.to_numpy()[samples.frame_index.to_numpy()]
        np.testing.assert_allclose(samples.error_m.to_numpy(), expected, equal_nan=True)
        usable = (samples.status == LabelStatus.LABELLED.value) & (samples.missing_rts == 0)
        assert (samples.usable == usable).all()
        # The RTS rows of a window are the monitor's rows of frames t-29 … t, its PSDs those of t-30 … t.
        rts_csv = pd.read_csv(session / "rts.csv")
        end = int(samples.frame_index.iloc[-1])
        np.testing.assert_allclose(
            rts[rts_rows[-1]],
            rts_csv[list(rts_schema.CHANNEL_NAMES)].to_numpy(np.float32)[end - 29 : end + 1],
            equal_nan=True,
        )
        assert np.load(folder / PSD_FRAMES_NPY)[psd_rows[-1]].tolist() == [end - 30, end - 20, end - 10, end]


@pytest.mark.system
def test_reader_gives_the_windows_the_assembler_gives(tiny):
    """A stored sample is exactly the window that assemble_windows makes from the session's logs (the one window
    definition, online and offline), though each PSD is stored once."""
    root, _ = tiny
    reader = DatasetReader(root)
    run = reader.index.run.iloc[0]
    windows = dataclasses.replace(load_window_config(), end_stride=1)
    assembled = {
        w.frame_index: w for w in assemble_windows(read_feature_frames(root / SESSIONS_DIR / run, run), windows)
    }
    rows = np.flatnonzero(reader.index.run == run)
    assert sorted(assembled) == reader.index.frame_index.iloc[rows].tolist()
    for i in rows[::7]:
        sample, window = reader[int(i)], assembled[int(reader.index.frame_index.iloc[i])]
        np.testing.assert_array_equal(sample.rts, window.rts)
        np.testing.assert_array_equal(sample.psd, window.psd)
        assert sample.rts.dtype == np.float32 and sample.psd.dtype == np.uint8


@pytest.mark.system
def test_reader_gives_lazy_random_access(tiny):
    root, _ = tiny
    reader = DatasetReader(root)
    assert len(reader) == sum(i.samples for i in list_runs(root))
    assert set(reader.index.environment) == set(ENVIRONMENTS)
    sample = reader[len(reader) - 1]
    row = reader.index.iloc[-1]
    folder = run_folder(root, row.run)
    stored = np.load(folder / PSD_NPY)[np.load(folder / SAMPLE_PSD_ROWS_NPY)[int(row["sample"])]]
    assert np.array_equal(sample.psd, stored) and sample.meta["trajectory"] == row.trajectory
    assert sample.psd.shape[0] == load_window_config().psd_samples
    assert isinstance(reader._run_arrays(row.run).psd, np.memmap)  # arrays are memory maps, not loaded
    usable = DatasetReader(root, usable_only=True)
    assert 0 < len(usable) <= len(reader) and usable.index.usable.all()
    one = DatasetReader(root, runs=[row.run])
    assert set(one.index.run) == {row.run}
    windows = reader.rts_windows()
    assert windows.shape == (len(reader), 30, rts_schema.NUM_CHANNELS)
    np.testing.assert_array_equal(windows[len(reader) - 1], sample.rts)
    with pytest.raises(DatasetError, match="not found"):
        DatasetReader(root, runs=["no_such_run"])
    with pytest.raises(IndexError):
        reader[len(reader)]


def test_a_missing_rts_row_reads_as_nan():
    rts = np.arange(12, dtype=np.float32).reshape(3, 4)
    window = gather_rts(rts, np.array([[2, -1, 0]]))
    assert window.shape == (1, 3, 4) and np.isnan(window[0, 1]).all()
    np.testing.assert_array_equal(window[0, [0, 2]], rts[[2, 0]])


@pytest.mark.system
def test_an_old_format_run_or_dataset_is_refused(tiny, tmp_path):
    root, _ = tiny
    copy = tmp_path / "copy"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("sessions"))
    run = list_runs(copy)[0]
    path = run_folder(copy, run.run) / "run.json"
    record = json.loads(path.read_text())
    del record["format_version"]  # format 1 had none
    path.write_text(json.dumps(record))
    with pytest.raises(DatasetError, match="dataset format 1.*Rebuild"):
        DatasetReader(copy)
    description = json.loads((copy / DATASET_JSON).read_text())
    del description["format_version"]
    (copy / DATASET_JSON).write_text(json.dumps(description))
    with pytest.raises(SeesysError, match="dataset format 1, this builder writes format 2"):
        _builder(copy).build(_plan(ENVIRONMENTS))


@pytest.mark.system
def test_resume_redoes_only_unfinished_runs(tiny, tmp_path):
    root, _ = tiny
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    kept, lost = sorted(list_runs(copy), key=lambda i: i.run)[:2]
    # An interrupted build: one run never finished (its folder absent, a partial write left behind).
    shutil.rmtree(run_folder(copy, lost.run))
    (copy / RUNS_DIR / f"{lost.run}.partial").mkdir()
    kept_json = (run_folder(copy, kept.run) / "run.json").read_text()
    result = _builder(copy).build(_plan(ENVIRONMENTS))
    assert [r.run for r in result.runs_done] == [lost.run] and result.runs_skipped == 2
    assert result.rendered_frames == 0  # the sequences were complete and are not rendered again
    assert read_run_info(run_folder(copy, lost.run)).status == COMPLETED
    assert (run_folder(copy, kept.run) / "run.json").read_text() == kept_json
    assert not (copy / RUNS_DIR / f"{lost.run}.partial").exists()


@pytest.mark.system
def test_a_retuned_preset_renders_and_runs_its_sequences_again(tiny, tmp_path):
    """Resuming with a preset retuned since: only its sequences are rendered again, and their stored runs (which
    played the old render) are redone."""
    root, _ = tiny
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    synth = load_synth_config()
    retuned = dataclasses.replace(
        synth, presets=[dataclasses.replace(p, albedo=0.3) if p.name == "lab" else p for p in synth.presets]
    )
    builder = DatasetBuilder(copy, load_dataset_config(), retuned, load_label_config(), load_window_config())
    result = builder.build(_plan(ENVIRONMENTS))
    assert result.rendered_frames == FRAMES and [r.run for r in result.runs_done] == ["lab__patrol__s0__rgbd__t0"]
    assert result.runs_skipped == 2 and len(list_runs(copy)) == 3


@pytest.mark.system
def test_failed_run_is_recorded_and_skipped(tiny, tmp_path):
    root, _ = tiny
    configs = tmp_path / "configs"
    shutil.copytree(REPO / "configs", configs)
    slam = configs / "slam.toml"
    slam.write_text(
        slam.read_text().replace(
            'vocabulary = "data/vocabulary/seesys_sample_k10L4.txt"',
            f'vocabulary = "{tmp_path / "missing_vocabulary.txt"}"',
        )
    )
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    result = _builder(copy, configs).build(_plan(ENVIRONMENTS[:1], modes=["mono"]))
    assert [r.status for r in result.runs_done] == [CRASHED]
    assert "vocabulary" in result.runs_done[0].error
    assert not (run_folder(copy, result.runs_done[0].run) / PSD_NPY).exists()
    again = _builder(copy, configs).build(_plan(ENVIRONMENTS[:1], modes=["mono"]))
    assert again.runs_done == [] and again.runs_skipped == 1
    assert len(DatasetReader(copy)) == len(DatasetReader(root))  # a crashed run adds no samples
    plan = json.loads((copy / DATASET_JSON).read_text())["plan"]
    assert plan["modes"] == ["rgbd", "mono"] and plan["environments"] == ENVIRONMENTS


@pytest.mark.system
def test_a_run_that_crashes_part_way_keeps_the_frames_logged_before(tiny, tmp_path, monkeypatch):
    root, _ = tiny
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    victim = sorted(list_runs(copy), key=lambda i: i.run)[0]
    shutil.rmtree(run_folder(copy, victim.run))
    crash_at = 45
    real_session = build_module.run_supervised_session

    def crashing_session(options, progress=None):
        # A real SIGSEGV inside the real worker, where ORB-SLAM3 segfaults after a map reset.
        crasher = ObserverSpec("test_track_isolation:crasher", {"at_frame": crash_at, "how": "segfault"})
        return real_session(dataclasses.replace(options, observers=options.observers + (crasher,)), progress)

    monkeypatch.setattr(build_module, "run_supervised_session", crashing_session)
    result = _builder(copy).build(_plan(ENVIRONMENTS))
    assert [r.run for r in result.runs_done] == [victim.run] and result.crashed == result.runs_done
    run = result.runs_done[0]
    assert run.status == PARTIAL and "SIGSEGV" in run.error and run.frames == crash_at
    assert read_run_info(run_folder(copy, run.run)) == run
    frames = DatasetReader(copy, runs=[run.run]).frame_labels()
    assert list(frames.frame_index) == list(range(crash_at))
    assert run.frames_tracked == (frames.status != LabelStatus.NOT_TRACKED.value).sum() > 0
    assert (frames.status == LabelStatus.LABELLED.value).any()
    samples = DatasetReader(copy, runs=[run.run])
    whole = DatasetReader(root, runs=[run.run]).index.frame_index  # the same run's windows when it did not crash
    # The monitor logs a frame just after tracking it: the crash may take the last one or two with it.
    monitored = int(np.load(run_folder(copy, run.run) / RTS_FRAMES_NPY).max())
    assert crash_at - 3 <= monitored < crash_at
    # It writes a frame's RTS row before its PSD: a crash between the two leaves that frame without a window.
    expected = [f for f in whole if f <= monitored]
    assert len(samples) == run.samples > 0 and list(samples.index.frame_index) in (expected, expected[:-1])
    assert run.run in set(run_table([copy]).run)
    again = _builder(copy).build(_plan(ENVIRONMENTS))
    assert again.runs_done == [] and again.runs_skipped == 3


def test_dataset_config_rejects_an_unknown_slam_mode(tmp_path):
    configs = tmp_path / "configs"
    shutil.copytree(REPO / "configs", configs)
    path = configs / "dataset.toml"
    path.write_text(
        path.read_text().replace('wait_for_mapping_modes = ["mono"]', 'wait_for_mapping_modes = ["monocular"]')
    )
    with pytest.raises(ConfigError, match="unknown SLAM mode.*monocular"):
        load_dataset_config(configs)


@pytest.mark.system
def test_a_dataset_is_extended_only_with_the_same_sample_definition(tiny, tmp_path):
    root, _ = tiny
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    description = (copy / DATASET_JSON).read_text()
    other_labels = replace_fields(load_label_config(), delta_frames=5)
    builder = DatasetBuilder(copy, load_dataset_config(), load_synth_config(), other_labels, load_window_config())
    with pytest.raises(SeesysError, match="different labels"):
        builder.build(_plan(ENVIRONMENTS))
    assert (copy / DATASET_JSON).read_text() == description
    assert sorted(i.run for i in list_runs(copy)) == sorted(i.run for i in list_runs(root))


def _synthetic_runs() -> pd.DataFrame:
    """Runs of 4 environments: per group 4 generated trajectories (one per environment) plus one real
    trajectory rendered in every environment; environment b's generated trajectories through a Kinect, the rest
    through the ideal camera."""
    rows = []
    for e, env in enumerate(["a", "b", "c", "held"]):
        for group in ("patrol", "aiming", "rapid"):
            rows.append((f"{env}_{group}", env, group, f"{group}_{e}", "kinect" if env == "b" else "ideal"))
            rows.append((f"{env}_real_{group}", env, group, f"real_{group}", "ideal"))
    rows.append(("held_only", "held", "patrol", "patrol_private", "ideal"))
    return pd.DataFrame(rows, columns=["run", "environment", "motion_group", "trajectory", "camera_model"])


def test_splits_never_share_a_trajectory_between_parts():
    runs = _synthetic_runs()
    splits = make_splits(runs, SplitConfig(rounds=4, seed=3, heldout_environments=("held",), heldout_cameras=()))
    trajectory = dict(zip(runs.run, runs.trajectory))
    environment = dict(zip(runs.run, runs.environment))
    for r in splits.rounds:
        parts = [{trajectory[x] for x in getattr(r, p)} for p in ("train", "validation", "test")]
        assert not (parts[0] & parts[1]) and not (parts[0] & parts[2]) and not (parts[1] & parts[2])
        assert len(r.validation_trajectories) == len(r.test_trajectories) == 3  # one per motion group
        assert {environment[x] for x in r.train + r.validation}.isdisjoint({"held"})
        assert "held_only" in r.test  # a trajectory seen only in a held-out environment is test data
        assert sorted(r.train + r.validation + r.test + r.excluded) == sorted(runs.run)
        assert r.train
    # Four rounds over the four trajectories per group outside the held-out environment test each one once.
    group_of = dict(zip(runs.trajectory, runs.motion_group))
    for group in ("patrol", "aiming", "rapid"):
        tested = [t for r in splits.rounds for t in r.test_trajectories if group_of[t] == group]
        assert sorted(tested) == sorted([f"{group}_0", f"{group}_1", f"{group}_2", f"real_{group}"])
    with pytest.raises(SplitError, match="at most 4 distinct rounds"):
        make_splits(runs, SplitConfig(rounds=5, seed=3, heldout_environments=("held",), heldout_cameras=()))
    leaky = splits.rounds[0]
    leaky.train.append(leaky.test[0])
    with pytest.raises(SplitError, match="is in train and test"):
        check_no_leak(splits, runs)


def test_a_held_out_camera_is_test_data_only_and_recorded(tmp_path):
    runs = _synthetic_runs()
    splits = make_splits(runs, SplitConfig(rounds=3, seed=3, heldout_environments=(), heldout_cameras=("kinect",)))
    camera = dict(zip(runs.run, runs.camera_model))
    kinect = set(runs.run[runs.camera_model == "kinect"])
    for r in splits.rounds:
        assert {camera[x] for x in r.train + r.validation} == {"ideal"}
        assert kinect <= set(r.test + r.excluded) and kinect & set(r.test)  # its own trajectories: test data
    out = tmp_path / "splits.json"
    out.write_text(splits.to_json())
    assert Splits.from_json(out.read_text()).heldout_cameras == ["kinect"]
    leaky = splits.rounds[0]
    leaky.train.append(sorted(kinect)[0])
    with pytest.raises(SplitError, match="held-out camera kinect is in train"):
        check_no_leak(splits, runs)
    with pytest.raises(
        SplitError, match=r"held-out camera models not in the data: d435 \(the data has ideal, kinect\)"
    ):
        make_splits(runs, SplitConfig(rounds=3, seed=3, heldout_environments=(), heldout_cameras=("d435",)))


@pytest.mark.system
def test_splits_need_three_trajectories_per_group(tiny):
    root, _ = tiny
    runs = run_table([root])
    assert len(make_splits(runs, SplitConfig(1, 0, (), ())).rounds[0].train) == 1
    with pytest.raises(SplitError, match="needs 3"):
        make_splits(runs, SplitConfig(1, 0, ("lab",), ()))
    with pytest.raises(SplitError, match="not in the data"):
        make_splits(runs, SplitConfig(1, 0, ("nowhere",), ()))


@pytest.mark.system
def test_report_writes_figures_against_targets(tiny, tmp_path):
    root, _ = tiny
    config = replace_fields(load_dataset_config().report, min_samples=5)
    report = write_report([root], config, load_dataset_config().targets, tmp_path / "report")
    text = (tmp_path / "report" / REPORT_MD).read_text()
    assert "median (mm)" in text and "4–8" in text and "lab" in text
    for png in (HISTOGRAM_PNG, CORRELATION_PNG):
        assert (tmp_path / "report" / png).stat().st_size > 5000
    frames = DatasetReader(root).frame_labels()
    errors = frames.error_m[frames.status == LabelStatus.LABELLED.value]
    assert report.main_mode().summary.median_m == pytest.approx(float(np.median(errors)))
    assert len(report.main_mode().correlations) > 0


def test_feature_correlations_find_a_monotone_feature():
    rng = np.random.default_rng(0)
    errors = rng.lognormal(-5, 1, 400)
    features = pd.DataFrame(
        {"follows": np.log(errors) + rng.normal(0, 0.3, 400), "noise": rng.normal(size=400), "constant": np.ones(400)}
    )
    table = feature_correlations(features, errors, 30)
    assert table.feature.iloc[0] == "follows" and table.spearman_rho.iloc[0] > 0.9
    assert "constant" not in set(table.feature)


@pytest.mark.system
def test_cli_splits_and_bad_input(tiny, tmp_path, monkeypatch):
    root, _ = tiny
    # The lockbox's camera is among the tiny build's: a config whose lockbox is outside it leaves every run.
    configs = tmp_path / "configs"
    shutil.copytree(config_dir(), configs)
    lockbox = load_dataset_config().lockbox
    text = (configs / "dataset.toml").read_text()
    outside = (("environment", "nowhere"), ("camera_model", "none"), ("sha256", lockbox_hash("nowhere", "none")))
    for key, value in outside:
        text = text.replace(f'{key} = "{getattr(lockbox, key)}"', f'{key} = "{value}"')
    (configs / "dataset.toml").write_text(text)
    monkeypatch.setenv(CONFIG_DIR_ENV, str(configs))
    parser = argparse.ArgumentParser(prog="seesys")
    dataset_commands.register(parser.add_subparsers())
    out = tmp_path / "splits.json"
    args = parser.parse_args(["dataset", "splits", str(root), "--out", str(out), "--heldout", "", "--rounds", "2"])
    assert args.func(args) == 0
    written = json.loads(out.read_text())
    assert len(written["rounds"]) == 2 and written["lockbox"]["runs"] == []
    assert written["build"]["runs"] == len(run_table([root]))
    done = run_seesys("dataset", "report", str(tmp_path / "nothing"), "--out", str(tmp_path / "r"))
    assert done.returncode == 2 and "seesys: error:" in done.stderr and "not a dataset folder" in done.stderr


@pytest.mark.system
def test_sample_is_rendered_as_a_small_tum_folder(tmp_path):
    from estimator.dataset.config import SampleSequenceConfig
    from estimator.dataset.sample import make_sample
    from slam_monitor.sources import load_camera_config, open_source, parse_source_spec

    config = SampleSequenceConfig("lab", "aiming", 1, 4, 90)
    result = make_sample(config, load_synth_config(), tmp_path / "sample")
    assert result.frames == 4 and not list((tmp_path / "sample" / "rgb").glob("*.png"))
    assert len(list((tmp_path / "sample" / "rgb").glob("*.jpg"))) == 4
    assert "seesys dataset sample" in (tmp_path / "sample" / "README.md").read_text()
    with open_source(parse_source_spec(f"tum:{tmp_path / 'sample'}"), load_camera_config(), True) as source:
        frames = list(source.frames())
    assert len(frames) == 4 and frames[0].depth is not None and frames[0].gray.shape == (480, 640)


@pytest.mark.parametrize(
    "modes, recorded, refused",
    [
        ({"mono"}, "old", "mono_alignment 'sim3-sliding-window' (here 'sim3-per-stretch')"),
        ({"mono"}, "here", None),
        ({"rgbd"}, "old", None),  # the RGB-D label did not change with the monocular alignment
        ({"rgbd"}, "other delta", "delta_frames 20 (here 10)"),
    ],
)
def test_a_dataset_labelled_under_another_definition_is_refused_for_its_modes(tmp_path, modes, recorded, refused):
    """A folder built before the monocular label became per stretch records the sliding window's settings and no
    alignment: its monocular runs must not train a model that records today's definition."""
    here = label_definition(load_label_config())
    old = {k: v for k, v in here.items() if k != "mono_alignment"} | {
        "mono_scale_window_frames": 90,
        "min_alignment_frames": 30,
    }
    labels = {
        "old": old,
        "here": here,
        "other delta": label_definition(dataclasses.replace(load_label_config(), delta_frames=20)),
    }[recorded]
    (tmp_path / DATASET_JSON).write_text(json.dumps({"labels": labels}))
    if refused is None:
        check_label_definition(tmp_path, modes)
    else:
        with pytest.raises(DatasetError, match=f"{tmp_path / DATASET_JSON}: .*{re.escape(refused)}"):
            check_label_definition(tmp_path, modes)


def test_a_dataset_built_with_another_rts_schema_is_refused_by_name(tmp_path):
    path = tmp_path / DATASET_JSON
    path.write_text(
        json.dumps({"rts_schema_version": rts_schema.SCHEMA_VERSION, "rts_channels": rts_schema.CHANNEL_NAMES})
    )
    check_rts_schema(tmp_path)
    path.write_text(json.dumps({"rts_schema_version": 3, "rts_channels": rts_schema.CHANNEL_NAMES[:19]}))
    with pytest.raises(DatasetError, match=rf"{re.escape(str(path))}: built with RTS schema v3 \(19 channels\)"):
        check_rts_schema(tmp_path)


@pytest.mark.system
def test_the_covariance_is_judged_against_the_label_on_each_test_set_with_a_scale_fitted_on_training(tiny, tmp_path):
    from estimator.dataset.covariance import (
        PAIR_SIGMA,
        build_frames,
        coverage_by_set,
        fitted_scale,
        model_scaled_coverage,
        read_predictions,
        session_frames,
    )
    from estimator.dataset.splits import HELDOUT_ENVIRONMENTS, TEST_TRAJECTORIES, SplitRound, Splits
    from seesys.core import session_layout
    from seesys.core.pose_covariance import relative_translation_covariance

    root, _ = tiny
    delta = load_label_config().delta_frames
    frames = build_frames([root], delta)
    runs = sorted(set(frames.run))
    assert len(runs) == len(ENVIRONMENTS) and (frames[PAIR_SIGMA].dropna() > 0).all()
    # One frame's σ by hand, from the session's logged covariances and trajectory.
    row = frames.dropna(subset=[PAIR_SIGMA]).iloc[5]
    session = root / "sessions" / row.run
    logged = pd.read_csv(session / session_layout.POSE_COVARIANCE_CSV).set_index("frame_index")
    matrices = session_layout.covariance_matrices(logged[list(session_layout.POSE_COVARIANCE_COLUMNS[2:])])
    of = dict(zip(logged.index, matrices))
    trajectory = pd.read_csv(session / session_layout.TRAJECTORY, sep=" ", header=None, comment="#")
    where = {round(t, 6): p for t, p in zip(trajectory[0], trajectory[[1, 2, 3]].to_numpy())}
    j, i = int(row.frame_index), int(row.frame_index) - delta
    c = relative_translation_covariance(
        of[i], of[j], where[round(logged.timestamp[i], 6)], where[round(logged.timestamp[j], 6)]
    )
    assert row[PAIR_SIGMA] == pytest.approx(np.sqrt(np.trace(c)))
    # The run's session folder on its own (labelled as a device session) gives the frames the build gives its run.
    alone = session_frames(session, delta, False, load_label_config())
    built = frames[frames.run == row.run][list(alone.columns)].reset_index(drop=True)
    assert len(alone) > 20
    pd.testing.assert_frame_equal(alone, built)
    # The scale is fitted on the training run alone and applied to the test sets.
    environment = {r: frames[frames.run == r].environment.iloc[0] for r in runs}
    split = SplitRound([], [], [runs[0]], [], runs[1:], [], heldout_environments=[environment[runs[2]]])
    table = coverage_by_set(frames, Splits([environment[runs[2]]], [split]), [0])
    scale = fitted_scale(frames[frames.run == runs[0]])
    assert scale > 0 and (table.scale == scale).all()
    pooled = table[table.camera_model == "all"].set_index("set")
    assert set(pooled.index) == {TEST_TRAJECTORIES, HELDOUT_ENVIRONMENTS}
    heldout = frames[frames.run == runs[2]].dropna(subset=[PAIR_SIGMA, "label_m"])
    ratio = heldout.label_m / heldout[PAIR_SIGMA]
    assert pooled.loc[HELDOUT_ENVIRONMENTS, "within_2sigma_scaled"] == pytest.approx(np.mean(ratio <= 2 * scale))
    assert pooled.loc[HELDOUT_ENVIRONMENTS, "within_1sigma"] == pytest.approx(np.mean(ratio <= 1))
    # Scaled to a row's estimates: a label lies within 1σ where it is at most the estimate, within 2σ at most twice.
    judged = heldout.reset_index(drop=True)
    low = np.arange(len(judged)) % 4 == 0  # a quarter estimated at 0.6 of the label: outside 1σ, inside 2σ
    estimate = np.where(low, judged.label_m * 0.6, judged.label_m * 1.5)
    predictions = pd.DataFrame(
        {"set": HELDOUT_ENVIRONMENTS, "row": "a model", "round": 0, "run": judged.run}
        | {"frame_index": judged.frame_index, "true_m": judged.label_m, "estimate_m": estimate}
    )
    path = tmp_path / "predictions.csv"
    predictions.to_csv(path, index=False)
    model = model_scaled_coverage(frames, read_predictions(path)).set_index("camera_model").loc["all"]
    assert model.windows == len(judged) and model.within_1sigma == pytest.approx(np.mean(~low))
    assert model.within_2sigma == 1.0
    predictions.drop(columns="estimate_m").to_csv(path, index=False)
    with pytest.raises(SeesysError, match=r"predictions.csv has no column\(s\) estimate_m"):
        read_predictions(path)
    # A build without its sessions cannot be judged, and says why.
    copy = tmp_path / "copy"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("sequences"))
    shutil.rmtree(copy / "sessions" / row.run)
    with pytest.raises(DatasetError, match="pose_covariance.csv is missing"):
        build_frames([copy], delta)
    (session_copy := copy / "sessions" / runs[1]).joinpath(session_layout.POSE_COVARIANCE_CSV).unlink()
    with pytest.raises(DatasetError, match="pose_covariance.csv is missing: its monitor logged no pose covariance"):
        session_frames(session_copy, delta, False, load_label_config())
