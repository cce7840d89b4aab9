"""Labelled session folders with a known error mechanism, and a tiny dataset made from them, for the estimator's
tests; a configuration small enough to train in seconds, and the tiny dataset's round 0 trained once per test
session.

A synthetic session is what the device writes (``session.json``, ``frames.csv``, ``trajectory.tum``,
``groundtruth.tum``, ``rts.csv`` + ``rts.json``, ``psd/``), written with the device's own writers. The estimate is
the ground truth plus noise whose size follows a hidden difficulty that changes every 30 frames; the difficulty
shows in the RTS channels (fewer inliers, more outliers, less contrast) and in the PSD (fewer inlier cells), so a
model can learn the label from the inputs. ``noise_scale`` makes the same inputs mean larger errors: another
"camera", for fine-tuning. The tiny dataset stores such sessions with the dataset builder's own labelling and
windowing (``label_run``) and store writer (``write_run``): a sample for every labelled frame, as a build does.
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from estimator.dataset.build import label_run
from estimator.dataset.config import load_dataset_config
from estimator.dataset.splits import SplitRound, Splits, read_splits
from estimator.dataset.store import COMPLETED, RunInfo, write_run
from seesys.core import camera_normalisation, rts_schema, session_layout
from seesys.core.messages import FeatureFrame
from seesys.core.tracking_state import TrackingState
from seesys.core.trajectory import Poses
from seesys.io import session_files
from seesys.io.core_settings import load_label_config, load_window_config
from seesys.io.rts_log import PsdLogWriter, RtsCsvWriter
from seesys.io.trajectory_files import write_tum
from slam_monitor.orbslam_settings import SlamMode

FPS = 30.0
PSD_SHAPE = (32, 48)  # small PSD matrices keep the tests fast; the model takes any multiple of its patch
SEGMENT = 30


@contextlib.contextmanager
def one_torch_thread():
    """With the other core busy, two torch threads run tiny models tens of times slower than one."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.fixture
def single_thread():
    """Torch on one thread for the test (modules of torch tests use it: ``pytest.mark.usefixtures``)."""
    with one_torch_thread():
        yield


