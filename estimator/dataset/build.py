"""Build the labelled dataset: render, then play every sequence through ORB-SLAM3 + the RTS monitor, label, store.

Order matters: every sequence is rendered first (one job per sequence, :func:`synth.batch.plan_batch`),
and only then are the SLAM runs made, one job per run, each in its own child process
(:func:`run_supervised_session`), at camera pace. Rendering while SLAM runs would take the CPU from ORB-SLAM3's
threads and change the errors being measured (monocular ORB-SLAM3 tracked 21 % of an easy sequence with two
renders running beside it). Here the jobs run one at a time; with ``--ray`` (:mod:`estimator.jobs`) each is a Ray
task reserving its CPUs (a render its processes, a run ``slam_cpus`` of configs/ray.toml), the same jobs with the
same skip rules and writes.

Each (sequence, mode, trial) becomes one run of the store (:mod:`estimator.dataset.store`); a finished run is
never redone, so an interrupted build continues where it stopped. When ORB-SLAM3 crashes or hangs part-way
(it does in map resets after a tracking loss), the frames it logged are labelled and stored as a ``partial`` run:
dropping them would drop the hardest stretches from the data. A session that fails before its first frame (bad
input, a crash at start) is recorded with its error and skipped.
"""

from __future__ import annotations

import copy
import json
import shutil
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from estimator.dataset.config import DatasetConfig
from estimator.dataset.store import (
    COMPLETED,
    CRASHED,
    DATASET_JSON,
    FORMAT_KEY,
    FORMAT_VERSION,
    PARTIAL,
    RUNS_DIR,
    RunArrays,
    RunInfo,
    label_definition,
    read_run_info,
    record_crashed_run,
    run_folder,
    run_name,
    write_run,
)
from estimator.jobs import Job, JobEnv, LocalExecutor, RayExecutor, load_ray_settings
from seesys.core import camera_normalisation, rts_schema, session_layout
from seesys.core.errors import SeesysError
from seesys.core.labels import LabelConfig, LabelStatus
from seesys.core.windows import WindowConfig, assemble_windows
from seesys.io import session_files
from seesys.io.rts_log import read_feature_frames
from seesys.io.session_labels import label_session
from slam_monitor.device_worker import FrameTracked, ObserverSpec, SessionOptions, SessionStarted
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.supervisor import run_supervised_session
from synth.batch import CameraDraw, expand_environments, expand_motions, plan_batch, render_into
from synth.config import SynthConfig
from synth.sequence import SequenceSpec

SEQUENCES_DIR = "sequences"
SESSIONS_DIR = "sessions"
BUILD_LOG = "build_log.jsonl"
SEQUENCE_METADATA = "metadata.json"
MONITOR_OBSERVER = "slam_monitor.monitor:create_observer"
# What a sample is: a later build into the same folder must agree on all of these.
DEFINITION_KEYS = ("rts_channels", "rts_schema_version", "windows", "labels", "pace", "wait_for_mapping_modes")
PROGRESS_COLUMNS = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())


@dataclass(frozen=True)
class BuildPlan:
    """What to build: the render template (length, size, lens) and the batch, the SLAM modes and trials."""

    template: SequenceSpec
    environments: list[str]
    motions: list[str]
    seeds: list[int]
    modes: list[SlamMode]
    trials: int
    render_processes: int | None = None
    cameras: CameraDraw | None = None  # None: every preset through its own camera model


@dataclass(frozen=True)
class BuildResult:
    sequences: int
    rendered_frames: int
    render_seconds: float
    runs_done: list[RunInfo]
    runs_skipped: int
    slam_seconds: float

    @property
    def crashed(self) -> list[RunInfo]:
        """Runs whose SLAM session failed: with no sample (``crashed``) or with the frames before it (``partial``)."""
        return [r for r in self.runs_done if r.status in (CRASHED, PARTIAL)]


