"""``seesys estimator train-table`` on a local 2-CPU Ray instance against the local run of the same rows (the tiny
dataset and model of test_deepsee_sessions, one torch thread a row): the same run folders and files, the same
configurations, the same training, DeepSEE's encoders under the ablation, resume; and the command's ``--ray``."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from rich.progress import Progress
from testkit.deepsee import TRAINED_ROWS, tiny_config, tiny_config_dir

from estimator.dataset.splits import read_splits
from estimator.deepsee.run_folder import CONFIG_JSON, METRICS_CSV
from estimator.deepsee.table import TrainSpec, table_jobs
from estimator.jobs import RayExecutor
from seesys.io.core_settings import load_window_config
from seesys_app.cli import main

pytestmark = pytest.mark.usefixtures("single_thread")


def _files(root) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def ray_runs(local_ray, tiny_dataset, tmp_path_factory):
    """The rows of ``trained_runs`` trained on Ray (one CPU and one torch thread a row)."""
    runs = tmp_path_factory.mktemp("ray_table") / "runs"
    spec = TrainSpec(tiny_config(), "reduced", load_window_config(), "cpu", 1, {"data": ["tiny"]})
    splits = read_splits(tiny_dataset.splits, [tiny_dataset.root])
    jobs = table_jobs([tiny_dataset.root], splits, [0], TRAINED_ROWS, runs, spec)
    with Progress(disable=True) as progress:
        RayExecutor(local_ray).run(jobs, progress)
    return runs, jobs, spec


@pytest.mark.system
def test_ray_trains_the_same_run_folders_as_the_local_run(ray_runs, trained_runs):
    runs, _, _ = ray_runs
    assert _files(runs) == _files(trained_runs)
    for name in TRAINED_ROWS:
        here, there = trained_runs / "round_0" / name, runs / "round_0" / name
        config_here, config_there = (json.loads((f / CONFIG_JSON).read_text()) for f in (here, there))
        if name == "wo_psd":  # waited for DeepSEE's encoders, as the local run's ablation starts from them
            assert (config_here["pretrained"], config_there["pretrained"]) == (
                str(trained_runs / "round_0" / "deepsee"),
                str(runs / "round_0" / "deepsee"),
            )
            config_here["pretrained"] = config_there["pretrained"]
        assert config_there == config_here
        if (here / METRICS_CSV).exists():  # seeded training on one thread: the same losses
            a, b = pd.read_csv(here / METRICS_CSV), pd.read_csv(there / METRICS_CSV)
            assert list(a.stage) == list(b.stage) and list(a.epoch) == list(b.epoch)
            np.testing.assert_allclose(b.train_loss, a.train_loss, rtol=1e-4)


@pytest.mark.system
def test_a_rerun_on_ray_trains_nothing_again(ray_runs, local_ray):
    runs, jobs, _ = ray_runs
    before = {name: len(pd.read_csv(runs / "round_0" / name / METRICS_CSV)) for name in ("deepsee", "wo_psd", "lstm")}
    with Progress(disable=True) as progress:
        models = RayExecutor(local_ray).run(jobs, progress)
    assert [m.parent.name for m in models] == [j.args[3] for j in jobs]
    assert {name: len(pd.read_csv(runs / "round_0" / name / METRICS_CSV)) for name in before} == before


@pytest.mark.system
def test_the_command_trains_rows_on_ray(local_ray, tiny_dataset, tmp_path, capsys, monkeypatch):
    """``seesys estimator train-table --ray`` (Ray already initialised here: the command uses it as it is)."""
    configs = tiny_config_dir(tmp_path / "configs")
    monkeypatch.setenv("SEESYS_CONFIG_DIR", str(configs))
    args = [
        "estimator",
        "train-table",
        "--data",
        str(tiny_dataset.root),
        "--splits",
        str(tiny_dataset.splits),
        "--rows",
        "lstm,random_forest",
        "--runs",
        str(tmp_path / "runs"),
        "--threads",
        "1",
        "--ray",
    ]
    assert main(args) == 0
    assert "round 0: 2 rows trained under" in capsys.readouterr().out
    assert (
        _files(tmp_path / "runs" / "round_0" / "lstm")
        and (tmp_path / "runs" / "round_0" / "random_forest" / "model.pkl").is_file()
    )
    assert main(args[:-1] + ["--device", "cuda", "--ray"]) == 2  # no node has a GPU: said at once, in one line
    assert capsys.readouterr().err.strip() == (
        "seesys: error: round 0: lstm needs 1 CPU + 1 GPU on one node; the Ray cluster's nodes have 2 CPU + 0 GPU"
    )
