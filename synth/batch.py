"""Render many sequences: every environment × motion × seed, one TUM folder each.

Folder names are ``<environment>__<motion>__s<seed>`` (``real:`` written as ``real-``), so that a batch can be
resumed: a folder whose ``metadata.json`` exists is complete (it is written last) and is skipped, unless the
preset it records differs from the preset of configs/synth.toml (the preset was retuned since) or was seen through
another camera model than the batch draws for it: such a folder is rendered again.

A batch may draw a camera model per sequence (:class:`CameraDraw`): every environment is then seen through
several cameras, so that a model trained on the batch meets the faults of real cameras in every room.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from synth.config import SynthConfig
from synth.sequence import REAL_PREFIX, SequenceSpec, camera_record, preset_record, render_sequence
from synth.trajectories import SCAN_GROUP, TABLE2_GROUPS

ALL = "all"
REAL = "real"
# The stream that deals the scan group's cameras (CameraDraw.cameras).
_SCAN_DEAL = 0x5CA7


def expand_environments(names: list[str], config: SynthConfig) -> list[str]:
    """``all`` → every preset; other names are checked against the presets."""
    if names == [ALL]:
        return [p.name for p in config.presets]
    return [config.preset(n).name for n in names]


def expand_motions(names: list[str], config: SynthConfig) -> list[str]:
    """``all`` → the three Table 2 groups, every real trajectory and the scan group (added last, so that the
    motions that came before keep their places: their seeds and cameras); ``real`` → every real trajectory."""
    out: list[str] = []
    for name in names:
        if name == ALL:
            out += list(TABLE2_GROUPS) + [REAL_PREFIX + r.name for r in config.real_trajectories] + [SCAN_GROUP]
        elif name == REAL:
            out += [REAL_PREFIX + r.name for r in config.real_trajectories]
        else:
            out.append(name)
    return out


def sequence_seed(batch_seed: int, environment: str, motion: str, config: SynthConfig) -> int:
    """The render seed of one sequence of a batch: from the batch seed and the environment's and motion's places
    in the config (preset order; the Table 2 groups, the real trajectories, then the scan group), never their
    places in the request, so that a folder name stands for the same frames in every batch that renders it."""
    environments = expand_environments([ALL], config)
    motions = expand_motions([ALL], config)
    return batch_seed * 1000 + environments.index(environment) * 37 + motions.index(motion)


def sequence_folder_name(spec: SequenceSpec) -> str:
    return f"{spec.environment}__{spec.motion.replace(REAL_PREFIX, 'real-')}__s{spec.seed}"


@dataclass(frozen=True)
class BatchResult:
    rendered: list[Path]
    skipped: list[Path]
    frames: int
    seconds: float

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def _rendered_with_current_preset(folder: Path, environment: str, config: SynthConfig) -> bool:
    """True when ``folder`` holds a complete render whose recorded preset and camera model are the configured
    ones (a camera model retuned since renders the folder again, as a retuned preset does)."""
    try:
        recorded = json.loads((folder / "metadata.json").read_text())
    except (OSError, ValueError):
        return False
    preset = config.preset(environment)
    model = config.camera_model(preset.camera_model)
    return recorded.get("preset") == preset_record(preset, model) and recorded.get("camera_model") == camera_record(
        model
    )


@dataclass(frozen=True)
class CameraDraw:
    """The camera models a batch renders through (names of ``[[camera_models]]`` in configs/synth.toml) and their
    weights. No models: every preset is rendered through its own ``camera_model``."""

    models: tuple[str, ...]
    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.models) != len(self.weights):
            raise ValueError(f"{len(self.models)} camera models but {len(self.weights)} weights")
        if any(w <= 0 for w in self.weights):
            raise ValueError(f"camera weights must be positive, got {list(self.weights)}")
        if len(set(self.models)) != len(self.models):
            raise ValueError(f"a camera model is listed twice: {list(self.models)}")

    def cameras(self, batch_seed: int, environment: str, config: SynthConfig) -> dict[str, str]:
        """The camera model of each motion of ``environment`` for ``batch_seed``.

        The motions of one environment (every configured motion, in config order, whatever a batch asks for, so
        that a sequence's camera does not depend on the request) draw their models weighted and without
        replacement, starting again once every model is drawn: an environment is seen through as many cameras as
        it has motions, while there are models enough. The scan group, added after the others, is dealt its
        models round the environments instead (preset order, the models in the order of one weighted draw without
        replacement for the batch seed), so that every model scans in some rooms and adding it changed no earlier
        camera."""
        for name in self.models:
            config.camera_model(name)  # refuse an unknown model by name
        motions = [m for m in expand_motions([ALL], config) if m != SCAN_GROUP]
        place = expand_environments([ALL], config).index(environment)
        rng = np.random.default_rng([batch_seed, place])
        p = np.asarray(self.weights) / sum(self.weights)
        drawn: list[str] = []
        while len(drawn) < len(motions):
            count = min(len(self.models), len(motions) - len(drawn))
            drawn += [self.models[i] for i in rng.choice(len(self.models), size=count, replace=False, p=p)]
        dealt = np.random.default_rng([batch_seed, _SCAN_DEAL]).choice(
            len(self.models), size=len(self.models), replace=False, p=p
        )
        return dict(zip(motions, drawn)) | {SCAN_GROUP: self.models[dealt[place % len(self.models)]]}


def plan_batch(
    template: SequenceSpec,
    environments: list[str],
    motions: list[str],
    seeds: list[int],
    config: SynthConfig,
    root: Path,
    cameras: CameraDraw | None = None,
) -> tuple[list[tuple[SequenceSpec, Path, SynthConfig]], list[Path]]:
    """What a batch renders under ``root``: (spec, folder, the config that renders it: its camera model drawn) of
    every sequence to render, in batch order, and the folders already rendered as planned (skipped)."""
    todo, skipped = [], []
    for seed in seeds:
        for env in environments:
            drawn = cameras.cameras(seed, env, config) if cameras is not None and cameras.models else {}
            for motion in motions:
                spec = replace(template, environment=env, motion=motion, seed=sequence_seed(seed, env, motion, config))
                folder = root / sequence_folder_name(replace(spec, seed=seed))
                seen = config.seen_through(env, config.camera_model(drawn[motion])) if motion in drawn else config
                if _rendered_with_current_preset(folder, env, seen):
                    skipped.append(folder)
                else:
                    todo.append((spec, folder, seen))
    return todo, skipped


def render_into(
    spec: SequenceSpec, config: SynthConfig, folder: Path, processes: int | None = None, progress=None
) -> int:
    """Render one sequence of a batch into ``folder`` (whatever an unfinished or outdated render left there is
    removed first); returns its frame count."""
    shutil.rmtree(folder, ignore_errors=True)  # unfinished, or rendered with an older preset
    return len(render_sequence(spec, config, folder, processes, progress=progress))


def render_batch(
    template: SequenceSpec,
    environments: list[str],
    motions: list[str],
    seeds: list[int],
    config: SynthConfig,
    root: Path,
    processes: int | None = None,
    cameras: CameraDraw | None = None,
) -> BatchResult:
    """Render environments × motions × seeds under ``root`` (``template`` gives length, size, lens, blur), each
    sequence through its preset's camera model or, with ``cameras``, the one drawn for it.

    Each sequence gets its own seed (:func:`sequence_seed`), so that two environments rendered with the same
    batch seed still get different trajectories.
    """
    start = time.perf_counter()
    todo, skipped = plan_batch(template, environments, motions, seeds, config, root, cameras)
    frames = sum(render_into(spec, seen, folder, processes) for spec, folder, seen in todo)
    return BatchResult([folder for _, folder, _ in todo], skipped, frames, time.perf_counter() - start)