def plan_from_config(
    config: DatasetConfig,
    synth: SynthConfig,
    template: SequenceSpec,
    environments: list[str] | None = None,
    motions: list[str] | None = None,
    seeds: list[int] | None = None,
    modes: list[str] | None = None,
    trials: int | None = None,
    render_processes: int | None = None,
    cameras: list[str] | None = None,
) -> BuildPlan:
    """The build plan: arguments given override configs/dataset.toml (``cameras``: models drawn with equal
    weights; an empty list: each preset's own camera); names are checked here, before any work."""
    trials = config.trials if trials is None else trials
    if trials < 1:
        raise SeesysError(f"trials must be at least 1, got {trials}")
    try:
        slam_modes = [SlamMode(m) for m in (modes or config.modes)]
    except ValueError as e:
        raise SeesysError(f"unknown SLAM mode: {e}") from None
    draw = config.cameras if cameras is None else CameraDraw(tuple(cameras), (1.0,) * len(cameras))
    for name in draw.models:  # refuses an unknown model by name, before any work
        synth.camera_model(name)
    return BuildPlan(
        template,
        expand_environments(list(environments or config.environments), synth),
        expand_motions(list(motions or config.motions), synth),
        list(seeds or config.seeds),
        slam_modes,
        trials,
        render_processes,
        draw if draw.models else None,
    )


def _sequence_metadata(folder: Path) -> dict:
    try:
        return json.loads((folder / SEQUENCE_METADATA).read_text())
    except (OSError, ValueError) as e:
        raise SeesysError(f"rendered sequence {folder} has no readable {SEQUENCE_METADATA}: {e}") from None


def label_run(session_dir: Path, mode: SlamMode, label_config: LabelConfig, windows: WindowConfig) -> RunArrays:
    """Samples of one finished session: every model window (:func:`seesys.core.windows.assemble_windows`, at most
    ``windows.max_missing_rts`` RTS rows missing or untracked: the rule the service serves by, so that a model is
    trained on the windows it is served), with the label of its end frame.

    The monitor's RTS rows and PSD matrices are kept once each; a sample is the rows of its window
    (:mod:`estimator.dataset.store`). A sample is ``usable`` (part of the regression target) when its end frame is
    ``labelled`` (and, as every stored window, within the missing-row rule).
    """
    labels = label_session(session_dir, mode is SlamMode.MONO, label_config).to_frame()
    states = pd.read_csv(session_dir / session_layout.FRAMES_CSV)
    frames = pd.concat(
        [states[["frame_index", "state"]].reset_index(drop=True), labels.drop(columns="timestamp")], axis=1
    )
    frames.insert(1, "timestamp", labels.timestamp)
    row_of_frame = {int(f): k for k, f in enumerate(frames.frame_index)}
    logged = list(read_feature_frames(session_dir, session_dir.name))
    with_psd = [(f.frame_index, f.psd) for f in logged if f.psd is not None]  # (frame index, PSD)
    rts_row = {f.frame_index: k for k, f in enumerate(logged)}
    psd_row = {index: k for k, (index, _) in enumerate(with_psd)}
    rts_rows: list[list[int]] = []
    psd_rows: list[list[int]] = []
    rows: list[tuple] = []
    for window in assemble_windows(logged, windows):
        label = frames.iloc[row_of_frame[window.frame_index]]
        usable = label.status == LabelStatus.LABELLED.value and window.missing_rts <= windows.max_missing_rts
        rows.append(
            (
                len(rows),
                window.frame_index,
                window.timestamp,
                label.error_m,
                label.status,
                label.scale,
                window.missing_rts,
                usable,
            )
        )
        rts_rows.append([rts_row.get(int(i), -1) for i in window.rts_frame_indices])
        psd_rows.append([psd_row[int(i)] for i in window.psd_frame_indices])
    samples = pd.DataFrame(
        rows, columns=["sample", "frame_index", "timestamp", "error_m", "status", "scale", "missing_rts", "usable"]
    )
    return RunArrays(
        rts=(np.stack([f.rts for f in logged]) if logged else np.zeros((0, rts_schema.NUM_CHANNELS), np.float32)),
        rts_frames=np.array([f.frame_index for f in logged], np.int64),
        psd=np.stack([psd for _, psd in with_psd]) if with_psd else np.zeros((0, 0, 0, 3), np.uint8),
        psd_frames=np.array([index for index, _ in with_psd], np.int64),
        sample_rts_rows=np.array(rts_rows, np.int32).reshape(-1, windows.rts_length),
        sample_psd_rows=np.array(psd_rows, np.int32).reshape(-1, windows.psd_samples),
        samples=samples,
        frames=frames,
    )


