"""Train / validation / test splits that never put one trajectory in two parts.

The paper's Table 2 protocol: trajectories belong to motion groups (patrol/inspection, aiming/inspection, rapid
waving/shaking/rotation); each cross-validation round takes, per group, one trajectory for validation and one
for test, the rest for training; n rounds test each of a group's n trajectories once. Here it is applied to
every run of one or more dataset folders at once (the synthetic pretraining data and any later data together),
grouped by trajectory *name*: a real trajectory rendered in nine environments is one group, so all its renders
land in the same part.

On top, each round holds out rooms and camera models: they never serve for training or validation in that round,
their runs are test data (unseen scenes, unseen cameras). The held-out rooms change from round to round (a seeded
permutation of the build's rooms, ``heldout_environments_per_round`` at a time, no room twice), unless a fixed list
``heldout_environments`` is given; with several ``heldout_cameras``, round r holds out the (r mod n)-th. A held-out
run whose trajectory also occurs in runs that are not held out goes to test only when that trajectory is a test
trajectory of the round; otherwise it is left out (listed under ``excluded``), since putting it in test would share
its trajectory with training.

The lockbox's runs (a room and a camera model of ``[lockbox]`` in configs/dataset.toml) are in no round at all.

A splits file records the build it was made from: :func:`build_fingerprint` of its run names and camera models.
:func:`check_splits` refuses a splits file on another build (naming both) and runs :func:`check_no_leak`; every
reader of a splits file goes through it.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Set as AbstractSet
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.dataset.config import LockboxConfig, SplitConfig
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
    # The round's held-out rooms and cameras; None in splits written before they rotated (then the Splits' own).
    heldout_environments: list[str] | None = None
    heldout_cameras: list[str] | None = None


@dataclass(frozen=True)
class Build:
    """Which build a splits file was made from: :func:`build_fingerprint`."""

    name: str
    runs: int
    camera_models: list[str]


@dataclass(frozen=True)
class Lockbox:
    environment: str
    camera_model: str
    sha256: str
    runs: list[str]  # the build's runs in the room or through the camera: in no round


@dataclass(frozen=True)
class Splits:
    heldout_environments: list[str]  # every round's held-out rooms (the union, when they rotate)
    rounds: list[SplitRound]
    heldout_cameras: list[str] = field(default_factory=list)
    build: Build | None = None  # None: written before splits recorded their build
    lockbox: Lockbox | None = None

    def heldout(self, round_index: int) -> tuple[list[str], list[str]]:
        """The held-out rooms and camera models of a round."""
        split_round = self.rounds[round_index]
        environments = split_round.heldout_environments
        cameras = split_round.heldout_cameras
        return (
            self.heldout_environments if environments is None else environments,
            self.heldout_cameras if cameras is None else cameras,
        )

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2) + "\n"

    @classmethod
    def from_json(cls, text: str) -> Splits:
        data = json.loads(text)
        # Splits written before held-out cameras hold none; before builds and lockboxes, neither.
        return cls(
            data["heldout_environments"],
            [SplitRound(**r) for r in data["rounds"]],
            data.get("heldout_cameras", []),
            Build(**data["build"]) if data.get("build") else None,
            Lockbox(**data["lockbox"]) if data.get("lockbox") else None,
        )


def build_fingerprint(runs: pd.DataFrame) -> Build:
    """The build of ``runs`` (:func:`run_table`): ``build-`` and 12 hex digits of the SHA-256 of its sorted run
    names with their camera models; any run added, removed or drawn through another camera changes it."""
    lines = sorted(f"{run}\t{camera}" for run, camera in zip(runs.run, runs.camera_model))
    digest = hashlib.sha256("\n".join(lines).encode()).hexdigest()
    return Build(f"build-{digest[:12]}", len(lines), sorted(set(runs.camera_model)))


def run_table(roots: list[Path]) -> pd.DataFrame:
    """One row per run with samples of the dataset folders: run, environment, motion group, trajectory, camera
    model."""
    rows = [
        (i.run, i.environment, i.motion_group, i.trajectory, i.camera_model)
        for root in roots
        for i in list_runs(root)
        if i.status in WITH_SAMPLES
    ]
    table = pd.DataFrame(rows, columns=["run", "environment", "motion_group", "trajectory", "camera_model"])
    duplicated = table.run[table.run.duplicated()]
    if len(duplicated):
        raise SplitError(f"run {duplicated.iloc[0]} occurs in two dataset folders")
    groups = table.groupby("trajectory").motion_group.nunique()
    if (groups > 1).any():
        raise SplitError(f"trajectory {groups[groups > 1].index[0]} is listed under two motion groups")
    return table


def lockbox_runs(runs: pd.DataFrame, lockbox: LockboxConfig | None) -> Lockbox | None:
    """The runs of ``lockbox``'s room or camera model among ``runs``."""
    if lockbox is None:
        return None
    inside = (runs.environment == lockbox.environment) | (runs.camera_model == lockbox.camera_model)
    return Lockbox(lockbox.environment, lockbox.camera_model, lockbox.sha256, sorted(runs.run[inside]))


