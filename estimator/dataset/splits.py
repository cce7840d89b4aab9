"""Train / validation / test splits that never put one trajectory in two parts.

The paper's Table 2 protocol: trajectories belong to motion groups (patrol/inspection, aiming/inspection, rapid
waving/shaking/rotation); each cross-validation round takes, per group, one trajectory for validation and one
for test, the rest for training; n rounds test each of a group's n trajectories once. Here it is applied to
every run of one or more dataset folders at once (the synthetic pretraining data and any later data together),
grouped by trajectory *name*: a real trajectory rendered in nine environments is one group, so all its renders
land in the same part.

On top, environments listed in ``heldout_environments`` and camera models listed in ``heldout_cameras`` never
serve for training or validation: their runs are test data (unseen scenes, unseen cameras). A held-out run whose trajectory also occurs in runs that are not held out
goes to test only when that trajectory is a test trajectory of the round; otherwise it is left out (listed
under ``excluded``), since putting it in test would share its trajectory with training.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.config import SplitConfig
from estimator.dataset.store import WITH_SAMPLES, list_runs
from seesys.core.errors import SeesysError

PARTS = ("train", "validation", "test")


class SplitError(SeesysError):
    """The runs cannot be split as asked (too few trajectories in a motion group, unknown environment)."""


@dataclass(frozen=True)
class SplitRound:
    validation_trajectories: list[str]
    test_trajectories: list[str]
    train: list[str]
    validation: list[str]
    test: list[str]
    excluded: list[str]


@dataclass(frozen=True)
class Splits:
    heldout_environments: list[str]
    rounds: list[SplitRound]
    heldout_cameras: list[str] = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2) + "\n"

    @classmethod
    def from_json(cls, text: str) -> Splits:
        data = json.loads(text)
        # Splits written before held-out cameras hold none.
        return cls(data["heldout_environments"], [SplitRound(**r) for r in data["rounds"]],
                   data.get("heldout_cameras", []))


def run_table(roots: list[Path]) -> pd.DataFrame:
    """One row per run with samples of the dataset folders: run, environment, motion group, trajectory, camera
    model."""
    rows = [(i.run, i.environment, i.motion_group, i.trajectory, i.camera_model) for root in roots
            for i in list_runs(root) if i.status in WITH_SAMPLES]
    table = pd.DataFrame(rows, columns=["run", "environment", "motion_group", "trajectory", "camera_model"])
    duplicated = table.run[table.run.duplicated()]
    if len(duplicated):
        raise SplitError(f"run {duplicated.iloc[0]} occurs in two dataset folders")
    groups = table.groupby("trajectory").motion_group.nunique()
    if (groups > 1).any():
        raise SplitError(f"trajectory {groups[groups > 1].index[0]} is listed under two motion groups")
    return table


def make_splits(runs: pd.DataFrame, config: SplitConfig) -> Splits:
    """Grouped cross-validation rounds over ``runs`` (:func:`run_table`), plus held-out environments and
    cameras."""
    unknown = sorted(set(config.heldout_environments) - set(runs.environment))
    if unknown:
        raise SplitError(f"held-out environments not in the data: {', '.join(unknown)}")
    unknown = sorted(set(config.heldout_cameras) - set(runs.camera_model))
    if unknown:
        raise SplitError(f"held-out camera models not in the data: {', '.join(unknown)} (the data has "
                         f"{', '.join(sorted(set(runs.camera_model)))})")
    heldout = runs.environment.isin(config.heldout_environments) | runs.camera_model.isin(config.heldout_cameras)
    # A trajectory seen only in held-out environments is always test data; the others rotate through the rounds.
    shared = set(runs.trajectory[~heldout])
    rng = np.random.default_rng(config.seed)
    candidates: dict[str, list[str]] = {}
    for group, names in runs[runs.trajectory.isin(shared)].groupby("motion_group").trajectory:
        names = sorted(set(names))
        if len(names) < 3:
            raise SplitError(f"motion group {group} has {len(names)} trajectories outside the held-out "
                             f"environments; a round needs 3 (one each for train, validation and test)")
        candidates[group] = [names[i] for i in rng.permutation(len(names))]
    # Round r validates on the r-th trajectory of each group's permutation and tests on the next, so that n
    # rounds test every trajectory once; more rounds than the smallest group has trajectories would repeat one.
    distinct = min(len(names) for names in candidates.values())
    if config.rounds > distinct:
        raise SplitError(f"{config.rounds} rounds asked, but a motion group has only {distinct} trajectories "
                         f"outside the held-out environments (at most {distinct} distinct rounds)")
    rounds = []
    for r in range(config.rounds):
        validation_traj = sorted(names[r % len(names)] for names in candidates.values())
        test_traj = sorted(names[(r + 1) % len(names)] for names in candidates.values())
        is_test = runs.trajectory.isin(test_traj) | (heldout & ~runs.trajectory.isin(shared))
        is_validation = runs.trajectory.isin(validation_traj) & ~heldout
        is_train = ~runs.trajectory.isin(validation_traj + test_traj) & ~heldout
        excluded = ~(is_test | is_validation | is_train)
        rounds.append(SplitRound(validation_traj, test_traj, sorted(runs.run[is_train]),
                                 sorted(runs.run[is_validation]), sorted(runs.run[is_test]),
                                 sorted(runs.run[excluded])))
    splits = Splits(sorted(config.heldout_environments), rounds, sorted(config.heldout_cameras))
    check_no_leak(splits, runs)
    return splits


def check_no_leak(splits: Splits, runs: pd.DataFrame) -> None:
    """Raise :class:`SplitError` if a run or a trajectory is in two parts of a round, or a held-out
    environment or camera is in training or validation."""
    trajectory_of = dict(zip(runs.run, runs.trajectory))
    environment_of = dict(zip(runs.run, runs.environment))
    camera_of = dict(zip(runs.run, runs.camera_model))
    for k, split_round in enumerate(splits.rounds):
        seen: dict[str, str] = {}
        for part in PARTS:
            for run in getattr(split_round, part):
                trajectory = trajectory_of[run]
                if seen.setdefault(trajectory, part) != part:
                    raise SplitError(f"round {k}: trajectory {trajectory} is in {seen[trajectory]} and {part}")
                if part != "test" and environment_of[run] in splits.heldout_environments:
                    raise SplitError(f"round {k}: held-out environment {environment_of[run]} is in {part}")
                if part != "test" and camera_of[run] in splits.heldout_cameras:
                    raise SplitError(f"round {k}: held-out camera {camera_of[run]} is in {part}")


def write_splits(roots: list[Path], config: SplitConfig, out: Path) -> Splits:
    splits = make_splits(run_table(roots), config)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(splits.to_json())
    return splits
