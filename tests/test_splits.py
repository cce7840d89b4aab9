"""Splits that move the test: held-out rooms that rotate over the rounds, a rotating held-out camera, the lockbox in
no round, and a splits file that records its build and is checked whenever it is read."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

from estimator.dataset.config import LockboxConfig, SplitConfig, load_dataset_config, lockbox_hash
from estimator.dataset.splits import (
    SplitError,
    build_fingerprint,
    check_no_leak,
    make_final_split,
    make_splits,
    read_splits,
    run_table,
)
from estimator.dataset.store import COMPLETED, RunInfo, record_crashed_run
from seesys.core.errors import ConfigError
from seesys.io.config import config_dir

ROOMS = ["r0", "r1", "r2", "r3", "r4", "r5"]


def _runs() -> pd.DataFrame:
    """Per room one trajectory per motion group (two trials each), rooms r0–r2 through camera a, r3–r5 through b,
    and a real trajectory per group rendered in every room through camera a."""
    rows = []
    for e, room in enumerate(ROOMS):
        for group in ("patrol", "aiming", "rapid"):
            for trial in (0, 1):
                rows.append((f"{room}__{group}__t{trial}", room, group, f"{group}_{e}", "a" if e < 3 else "b"))
                rows.append((f"{room}__real_{group}__t{trial}", room, group, f"real_{group}", "a"))
    return pd.DataFrame(rows, columns=["run", "environment", "motion_group", "trajectory", "camera_model"])


def _config(**changes) -> SplitConfig:
    return dataclasses.replace(
        SplitConfig(rounds=3, seed=1, heldout_environments=(), heldout_cameras=(), heldout_environments_per_round=2),
        **changes,
    )


def test_held_out_rooms_rotate_and_no_room_is_held_out_twice():
    runs = _runs()
    splits = make_splits(runs, _config())
    room = dict(zip(runs.run, runs.environment))
    held = [splits.heldout(r)[0] for r in range(3)]
    assert all(len(h) == 2 for h in held) and sorted(sum(held, [])) == ROOMS  # each room once
    for r, split_round in enumerate(splits.rounds):
        assert {room[x] for x in split_round.train + split_round.validation}.isdisjoint(held[r])
        assert set(held[r]) <= {room[x] for x in split_round.test}  # its rooms are test data
    assert sorted(splits.heldout_environments) == ROOMS
    with pytest.raises(SplitError, match="4 rounds of 2 held-out rooms need 8 rooms, the build has 6"):
        make_splits(runs, _config(rounds=4))
    # A fixed list is the same in every round, as before rotation.
    fixed = make_splits(runs, _config(heldout_environments=("r0",)))
    assert [fixed.heldout(r)[0] for r in range(3)] == [["r0"]] * 3


def test_the_held_out_camera_rotates_where_the_draw_allows():
    splits = make_splits(_runs(), _config(heldout_environments_per_round=0, heldout_cameras=("a", "b")))
    assert [splits.heldout(r)[1] for r in range(3)] == [["a"], ["b"], ["a"]]


def test_the_lockbox_is_in_no_round():
    runs = _runs()
    lockbox = LockboxConfig("r5", "b", lockbox_hash("r5", "b"))
    splits = make_splits(runs, _config(rounds=2, heldout_environments_per_round=1), lockbox)
    boxed = set(runs.run[(runs.environment == "r5") | (runs.camera_model == "b")])
    assert set(splits.lockbox.runs) == boxed
    for split_round in splits.rounds:
        parts = split_round.train + split_round.validation + split_round.test + split_round.excluded
        assert boxed.isdisjoint(parts) and split_round.train
    split_round = splits.rounds[0]
    split_round.train.append(sorted(boxed)[0])
    with pytest.raises(SplitError, match=f"round 0: lockbox run {sorted(boxed)[0]} is in train"):
        check_no_leak(splits, runs)


def test_the_final_split_trains_on_every_run_outside_the_lockbox_but_one_validation_trajectory_a_group():
    runs = _runs()
    lockbox = LockboxConfig("r5", "b", lockbox_hash("r5", "b"))
    splits = make_final_split(runs, _config(), lockbox)
    [final] = splits.rounds
    boxed = set(splits.lockbox.runs)
    assert final.test == [] and final.excluded == [] and boxed.isdisjoint(final.train + final.validation)
    assert sorted(final.train + final.validation) == sorted(set(runs.run) - boxed)
    trajectory = dict(zip(runs.run, runs.trajectory))
    group = dict(zip(runs.trajectory, runs.motion_group))
    assert sorted(group[t] for t in final.validation_trajectories) == ["aiming", "patrol", "rapid"]
    assert {trajectory[r] for r in final.validation} == set(final.validation_trajectories)
    assert not {trajectory[r] for r in final.train} & set(final.validation_trajectories)
    assert make_final_split(runs, _config(), lockbox) == splits  # seeded
    with pytest.raises(SplitError, match="motion group rapid has 1 trajectory; the final split needs 2"):
        make_final_split(runs[(runs.motion_group != "rapid") | (runs.trajectory == "rapid_0")], _config())


def test_the_lockbox_is_recorded_with_its_hash_and_refused_when_changed(tmp_path):
    lockbox = load_dataset_config().lockbox
    assert lockbox.sha256 == lockbox_hash(lockbox.environment, lockbox.camera_model)
    with pytest.raises(ValueError, match="does not match its recorded sha256"):
        LockboxConfig("office", lockbox.camera_model, lockbox.sha256)
    configs = tmp_path / "configs"
    configs.mkdir()
    for path in config_dir().glob("*.toml"):
        (configs / path.name).write_text(path.read_text())
    text = (configs / "dataset.toml").read_text()
    (configs / "dataset.toml").write_text(
        text.replace(f'environment = "{lockbox.environment}"', 'environment = "office"')
    )
    with pytest.raises(ConfigError, match="does not match its recorded sha256"):
        load_dataset_config(configs)


def _write_build(root: Path, runs: pd.DataFrame) -> None:
    """Dataset folders whose run records say what ``runs`` says (the splits read only the records)."""
    for row in runs.itertuples():
        record_crashed_run(
            root,
            RunInfo(
                row.run,
                row.run.rsplit("__", 1)[0],
                row.environment,
                row.motion_group,
                row.trajectory,
                "rgbd",
                int(row.run[-1]),
                COMPLETED,
                camera_model=row.camera_model,
            ),
        )


def test_a_splits_file_records_its_build_and_is_refused_on_another(tmp_path):
    runs = _runs()
    root, other = tmp_path / "build", tmp_path / "other"
    _write_build(root, runs)
    _write_build(other, runs[runs.run != runs.run.iloc[0]])
    assert build_fingerprint(run_table([root])) == build_fingerprint(runs)
    path = tmp_path / "splits.json"
    path.write_text(make_splits(run_table([root]), _config()).to_json())
    assert json.loads(path.read_text())["build"]["name"] == build_fingerprint(runs).name
    assert read_splits(path, [root]).build.runs == len(runs)
    made = build_fingerprint(runs).name
    with pytest.raises(
        SplitError,
        match=rf"^{path} was made from {made} \({len(runs)} runs\), the dataset folders "
        rf"are build-\w{{12}} \({len(runs) - 1} runs\)",
    ):
        read_splits(path, [other])
    # A splits file written before builds were recorded is still checked for leaks on every read.
    legacy = json.loads(path.read_text())
    legacy.pop("build")
    legacy["rounds"][0]["train"].append(legacy["rounds"][0]["test"][0])
    path.write_text(json.dumps(legacy))
    with pytest.raises(SplitError, match="^round 0: .* is in train"):
        read_splits(path, [root])