def _heldout_rooms(runs: pd.DataFrame, config: SplitConfig) -> list[list[str]]:
    """Each round's held-out rooms: the fixed list, or a seeded permutation's consecutive groups."""
    if config.heldout_environments or config.heldout_environments_per_round == 0:
        return [sorted(config.heldout_environments)] * config.rounds
    rooms = sorted(set(runs.environment))
    needed = config.rounds * config.heldout_environments_per_round
    if needed > len(rooms):
        raise SplitError(
            f"{config.rounds} rounds of {config.heldout_environments_per_round} held-out rooms need "
            f"{needed} rooms, the build has {len(rooms)} outside the lockbox (a room is never held out "
            f"twice): ask for fewer rounds or fewer rooms per round"
        )
    order = [rooms[i] for i in np.random.default_rng(config.seed).permutation(len(rooms))]
    k = config.heldout_environments_per_round
    return [sorted(order[r * k : (r + 1) * k]) for r in range(config.rounds)]


def _heldout_cameras(config: SplitConfig, round_index: int) -> list[str]:
    cameras = sorted(config.heldout_cameras)
    return [cameras[round_index % len(cameras)]] if cameras else []


def _next_eligible(
    names: list[str],
    start: int,
    eligible: AbstractSet[str],
    avoid: AbstractSet[str],
    prefer_not: AbstractSet[str] = frozenset(),
) -> str:
    """The first of ``names`` from position ``start`` on (cyclically) that is eligible, not avoided and, where one
    is left, not in ``prefer_not``."""
    ordered = [names[(start + k) % len(names)] for k in range(len(names))]
    allowed = [name for name in ordered if name in eligible and name not in avoid]
    if not allowed:
        raise SplitError(f"no trajectory left of {', '.join(names)} for a round")
    return next((name for name in allowed if name not in prefer_not), allowed[0])


