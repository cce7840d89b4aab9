"""The dataset build's camera draw: every environment seen through several camera models, the same sequence
always through the same one, a render through another camera rendered again."""

import json

import pytest

from estimator.dataset.build import plan_from_config
from estimator.dataset.config import load_dataset_config
from seesys.core.errors import ConfigError
from seesys.io.config import write_config_dir
from synth.batch import CameraDraw, expand_environments, plan_batch, sequence_folder_name
from synth.config import load_synth_config
from synth.sequence import SequenceSpec, camera_record, preset_record

TEMPLATE = SequenceSpec("", "", 0, 30, 160, 120)


def test_every_environment_draws_as_many_cameras_as_it_has_motions_while_there_are_models():
    synth = load_synth_config()
    draw = CameraDraw(("ideal", "d435"), (1.0, 1.0))
    for seed in (0, 1):
        for env in expand_environments(["all"], synth):
            cameras = draw.cameras(seed, env, synth)
            assert set(cameras) == {"patrol", "aiming", "rapid", "scan"} | {m for m in cameras if m.startswith("real:")}
            assert set(cameras.values()) == {"ideal", "d435"}, (env, cameras)
    assert draw.cameras(0, "office", synth) == draw.cameras(0, "office", synth)
    seeds = [draw.cameras(s, "office", synth) for s in range(8)]
    assert len({tuple(c.values()) for c in seeds}) > 1  # the batch seed changes the draw


# The default build's draw for batch seed 0 (patrol, aiming, rapid), as the builds of docs/v4-build and docs/v5-build
# rendered them: the scan group, added later, must not change them.
BUILT_SEED_0 = {
    "office": ("d435_unaligned", "d435", "ideal"),
    "living_room": ("kinect_v1", "d435_unaligned", "ideal"),
    "hall": ("ideal", "d435", "d435_unaligned"),
    "lab": ("kinect_v1", "d435", "ideal"),
    "storage": ("kinect_v1", "ideal", "d435"),
    "corridor": ("d435", "d435_unaligned", "ideal"),
    "gallery": ("d435", "ideal", "d435_unaligned"),
    "basement": ("ideal", "kinect_v1", "d435"),
    "studio": ("kinect_v1", "ideal", "d435"),
    "workshop": ("d435_unaligned", "kinect_v1", "ideal"),
}


def test_the_scan_group_is_dealt_every_camera_and_leaves_the_built_sequences_cameras_as_they_were():
    synth = load_synth_config()
    config = load_dataset_config()
    draw = CameraDraw(config.cameras.models, config.cameras.weights)
    environments = expand_environments(["all"], synth)
    assert set(BUILT_SEED_0) == set(environments)
    cameras = {env: draw.cameras(0, env, synth) for env in environments}
    assert {env: (c["patrol"], c["aiming"], c["rapid"]) for env, c in cameras.items()} == BUILT_SEED_0
    for seed in (0, 1, 2):
        scans = [draw.cameras(seed, env, synth)["scan"] for env in environments]
        # Dealt round the ten rooms: every one of the four models scans in two or three of them.
        assert sorted(scans.count(m) for m in config.cameras.models) == [2, 2, 3, 3], scans


def test_weights_set_how_often_a_camera_is_drawn():
    synth = load_synth_config()
    heavy = CameraDraw(("ideal", "d435"), (1.0, 20.0))
    firsts = [heavy.cameras(s, "lab", synth)["patrol"] for s in range(60)]
    assert firsts.count("d435") > 45  # first draw: p = 20/21


