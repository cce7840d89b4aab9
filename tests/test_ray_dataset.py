"""``seesys dataset build`` on a local 2-CPU Ray instance against the same build run locally, on a tiny dataset
(2 environments × patrol × 1 trial, 60 frames of 320×240) with real rendering and real ORB-SLAM3: the same files,
the same rendered bytes, the same schema (ORB-SLAM3 is not deterministic, so not the same numbers), the driver's
settings in every task, and the same resume."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from estimator.dataset.build import DATASET_JSON, SEQUENCES_DIR, SESSIONS_DIR, DatasetBuilder, plan_from_config
from estimator.dataset.config import load_dataset_config
from estimator.dataset.store import RUN_JSON, RUNS_DIR
from estimator.jobs import RayExecutor
from seesys.core import session_layout
from seesys.io.config import write_config_dir
from seesys.io.core_settings import load_label_config, load_window_config
from synth.config import load_synth_config
from synth.sequence import SequenceSpec

ENVIRONMENTS = ["lab", "office"]
TEMPLATE = SequenceSpec("", "", 0, 60, 320, 240)
STALL_TIMEOUT_S = 97.0  # not the default: a session's session.json shows which settings its task had


def _build(root: Path, configs: Path, executor=None):
    builder = DatasetBuilder(
        root, load_dataset_config(), load_synth_config(), load_label_config(), load_window_config(), configs
    )
    plan = plan_from_config(
        load_dataset_config(), load_synth_config(), TEMPLATE, ENVIRONMENTS, ["patrol"], [0], ["rgbd"], 1
    )
    return builder.build(plan, executor)


def _files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def builds(local_ray, tmp_path_factory):
    """The tiny dataset built here and on Ray (one SLAM CPU per run, so that both runs share the 2 CPUs)."""
    base = tmp_path_factory.mktemp("ray_dataset")
    configs = write_config_dir(base / "configs", {"slam.stall_timeout_s": STALL_TIMEOUT_S, "slam_cpus": 1})
    local = _build(base / "local", configs)
    remote = _build(base / "ray", configs, RayExecutor(local_ray))
    return base, configs, local, remote


@pytest.mark.system
def test_ray_writes_the_local_builds_files_and_schema(builds):
    base, _, local, remote = builds
    assert _files(base / "ray") == _files(base / "local")
    assert (
        [r.run for r in remote.runs_done]
        == [r.run for r in local.runs_done]
        == ["lab__patrol__s0__rgbd__t0", "office__patrol__s0__rgbd__t0"]
    )
    assert (remote.sequences, remote.rendered_frames, remote.runs_skipped) == (2, 120, 0)
    for sequence in (base / "local" / SEQUENCES_DIR).iterdir():  # rendering is deterministic
        for path in sequence.rglob("*"):
            if path.is_file():
                assert path.read_bytes() == (base / "ray" / path.relative_to(base / "local")).read_bytes(), path
    assert json.loads((base / "ray" / DATASET_JSON).read_text()) == json.loads(
        (base / "local" / DATASET_JSON).read_text()
    )
    log = [json.loads(line) for line in (base / "ray" / "build_log.jsonl").read_text().splitlines()]
    assert [(e["phase"], sorted(e)) for e in log] == [
        (e["phase"], sorted(e)) for e in map(json.loads, (base / "local" / "build_log.jsonl").read_text().splitlines())
    ]
    for info in remote.runs_done:
        here, there = base / "local" / RUNS_DIR / info.run, base / "ray" / RUNS_DIR / info.run
        assert json.loads((there / RUN_JSON).read_text()).keys() == json.loads((here / RUN_JSON).read_text()).keys()
        assert info.frames == 60
        for npy in here.glob("*.npy"):
            a, b = np.load(npy, mmap_mode="r"), np.load(there / npy.name, mmap_mode="r")
            assert (a.dtype, a.shape[1:]) == (b.dtype, b.shape[1:]), npy.name
        for csv in here.glob("*.csv"):
            assert list(pd.read_csv(csv).columns) == list(pd.read_csv(there / csv.name).columns), csv.name


@pytest.mark.system
def test_every_task_ran_with_the_drivers_settings(builds):
    base, _, _, remote = builds
    for info in remote.runs_done:
        manifest = json.loads((base / "ray" / SESSIONS_DIR / info.run / session_layout.MANIFEST).read_text())
        assert manifest["config"]["slam"]["supervisor"]["stall_timeout_s"] == STALL_TIMEOUT_S


@pytest.mark.system
def test_a_rerun_on_ray_does_only_the_missing_run_as_a_local_rerun_would(builds, local_ray):
    base, configs, _, _ = builds
    copy = base / "resumed"
    shutil.copytree(base / "ray", copy)
    shutil.rmtree(copy / RUNS_DIR / "office__patrol__s0__rgbd__t0")  # a run that never finished
    again = _build(copy, configs, RayExecutor(local_ray))
    assert (again.rendered_frames, again.runs_skipped) == (0, 1)
    assert [r.run for r in again.runs_done] == ["office__patrol__s0__rgbd__t0"]
    assert _files(copy) == _files(base / "local")
    here = _build(copy, configs)  # the local build takes the Ray-built dataset as its own
    assert (here.rendered_frames, here.runs_skipped, here.runs_done) == (0, 2, [])