def make_splits(runs: pd.DataFrame, config: SplitConfig, lockbox: LockboxConfig | None = None) -> Splits:
    """Grouped cross-validation rounds over ``runs`` (:func:`run_table`), with each round's held-out rooms and
    cameras, the ``lockbox``'s runs left out of every round, and the build recorded."""
    build = build_fingerprint(runs)
    box = lockbox_runs(runs, lockbox)
    if box is not None:
        runs = runs[~runs.run.isin(box.runs)].reset_index(drop=True)
    unknown = sorted(set(config.heldout_environments) - set(runs.environment))
    if unknown:
        raise SplitError(f"held-out environments not in the data: {', '.join(unknown)}")
    unknown = sorted(set(config.heldout_cameras) - set(runs.camera_model))
    if unknown:
        raise SplitError(
            f"held-out camera models not in the data: {', '.join(unknown)} (the data has "
            f"{', '.join(sorted(set(runs.camera_model)))})"
        )
    rooms = _heldout_rooms(runs, config)
    heldout = [
        runs.environment.isin(rooms[r]) | runs.camera_model.isin(_heldout_cameras(config, r))
        for r in range(config.rounds)
    ]
    # A trajectory seen only in held-out runs of a round is always test data in it; the others rotate through
    # the rounds in the order of a seeded permutation of every trajectory that is ever outside the held-out runs.
    shared = [set(runs.trajectory[~h]) for h in heldout]
    ever = set().union(*shared) if shared else set()
    rng = np.random.default_rng(config.seed)
    candidates: dict[str, list[str]] = {}
    for group, names in runs[runs.trajectory.isin(ever)].groupby("motion_group").trajectory:
        names = sorted(set(names))
        candidates[group] = [names[i] for i in rng.permutation(len(names))]
    for r, eligible in enumerate(shared):
        for group, names in candidates.items():
            count = len(eligible & set(names))
            if count < 3:
                raise SplitError(
                    f"motion group {group} has {count} trajectories outside the held-out runs of round "
                    f"{r}; a round needs 3 (one each for train, validation and test)"
                )
    # Round r validates on the r-th trajectory of each group's permutation and tests on the next, so that n
    # rounds test every trajectory once; more rounds than the smallest group has trajectories would repeat one.
    distinct = min((len(names) for names in candidates.values()), default=0)
    if config.rounds > distinct:
        raise SplitError(
            f"{config.rounds} rounds asked, but a motion group has only {distinct} trajectories "
            f"outside the held-out runs (at most {distinct} distinct rounds)"
        )
    rounds = []
    tested: dict[str, set[str]] = {group: set() for group in candidates}
    for r in range(config.rounds):
        validation_traj, test_traj = [], []
        for group, names in candidates.items():
            test = _next_eligible(names, r + 1, shared[r], set(), prefer_not=tested[group])
            tested[group].add(test)
            test_traj.append(test)
            validation_traj.append(_next_eligible(names, r, shared[r], {test}))
        validation_traj, test_traj = sorted(validation_traj), sorted(test_traj)
        is_test = runs.trajectory.isin(test_traj) | (heldout[r] & ~runs.trajectory.isin(shared[r]))
        is_validation = runs.trajectory.isin(validation_traj) & ~heldout[r]
        is_train = ~runs.trajectory.isin(validation_traj + test_traj) & ~heldout[r]
        excluded = ~(is_test | is_validation | is_train)
        rounds.append(
            SplitRound(
                validation_traj,
                test_traj,
                sorted(runs.run[is_train]),
                sorted(runs.run[is_validation]),
                sorted(runs.run[is_test]),
                sorted(runs.run[excluded]),
                rooms[r],
                _heldout_cameras(config, r),
            )
        )
    splits = Splits(sorted(set().union(*rooms)) if rooms else [], rounds, sorted(config.heldout_cameras), build, box)
    check_no_leak(splits, runs)
    return splits


def make_final_split(runs: pd.DataFrame, config: SplitConfig, lockbox: LockboxConfig | None = None) -> Splits:
    """One round for the model to ship: a validation trajectory of each motion group (seeded) for early stopping,
    every other run outside the ``lockbox`` to train on, and no test set: such a model is judged only on the
    lockbox (``seesys estimator lockbox``), its design having been chosen on the cross-validation rounds."""
    build = build_fingerprint(runs)
    box = lockbox_runs(runs, lockbox)
    if box is not None:
        runs = runs[~runs.run.isin(box.runs)].reset_index(drop=True)
    rng = np.random.default_rng(config.seed)
    validation = []
    for group, names in runs.groupby("motion_group").trajectory:
        names = sorted(set(names))
        if len(names) < 2:
            raise SplitError(f"motion group {group} has {len(names)} trajectory; the final split needs 2")
        validation.append(names[int(rng.integers(len(names)))])
    is_validation = runs.trajectory.isin(validation)
    final = SplitRound(
        sorted(validation), [], sorted(runs.run[~is_validation]), sorted(runs.run[is_validation]), [], [], [], []
    )
    splits = Splits([], [final], [], build, box)
    check_no_leak(splits, runs)
    return splits