def _merge_plans(earlier: dict, later: dict) -> dict:
    """The plan of a dataset built by ``earlier`` and then extended by ``later``: list entries in first-seen order,
    the larger trial count, the latest camera draw (each run's info records the camera it was rendered through)."""
    merged = dict(earlier)
    for key in ("environments", "motions", "seeds", "modes"):
        merged[key] = list(dict.fromkeys(earlier[key] + later[key]))
    merged["trials"] = max(earlier["trials"], later["trials"])
    merged["cameras"] = later.get("cameras")
    return merged


class DatasetBuilder:
    """Renders a plan's sequences into ``root/sequences`` and stores one run per (sequence, mode, trial).

    ``windows`` are the model windows; their end stride is replaced by ``window_end_stride`` of dataset.toml
    (1: a sample for every labelled frame), and the monitor of every run computes the PSD on those frames."""

    def __init__(
        self,
        root: Path,
        config: DatasetConfig,
        synth: SynthConfig,
        label_config: LabelConfig,
        windows: WindowConfig,
        config_dir: Path | None = None,
    ):
        self.root = Path(root)
        self.config = config
        self.synth = synth
        self.label_config = label_config
        try:
            self.windows = replace(windows, end_stride=config.window_end_stride)
        except ValueError as e:
            raise SeesysError(f"configs/dataset.toml window_end_stride: {e}") from None
        self.config_dir = config_dir

    def build(self, plan: BuildPlan, executor: LocalExecutor | RayExecutor | None = None) -> BuildResult:
        """Render, then run; ``executor`` runs the render and SLAM jobs (default: here, one after the other; a
        :class:`~estimator.jobs.RayExecutor` runs them as Ray tasks). Either way the jobs and what they skip and
        write are the same."""
        executor = executor or LocalExecutor()
        self.root.mkdir(parents=True, exist_ok=True)
        self._write_description(plan)
        processes = plan.render_processes or self.synth.processes
        renders, rendered_before = plan_batch(
            plan.template,
            plan.environments,
            plan.motions,
            plan.seeds,
            self.synth,
            self.root / SEQUENCES_DIR,
            plan.cameras,
        )
        render_jobs = [
            Job(folder.name, render_job, (spec, seen, folder, processes), cpus=processes)
            for spec, folder, seen in renders
        ]
        start = time.perf_counter()
        with Progress(*PROGRESS_COLUMNS, disable=not render_jobs) as progress:
            renders_task = progress.add_task("renders", total=len(render_jobs))
            frames = sum(
                executor.run(render_jobs, progress, lambda job, _: progress.advance(renders_task), self.config_dir)
            )
        render_seconds = time.perf_counter() - start
        self._log(
            {
                "phase": "render",
                "render_processes": processes,
                "rendered_frames": frames,
                "render_seconds": render_seconds,
            }
        )
        for _, folder, _ in renders:
            self._drop_runs_of(folder.name)
        sequences = sorted([folder for _, folder, _ in renders] + rendered_before)
        jobs = [(seq, mode, trial) for seq in sequences for mode in plan.modes for trial in range(plan.trials)]
        todo = [
            job
            for job in jobs
            if read_run_info(run_folder(self.root, run_name(job[0].name, job[1].value, job[2]))) is None
        ]
        slam_cpus = load_ray_settings(self.config_dir).slam_cpus if isinstance(executor, RayExecutor) else 1
        slam_jobs = [
            Job(run_name(seq.name, mode.value, trial), slam_job, (self, seq, mode, trial), cpus=slam_cpus)
            for seq, mode, trial in todo
        ]
        start = time.perf_counter()
        with Progress(*PROGRESS_COLUMNS) as progress:
            runs_task = progress.add_task("SLAM runs", total=len(todo))
            done = executor.run(slam_jobs, progress, lambda job, _: progress.advance(runs_task), self.config_dir)
        result = BuildResult(
            len(sequences), frames, render_seconds, done, len(jobs) - len(todo), time.perf_counter() - start
        )
        self._log(
            {
                "phase": "runs",
                "runs": len(result.runs_done),
                "crashed": len(result.crashed),
                "slam_frames": sum(r.frames for r in result.runs_done),
                "slam_seconds": result.slam_seconds,
            }
        )
        return result

    def with_config_dir(self, config_dir: Path | None) -> DatasetBuilder:
        """The same builder, its device sessions reading their settings from ``config_dir``."""
        builder = copy.copy(self)
        builder.config_dir = config_dir
        return builder

    def _drop_runs_of(self, sequence: str) -> None:
        """Delete the stored runs and sessions of ``sequence``: it was just (re-)rendered, so any run of it already
        there played an older render (its preset was retuned since)."""
        for folder in (self.root / RUNS_DIR, self.root / SESSIONS_DIR):
            for stale in folder.glob(f"{sequence}__*"):
                shutil.rmtree(stale)

    def _log(self, entry: dict) -> None:
        """Append a timed entry to ``build_log.jsonl``: the render phase as soon as it ends (so that an
        interrupted build keeps it), the SLAM runs at the end; each run's own timing is in its ``run.json``."""
        with open(self.root / BUILD_LOG, "a") as f:
            f.write(json.dumps({"time": session_files.utc_now(), **entry}) + "\n")

    def _write_description(self, plan: BuildPlan) -> None:
        """``dataset.json``: what the samples are (channels, windows, label definition) and how they were built.

        A build into an existing dataset adds runs to it, so it must use the same definitions; the plan recorded is
        the union of every build's plan."""
        description = json.loads(
            json.dumps(
                {
                    FORMAT_KEY: FORMAT_VERSION,
                    "rts_channels": list(rts_schema.CHANNEL_NAMES),
                    "rts_schema_version": rts_schema.SCHEMA_VERSION,
                    "windows": asdict(self.windows),
                    "labels": label_definition(self.label_config),
                    "pace": self.config.pace,
                    "wait_for_mapping_modes": list(self.config.wait_for_mapping_modes),
                    "plan": {
                        "template": asdict(plan.template),
                        "environments": plan.environments,
                        "motions": plan.motions,
                        "seeds": plan.seeds,
                        "modes": [m.value for m in plan.modes],
                        "trials": plan.trials,
                        "cameras": asdict(plan.cameras) if plan.cameras else None,
                    },
                }
            )
        )
        path = self.root / DATASET_JSON
        if path.exists():
            earlier = json.loads(path.read_text())
            if earlier.get(FORMAT_KEY, 1) != FORMAT_VERSION:
                raise SeesysError(
                    f"{path}: dataset format {earlier.get(FORMAT_KEY, 1)}, this builder writes format "
                    f"{FORMAT_VERSION}; build into a new folder (move {self.root / SEQUENCES_DIR} "
                    f"into it first to reuse the rendered sequences)"
                )
            changed = [key for key in DEFINITION_KEYS if earlier.get(key) != description[key]]
            if earlier.get("plan", {}).get("template") != description["plan"]["template"]:
                changed.append("render template (frames, size, blur, distortion)")
            if changed:
                raise SeesysError(
                    f"{path}: the dataset there was built with a different {', '.join(changed)}; "
                    f"build into a new folder (samples of two definitions must not mix)"
                )
            description["plan"] = _merge_plans(earlier["plan"], description["plan"])
        path.write_text(json.dumps(description, indent=2) + "\n")

    def _run(self, sequence: Path, mode: SlamMode, trial: int, on_event) -> RunInfo:
        meta = _sequence_metadata(sequence)
        name = run_name(sequence.name, mode.value, trial)
        info = RunInfo(
            name,
            sequence.name,
            meta["environment"],
            meta["motion_group"],
            meta["trajectory"],
            mode.value,
            trial,
            COMPLETED,
            camera_model=meta.get("camera_model", {}).get("name", "ideal"),  # ideal: not recorded
            camera_normalisation=camera_normalisation.VERSION,
        )  # what this process's monitor applies
        session_dir = self.root / SESSIONS_DIR / name
        shutil.rmtree(session_dir, ignore_errors=True)
        options = SessionOptions(
            f"tum:{sequence}",
            mode,
            session_dir,
            pace=self.config.pace,
            wait_for_mapping=mode.value in self.config.wait_for_mapping_modes,
            config_dir=self.config_dir,
            observers=(
                ObserverSpec(
                    MONITOR_OBSERVER, {"stream": False, "device_id": name, "end_stride": self.windows.end_stride}
                ),
            ),
        )
        start = time.perf_counter()
        try:
            result = run_supervised_session(options, progress=on_event)
        except SeesysError as e:
            return self._store_failed(replace(info, status=CRASHED, error=str(e)), session_dir, mode, start)
        slam_seconds = time.perf_counter() - start
        arrays = label_run(session_dir, mode, self.label_config, self.windows)
        info = replace(
            info,
            frames=result.frames,
            frames_tracked=result.frames_tracked,
            samples=len(arrays.samples),
            slam_seconds=slam_seconds,
            seconds=time.perf_counter() - start,
        )
        return self._store(info, arrays, session_dir)

    def _store(self, info: RunInfo, arrays: RunArrays, session_dir: Path) -> RunInfo:
        write_run(self.root, info, arrays)
        if not self.config.keep_sessions:
            shutil.rmtree(session_dir, ignore_errors=True)
        return info

    def _store_failed(self, crashed: RunInfo, session_dir: Path, mode: SlamMode, start: float) -> RunInfo:
        """A failed session: its logged frames as a ``partial`` run, or a ``crashed`` record when it logged none."""
        crashed = replace(crashed, slam_seconds=time.perf_counter() - start)
        frames_csv = session_dir / session_layout.FRAMES_CSV
        logged = pd.read_csv(frames_csv) if frames_csv.is_file() else pd.DataFrame()
        if logged.empty:
            record_crashed_run(self.root, crashed)
            return crashed
        arrays = label_run(session_dir, mode, self.label_config, self.windows)
        tracked = int((arrays.frames.status != LabelStatus.NOT_TRACKED.value).sum())
        partial = replace(
            crashed,
            status=PARTIAL,
            frames=len(arrays.frames),
            frames_tracked=tracked,
            samples=len(arrays.samples),
            seconds=time.perf_counter() - start,
        )
        return self._store(partial, arrays, session_dir)


def render_job(spec: SequenceSpec, synth: SynthConfig, folder: Path, processes: int, env: JobEnv) -> int:
    """One sequence of the build's batch (a job of :meth:`DatasetBuilder.build`); returns its frame count."""
    return render_into(spec, synth, folder, processes, progress=env.progress)


def slam_job(builder: DatasetBuilder, sequence: Path, mode: SlamMode, trial: int, env: JobEnv) -> RunInfo:
    """One (sequence, mode, trial) run: SLAM, label, store (a job of :meth:`DatasetBuilder.build`), its frames on
    a bar of their own."""
    progress = env.progress
    task = progress.add_task(run_name(sequence.name, mode.value, trial), total=None)

    def on_event(event) -> None:
        if isinstance(event, SessionStarted):
            progress.update(task, total=event.frame_count)
        elif isinstance(event, FrameTracked):
            progress.update(task, completed=event.frame_index + 1)

    try:
        return builder.with_config_dir(env.config_dir)._run(sequence, mode, trial, on_event)
    finally:
        progress.remove_task(task)
