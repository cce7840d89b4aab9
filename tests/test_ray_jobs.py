"""The job executors on a local 2-CPU Ray instance: a job's progress reaches the driver's display as the local
run's does, a task reads the driver's settings, dependencies, one-line errors, resources no node has; and the
``--ray`` flag's address errors, without importing Ray where it is not asked for."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch
from testkit.ports import refused_port
from testkit.sample import REPO, run_seesys

from estimator.dataset.splits import Splits
from estimator.deepsee.rows import ROW_NAMES
from estimator.deepsee.table import TrainSpec, job_name, table_jobs
from estimator.jobs import Job, LocalExecutor, RayExecutor, load_ray_settings
from seesys.core.errors import SeesysError
from seesys.io.config import write_config_dir


class RecordingProgress:
    """A rich Progress stand-in that records the calls made on it (the driver's display)."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.console = self
        self._ids = 0

    def add_task(self, description, **kwargs):
        self._ids += 1
        self.calls.append(("add_task", self._ids, description, kwargs))
        return self._ids

    def update(self, task, **kwargs):
        self.calls.append(("update", task, kwargs))

    def advance(self, task, advance=1):
        self.calls.append(("advance", task, advance))

    def remove_task(self, task):
        self.calls.append(("remove_task", task))

    def log(self, *objects):
        self.calls.append(("log", objects))


def counting_job(name: str, steps: int, env) -> tuple[str, int, int]:
    """Shows a bar of ``steps``; returns the SLAM CPUs of its config folder and of $SEESYS_CONFIG_DIR's."""
    task = env.progress.add_task(name, total=steps)
    for _ in range(steps):
        env.progress.advance(task)
    env.progress.update(task, description=f"{name} done")
    env.progress.console.log(f"{name} ended")
    env.progress.remove_task(task)
    return name, load_ray_settings(env.config_dir).slam_cpus, load_ray_settings().slam_cpus


def write_job(path, text: str, env) -> str:
    path.write_text(text)
    return text


def read_job(path, env) -> str:
    return path.read_text()


def failing_job(message: str, env):
    raise SeesysError(message)


def broken_job(env):
    return 1 / 0


@pytest.fixture(scope="module")
def ray_module(local_ray):
    """The local Ray, with this module's job functions sent by value (its workers cannot import a test module)."""
    local_ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    return local_ray


@pytest.fixture
def configs(tmp_path):
    """configs/ with slam_cpus = 1: settings a task can only have from the driver."""
    return write_config_dir(tmp_path / "configs", {"slam_cpus": 1})


@pytest.mark.system
def test_a_task_shows_the_same_progress_and_reads_the_drivers_settings(ray_module, configs):
    jobs = [Job("one", counting_job, ("one", 5))]
    local, remote = RecordingProgress(), RecordingProgress()
    assert LocalExecutor().run(jobs, local, config_dir=configs) == [("one", 1, 2)]
    # On Ray, $SEESYS_CONFIG_DIR is the driver's settings too (this process's default says 2).
    assert RayExecutor(ray_module).run(jobs, remote, config_dir=configs) == [("one", 1, 1)]
    assert remote.calls == local.calls
    assert local.calls[0] == ("add_task", 1, "one", {"total": 5}) and local.calls[-1] == ("remove_task", 1)


@pytest.mark.system
def test_results_come_in_job_order_and_each_end_is_reported(ray_module, configs):
    jobs = [Job(name, counting_job, (name, 3)) for name in ("a", "b", "c")]
    ended = []
    progress = RecordingProgress()
    results = RayExecutor(ray_module).run(
        jobs, progress, lambda job, result: ended.append((job.name, result[0])), configs
    )
    assert [r[0] for r in results] == ["a", "b", "c"] and sorted(ended) == [("a", "a"), ("b", "b"), ("c", "c")]
    added = {c[2] for c in progress.calls if c[0] == "add_task"}
    assert added == {"a", "b", "c"} and sum(c[0] == "remove_task" for c in progress.calls) == 3


@pytest.mark.system
def test_a_job_waits_for_the_jobs_it_comes_after(ray_module, tmp_path):
    path = tmp_path / "first.txt"
    jobs = [Job("first", write_job, (path, "written first")), Job("second", read_job, (path,), after=("first",))]
    assert RayExecutor(ray_module).run(jobs, RecordingProgress()) == ["written first", "written first"]


@pytest.mark.system
def test_a_failed_task_is_the_same_error_as_a_failed_local_job(ray_module):
    jobs = [Job("fails", failing_job, ("run x: bad input",))]
    with pytest.raises(SeesysError, match="^run x: bad input$"):
        LocalExecutor().run(jobs, RecordingProgress())
    with pytest.raises(SeesysError, match="^run x: bad input$"):
        RayExecutor(ray_module).run(jobs, RecordingProgress())
    with pytest.raises(ray_module.exceptions.RayTaskError, match="ZeroDivisionError"):  # a bug keeps its traceback
        RayExecutor(ray_module).run([Job("broken", broken_job, ())], RecordingProgress())


@pytest.mark.system
def test_a_job_no_node_can_take_is_refused_at_once(ray_module):
    executor = RayExecutor(ray_module)
    with pytest.raises(
        SeesysError,
        match=r"^big needs 3 CPU \+ 0 GPU on one node; the Ray cluster's nodes have 2 "
        r"CPU \+ 0 GPU$",
    ):
        executor.run([Job("big", write_job, (None, ""), cpus=3)], RecordingProgress())
    with pytest.raises(SeesysError, match=r"needs 1 CPU \+ 1 GPU"):
        executor.run([Job("gpu", write_job, (None, ""), gpus=1)], RecordingProgress())


def test_table_jobs_reserve_a_gpu_on_cuda_and_ablations_wait_for_deepsee():
    spec = TrainSpec(None, "reduced", None, "cuda", 3, {})
    jobs = {j.name: j for j in table_jobs([], None, [0, 1], list(ROW_NAMES), REPO, spec)}
    assert len(jobs) == 2 * len(ROW_NAMES)
    assert jobs[job_name(1, "random_forest")].gpus == 0 and jobs[job_name(1, "lstm")].gpus == 1
    assert all(j.cpus == 3 for j in jobs.values())
    assert jobs[job_name(1, "wo_psd")].after == (job_name(1, "deepsee"),)
    assert jobs[job_name(1, "wo_ssl")].after == () and jobs[job_name(0, "lstm")].after == ()
    cpu_only = table_jobs([], None, [0], ["wo_psd", "lstm"], REPO, TrainSpec(None, "reduced", None, "cpu", 1, {}))
    assert [(j.gpus, j.after) for j in cpu_only] == [(0, ()), (0, ())]  # no DeepSEE job to wait for
    if not torch.cuda.is_available():  # a node whose torch has no CUDA says so in one line, before any work
        with pytest.raises(SeesysError, match=r"^--device cuda: no CUDA device for the task on .* \(this torch is "):
            LocalExecutor().run([jobs[job_name(0, "lstm")]], RecordingProgress())


@pytest.mark.system
def test_an_unreachable_or_malformed_address_is_a_one_line_error(tmp_path):
    out = tmp_path / "dataset"
    with refused_port() as port:
        result = run_seesys("dataset", "build", "--out", str(out), "--envs", "lab", "--ray", f"127.0.0.1:{port}")
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"seesys: error: cannot reach the Ray cluster at 127.0.0.1:{port}: "
        f"Connection refused (is `ray start --head` running there?)"
    ]
    assert not out.exists()
    (tmp_path / "splits.json").write_text(Splits([], []).to_json())
    result = run_seesys(
        "estimator",
        "train-table",
        "--data",
        str(out),
        "--splits",
        str(tmp_path / "splits.json"),
        "--runs",
        str(tmp_path / "runs"),
        "--ray",
        "headnode",
    )
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "--ray headnode: expected auto or HOST:PORT" in result.stderr
    assert not (tmp_path / "runs").exists()


@pytest.mark.system
def test_commands_import_ray_only_when_asked_to():
    code = (
        "import sys; from seesys_app.cli import build_parser; build_parser(); "
        "import estimator.dataset.build, estimator.deepsee.table, estimator.jobs; "
        "print('ray' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert result.stdout.strip() == "False", result.stderr