def test_bad_draws_are_refused_by_name(tmp_path):
    synth = load_synth_config()
    with pytest.raises(ConfigError, match="unknown camera model 'kinect_v9'"):
        CameraDraw(("ideal", "kinect_v9"), (1.0, 1.0)).cameras(0, "lab", synth)
    with pytest.raises(ValueError, match="2 camera models but 1 weights"):
        CameraDraw(("ideal", "d435"), (1.0,))
    with pytest.raises(ConfigError, match=r"cameras.*weights must be positive"):
        load_dataset_config(write_config_dir(tmp_path, {"weights": [1.0, 0.0, 1.0, 1.0]}))
    with pytest.raises(ConfigError, match="unknown camera model 'kinect_v9'"):
        plan_from_config(load_dataset_config(), synth, TEMPLATE, ["lab"], ["patrol"], [0], cameras=["kinect_v9"])
    # Camera normalisation puts every camera's PSD on the reference camera's grid: sizes may mix.
    assert plan_from_config(load_dataset_config(), synth, TEMPLATE, cameras=["ideal", "phone"]).cameras.models == (
        "ideal",
        "phone",
    )


def test_the_plan_renders_each_sequence_through_its_drawn_camera_and_again_when_it_was_seen_through_another(tmp_path):
    synth = load_synth_config()
    draw = CameraDraw(("ideal", "d435"), (1.0, 1.0))
    todo, skipped = plan_batch(TEMPLATE, ["lab"], ["patrol", "aiming", "rapid"], [0], synth, tmp_path, draw)
    assert skipped == [] and len(todo) == 3
    drawn = draw.cameras(0, "lab", synth)
    for spec, folder, seen in todo:
        assert seen.preset("lab").camera_model == drawn[spec.motion]
        assert folder.name == sequence_folder_name(SequenceSpec("lab", spec.motion, 0))
    # A complete render of the patrol sequence through its drawn camera is kept; through the other, redone.
    spec, folder, seen = todo[0]
    folder.mkdir()
    preset = seen.preset("lab")
    model = seen.camera_model(preset.camera_model)
    (folder / "metadata.json").write_text(
        json.dumps({"preset": preset_record(preset, model), "camera_model": camera_record(model)})
    )
    todo, skipped = plan_batch(TEMPLATE, ["lab"], ["patrol", "aiming", "rapid"], [0], synth, tmp_path, draw)
    assert skipped == [folder] and len(todo) == 2
    other = "ideal" if drawn[spec.motion] == "d435" else "d435"
    todo, skipped = plan_batch(TEMPLATE, ["lab"], ["patrol"], [0], synth, tmp_path, CameraDraw((other,), (1.0,)))
    assert skipped == [] and todo[0][1] == folder


def test_the_default_build_draws_the_configured_cameras_and_preset_means_each_presets_own():
    synth, config = load_synth_config(), load_dataset_config()
    plan = plan_from_config(config, synth, TEMPLATE)
    assert plan.cameras == config.cameras and len(plan.cameras.models) >= 2
    assert plan_from_config(config, synth, TEMPLATE, cameras=[]).cameras is None


def test_evaluation_judges_each_held_out_camera_as_a_set_of_its_own():
    import pandas as pd

    from estimator.dataset.splits import HELDOUT_ENVIRONMENTS, TEST_TRAJECTORIES, heldout_camera_set, set_indices

    meta = pd.DataFrame(
        {
            "run": list("abcdef"),
            "environment": ["lab", "lab", "hall", "hall", "lab", "hall"],
            "camera_model": ["ideal", "kinect_v1", "ideal", "kinect_v1", "d435", "d435"],
        }
    )
    runs = meta.run.to_numpy()
    sets = set_indices(meta, ["hall"], ["kinect_v1"])
    assert {name: list(runs[rows]) for name, rows in sets.items()} == {
        TEST_TRAJECTORIES: ["a", "e"],
        HELDOUT_ENVIRONMENTS: ["c", "f"],
        heldout_camera_set("kinect_v1"): ["b", "d"],
    }
    # A round that holds out no room (splits made with --heldout-per-round 0) has no held-out set to judge.
    assert {name: list(runs[rows]) for name, rows in set_indices(meta, [], []).items()} == {
        TEST_TRAJECTORIES: list("abcdef")
    }