def check_no_leak(splits: Splits, runs: pd.DataFrame) -> None:
    """Raise :class:`SplitError` if a run of the splits is not in ``runs``, a run or a trajectory is in two parts of
    a round, a round's held-out environment or camera is in its training or validation, or a lockbox run is in a
    round."""
    trajectory_of = dict(zip(runs.run, runs.trajectory))
    environment_of = dict(zip(runs.run, runs.environment))
    camera_of = dict(zip(runs.run, runs.camera_model))
    boxed = set(splits.lockbox.runs) if splits.lockbox else set()
    for k, split_round in enumerate(splits.rounds):
        environments, cameras = splits.heldout(k)
        seen: dict[str, str] = {}
        for part in PARTS:
            for run in getattr(split_round, part):
                if run not in trajectory_of:
                    raise SplitError(f"round {k}: {part} run {run} is not in the dataset folders")
                if run in boxed:
                    raise SplitError(f"round {k}: lockbox run {run} is in {part}")
                trajectory = trajectory_of[run]
                if seen.setdefault(trajectory, part) != part:
                    raise SplitError(f"round {k}: trajectory {trajectory} is in {seen[trajectory]} and {part}")
                if part != "test" and environment_of[run] in environments:
                    raise SplitError(f"round {k}: held-out environment {environment_of[run]} is in {part}")
                if part != "test" and camera_of[run] in cameras:
                    raise SplitError(f"round {k}: held-out camera {camera_of[run]} is in {part}")


def check_splits(splits: Splits, roots: list[Path], source: str) -> None:
    """Raise :class:`SplitError` when ``splits`` (read from ``source``) were made from another build than the
    dataset folders ``roots`` (one line naming both builds), or leak (:func:`check_no_leak`)."""
    runs = run_table(roots)
    if splits.build is not None:
        build = build_fingerprint(runs)
        if build.name != splits.build.name:
            raise SplitError(
                f"{source} was made from {splits.build.name} ({splits.build.runs} runs), the dataset "
                f"folders are {build.name} ({build.runs} runs): make splits of this build with "
                f"`seesys dataset splits`"
            )
    check_no_leak(splits, runs)


def read_splits(path: Path, roots: list[Path]) -> Splits:
    """The splits of ``path``, checked against the dataset folders ``roots`` they will be used on: made from
    their build, no leak between parts, no lockbox run in a round (:func:`check_splits`); raises a one-line
    :class:`SplitError`."""
    try:
        splits = Splits.from_json(Path(path).read_text())
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SplitError(f"cannot read the splits {path}: {e}") from None
    check_splits(splits, [Path(r) for r in roots], str(path))
    return splits


def write_splits(
    roots: list[Path], config: SplitConfig, out: Path, lockbox: LockboxConfig | None = None, final: bool = False
) -> Splits:
    """The rounds of :func:`make_splits` (with ``final``, the one round of :func:`make_final_split`) written to
    ``out``."""
    splits = (make_final_split if final else make_splits)(run_table(roots), config, lockbox)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(splits.to_json())
    return splits


TEST_TRAJECTORIES = "test trajectories"
HELDOUT_ENVIRONMENTS = "held-out environments"


def heldout_camera_set(camera: str) -> str:
    return f"held-out camera {camera}"


def set_indices(meta: pd.DataFrame, environments: list[str], cameras: list[str]) -> dict[str, np.ndarray]:
    """The windows (indices into ``meta``) of a round's test sets: the test trajectories, the held-out
    ``environments`` and each held-out camera of ``cameras`` (through which a held-out environment's run counts for
    its camera); a set without windows (a round that holds out no room) is left out."""
    camera = meta.camera_model.to_numpy() if len(meta) else np.zeros(0, str)
    unseen_camera = np.isin(camera, cameras)
    in_heldout = (meta.environment.isin(environments).to_numpy() if len(meta) else np.zeros(0, bool)) & ~unseen_camera
    sets = {
        TEST_TRAJECTORIES: np.flatnonzero(~in_heldout & ~unseen_camera),
        HELDOUT_ENVIRONMENTS: np.flatnonzero(in_heldout),
    }
    for name in cameras:
        sets[heldout_camera_set(name)] = np.flatnonzero(camera == name)
    return {name: index for name, index in sets.items() if len(index)}