def write_session(
    folder: Path, seed: int, frames: int = 240, noise_scale: float = 1.0, t0: float = 0.0, camera_gain: float = 1.0
) -> Path:
    """A labelled RGB-D session folder whose errors follow a hidden per-segment difficulty (module docstring); its
    times start at ``t0`` (an epoch time, as a RealSense or TUM recording has); ``camera_gain``: another camera's
    image, its contrast that many times and its Laplacian variance the square of it."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    elapsed = np.arange(frames) / FPS
    t = t0 + elapsed
    difficulty = np.repeat(rng.uniform(0, 1, frames // SEGMENT + 1), SEGMENT)[:frames]
    gt_pos = np.column_stack([0.3 * np.sin(0.5 * elapsed), 0.1 * elapsed, 0.2 * np.cos(0.4 * elapsed)])
    gt_rot = Rotation.from_euler("y", 0.3 * elapsed[:, None])
    sigma = noise_scale * (0.0005 + 0.006 * difficulty)
    est_pos = gt_pos + rng.normal(size=(frames, 3)) * sigma[:, None]
    quats = gt_rot.as_quat()
    write_tum(folder / session_layout.GROUND_TRUTH, Poses(t, gt_pos, quats))
    write_tum(folder / session_layout.TRAJECTORY, Poses(t, est_pos, quats))
    with open(folder / session_layout.FRAMES_CSV, "w") as f:
        f.write(session_layout.FRAMES_HEADER + "\n")
        for k in range(frames):
            f.write(f"{k},{t[k]:.6f},OK,{int(400 - 300 * difficulty[k])},5.0\n")
    session_files.update_manifest(folder, mode="rgbd", status="completed", frames=frames)
    rts_writer = RtsCsvWriter(folder / "rts.csv")
    psd_writer = PsdLogWriter(folder / "psd", 100)
    velocity = np.gradient(gt_pos, axis=0)
    for k in range(frames):
        d = difficulty[k]
        row = np.zeros(rts_schema.NUM_CHANNELS, np.float32)
        values = {
            "brightness": 0.5 + 0.05 * rng.normal(),
            "contrast": camera_gain * (0.25 - 0.15 * d),
            "entropy": 7.2 - 1.5 * d,
            "laplacian": camera_gain**2 * (300 - 200 * d),
            "matched_inliers": 400 - 300 * d + 10 * rng.normal(),
            "outliers": 20 + 60 * d + 3 * rng.normal(),
            "matches_before_po": 420 - 240 * d,
            "rel_tx": velocity[k, 0],
            "rel_ty": velocity[k, 1],
            "rel_tz": velocity[k, 2],
            "rel_roll": 0.0,
            "rel_pitch": 0.0,
            "rel_yaw": 0.01,
            "avg_mp_depth": 2.0 + d,
            "var_mp_depth": 0.5,
            "local_mapping_visual_error": 0.8 + 2 * d,
            # schema v4's geometry channels, as a monitor gives them: a harder stretch is less well observed
            "translation_sigma": 1.0 + 4.0 * d + 0.2 * rng.normal(),
            "weakest_information": 10.0 * (1.0 - 0.8 * d),
            "inverse_condition": 0.2 - 0.15 * d,
            "image_coverage": 0.9 - 0.5 * d,
            "depth_spread": 0.8,
            "residual_median": 0.5 + d,
            "residual_p90": 1.2 + 2.0 * d,
            "residual_over_gate": 0.02 + 0.1 * d,
            "flow_disagreement": 1.0 + 5.0 * d + 0.5 * rng.normal(),
        }
        for name, value in values.items():
            row[rts_schema.index_of(name)] = value
        psd = np.zeros((*PSD_SHAPE, 3), np.uint8)
        cells = rng.uniform(size=PSD_SHAPE)
        psd[..., 0] = np.where(cells < 0.4, 120, 0)
        psd[..., 1] = np.where(cells < 0.4 * (1 - d), 255, 0)
        psd[..., 2] = np.where(rng.uniform(size=PSD_SHAPE) < 0.2, 90, 0)
        rts_writer.write(FeatureFrame(folder.name, k, float(t[k]), TrackingState.OK, row))
        psd_writer.write(k, float(t[k]), psd)
    rts_writer.close()
    psd_writer.close()
    return folder


@dataclasses.dataclass(frozen=True)
class TinyDataset:
    root: Path
    splits: Path
    sessions: Path


# (trajectory, motion group, environment) of each run; heldout_env is the held-out environment.
RUNS = [
    ("traj_a", "patrol", "lab"),
    ("traj_b", "patrol", "lab"),
    ("traj_c", "aiming", "office"),
    ("traj_d", "aiming", "office"),
    ("traj_e", "rapid", "lab"),
    ("traj_f", "patrol", "heldout_env"),
]


def build_tiny_dataset(base: Path) -> TinyDataset:
    """Six runs of 240 frames, one split round: 3 train, 1 validation, 1 test, 1 test in a held-out environment."""
    root, sessions = base / "dataset", base / "sessions"
    windows = dataclasses.replace(load_window_config(), end_stride=load_dataset_config().window_end_stride)
    names = []
    for k, (trajectory, group, environment) in enumerate(RUNS):
        name = f"{environment}__{trajectory}__s0__rgbd__t0"
        folder = write_session(sessions / name, seed=k)
        arrays = label_run(folder, SlamMode.RGBD, load_label_config(), windows)
        info = RunInfo(
            name,
            f"{environment}__{trajectory}__s0",
            environment,
            group,
            trajectory,
            "rgbd",
            0,
            COMPLETED,
            frames=240,
            frames_tracked=240,
            samples=len(arrays.samples),
            camera_normalisation=camera_normalisation.VERSION,
        )
        write_run(root, info, arrays)
        names.append(name)
    split_round = SplitRound(
        ["traj_d"], ["traj_e", "traj_f"], [names[0], names[1], names[2]], [names[3]], [names[4], names[5]], []
    )
    splits = base / "splits.json"
    splits.write_text(Splits(["heldout_env"], [split_round]).to_json())
    return TinyDataset(root, splits, sessions)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> TinyDataset:
    """Built once per test session, whichever module asks first."""
    return build_tiny_dataset(tmp_path_factory.mktemp("deepsee"))


def tiny_config():
    """configs/estimator.toml with a model and schedules small enough for a test (seconds on one core)."""
    from estimator.deepsee.config import (
        FinetuneConfig,
        FusionConfig,
        ModelConfig,
        PsdEncoderConfig,
        RtsEncoderConfig,
        Schedule,
        StageSchedule,
        Ts2VecSchedule,
        load_estimator_config,
    )
    from estimator.deepsee.stages import with_schedule

    config = load_estimator_config()
    model = ModelConfig(
        32, PsdEncoderConfig(16, 1, 2, 2.0, 0.0), RtsEncoderConfig(16, 2, 3, 0.0), FusionConfig(1, 2, 2.0, (32,), 0.0)
    )
    stage = StageSchedule(epochs=3, steps_per_epoch=8, batch_size=32, lr=2e-3, weight_decay=0.0, patience=3)
    frozen = dataclasses.replace(stage, epochs=8, steps_per_epoch=0, batch_size=64, lr=3e-3)
    schedule = Schedule(0, 0, stage, 0.5, Ts2VecSchedule(20, 8, 1e-3, 0.5, 0.5), frozen, stage, frozen, stage, frozen)
    finetune = FinetuneConfig(0.25, dataclasses.replace(stage, epochs=8, steps_per_epoch=0, lr=1e-3))
    return with_schedule(dataclasses.replace(config, model=model, finetune=finetune), "reduced", schedule)


def tiny_config_dir(folder: Path) -> Path:
    """The configuration in use with configs/estimator.toml replaced by :func:`tiny_config`, written to ``folder``
    (for ``$SEESYS_CONFIG_DIR``)."""
    from estimator.deepsee import config as estimator_config
    from seesys.io.config import ConfigSet

    return ConfigSet.read().replaced(estimator_config.SECTION, tiny_config()).write(folder)


TRAINED_ROWS = ["deepsee", "wo_psd", "lstm", "random_forest"]


def train_context(progress, config=None):
    from estimator.deepsee.stages import TrainContext

    return TrainContext(
        config or tiny_config(),
        "reduced",
        load_window_config(),
        torch.device("cpu"),
        progress,
        {"data": ["tiny"], "round": 0},
    )


@pytest.fixture(scope="session")
def trained_runs(tiny_dataset) -> Path:
    """Round 0 of the tiny dataset trained for DeepSEE, one ablation and both baselines (``RUNS/round_0/<row>``),
    once per test session."""
    from rich.progress import Progress

    from estimator.deepsee.table import train_table

    runs = tiny_dataset.root.parent / "runs"
    with Progress(disable=True) as progress, one_torch_thread():
        splits = read_splits(tiny_dataset.splits, [tiny_dataset.root])
        train_table([tiny_dataset.root], splits, 0, TRAINED_ROWS, runs, train_context(progress))
    return runs
