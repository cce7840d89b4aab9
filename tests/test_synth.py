"""The synthetic renderer: scenes, exact depth, camera effects, trajectories, TUM output, determinism, CLI.
Sequences here are tiny (64×48, a few frames) so that the file runs in seconds."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from testkit.renders import depths, grays, png_bytes, with_camera

from synth.batch import render_batch
from synth.camera_effects import LensDistortion
from synth.config import load_synth_config
from synth.environments import build_scene
from synth.real_camera import auto_exposure_response, depth_noise, rolling_shutter
from synth.renderer import RayGrid, render
from synth.sequence import SequenceSpec, plan_sequence, render_sequence
from synth.textures import make_tile
from synth.trajectories import (
    SCAN_WALL_MARGIN_M,
    TABLE2_GROUPS,
    TrajectoryError,
    generate_motion,
    generate_scan,
    load_euroc,
    load_tum,
    place_real,
)
from synth.wall_objects import place_wall_objects


@pytest.fixture(scope="module")
def config():
    return load_synth_config()


def test_at_least_nine_presets_that_differ(config):
    assert len(config.presets) >= 9
    for field in ("room_m", "light", "falloff_m", "texture_density", "texture_contrast", "texture_scale_m", "boxes"):
        assert len({getattr(p, field) for p in config.presets}) >= 4, field
    assert any(p.poor_walls > 0 for p in config.presets)


def test_bare_tiles_carry_sparse_fixtures_without_changing_the_scene_stream():
    """A bare tile is smooth paint plus the fixtures asked for, each a patch well above the paint's variation;
    drawing them takes nothing from the scene's generator, so whatever is drawn after the bare tiles stays the
    same."""
    blank_rng, fixed_rng = np.random.default_rng(5), np.random.default_rng(5)
    blank = make_tile(blank_rng, 256, 0, 0.5, 0.5, True)
    fixed = make_tile(fixed_rng, 256, 12, 0.5, 0.5, True)
    assert blank_rng.uniform() == fixed_rng.uniform()
    # Bare paint stays within 0.1 x contrast of the albedo (0.08 plus the cubic overshoot); fixtures reach 0.5 x.
    assert np.abs(blank - 0.5).max() < 0.1 * 0.5
    marked = np.abs(fixed - blank) > 0.05
    assert 0.002 < marked.mean() < 0.3
    labels = cv2.connectedComponents(marked.astype(np.uint8))[0] - 1
    assert 4 <= labels <= 3 * 12


def test_depth_is_exact_z_of_the_wall_ahead(config):
    """Camera 1 m in front of the room centre, looking at the +x wall with a 20° yaw: depth of every wall pixel
    is the z-distance to the plane x = W/2."""
    scene = build_scene(config.preset("office"), 3, config.sensor)
    empty = scene.without_boxes_near(np.array([[0.0, 0.0, 1.0]]), 100.0)
    assert len(empty.boxes) == 0 and len(empty.faces) == 6
    camera = config.camera.scaled(64, 48)
    grid = RayGrid.for_camera(camera)
    forward = np.array([np.cos(0.35), np.sin(0.35), 0.0])
    right = np.cross(forward, [0, 0, 1.0])
    rotation = np.column_stack([right, np.cross(forward, right), forward])
    centre = np.array([1.0, 0.0, 1.4])
    out = render(empty, rotation, centre, grid)
    width = empty.room[0]
    # Rays (x, y, 1) in the camera frame; the wall x = W/2 is hit at z = (W/2 − cx) / (R · ray)_x.
    ray_x = rotation[0, 0] * grid.x + rotation[0, 1] * grid.y + rotation[0, 2]
    expected = (width / 2 - centre[0]) / ray_x
    on_wall = (out.depth > 0) & np.isclose(out.depth, expected, rtol=1e-4)
    assert on_wall[20:28, 28:36].all()
    assert (out.radiance > 0).all()


def test_generated_motion_groups_stay_in_the_room_and_differ_in_speed(config):
    scene = build_scene(config.preset("living_room"), 0, config.sensor)
    lo, hi = scene.room_bounds()
    speeds = {group: [] for group in TABLE2_GROUPS}
    for seed in range(3):
        for group in TABLE2_GROUPS:
            traj = generate_motion(
                group, getattr(config.motion, group), lo, hi, config.trajectory, 20.0, np.random.default_rng(seed)
            )
            margin = config.trajectory.wall_margin_m
            assert (traj.positions >= lo + margin - 1e-9).all() and (traj.positions <= hi - margin + 1e-9).all()
            rel = traj.rotations[:-1].inv() * traj.rotations[1:]
            ang = np.degrees(rel.magnitude()) / np.diff(traj.times)
            lin = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1) / np.diff(traj.times)
            speeds[group].append((np.mean(ang), np.mean(lin)))
    mean = {group: np.mean(values, axis=0) for group, values in speeds.items()}
    assert mean["rapid"][0] > mean["patrol"][0] and mean["rapid"][0] > mean["aiming"][0]
    assert mean["aiming"][1] < mean["patrol"][1]
    # Handheld range (docs/synthetic-data.md): 25-60 deg/s for the bulk, faster for rapid motion.
    assert 20 < mean["patrol"][0] < 60 and 20 < mean["aiming"][0] < 60 and mean["rapid"][0] < 100


def test_the_scan_group_sweeps_each_box_at_close_range_looking_at_it(config):
    """While sweeping, the camera stands within the configured distance of a box's centre line (give or take the
    hand's shake) and looks at its top (within the look-around, shake and sudden turns); it visits box after box."""
    scan = config.scan
    for env, seed in (("office", 0), ("studio", 1), ("hall", 2), ("storage", 3), ("corridor", 4)):
        scene = build_scene(config.preset(env), seed, config.sensor)
        lo, hi = scene.room_bounds()
        rng = np.random.default_rng(seed)
        objects = place_wall_objects(
            scene.room, 10, scan.object_size_m, scan.object_height_m, scan.wall_gap_m, rng, scan.min_spacing_m
        )
        assert len(objects) >= 4
        traj = generate_scan(objects, config.motion.scan, scan, lo, hi, 40.0, rng)
        assert traj.duration >= 40.0
        inside = (traj.positions >= lo + SCAN_WALL_MARGIN_M - 1e-9) & (traj.positions <= hi - SCAN_WALL_MARGIN_M + 1e-9)
        assert inside.all()
        axis = traj.rotations.apply([0.0, 0.0, 1.0])  # the optical axis, z of R_world_camera
        seconds = []
        for obj in objects:
            horizontal = np.linalg.norm(traj.positions[:, :2] - obj.aim[:2], axis=1)
            inside_box = np.all((traj.positions > obj.box.lo - 0.05) & (traj.positions < obj.box.hi + 0.05), axis=1)
            assert not inside_box.any()  # the camera never passes through a box
            to_aim = obj.aim - traj.positions
            off = np.degrees(np.arccos(np.clip(np.sum(axis * to_aim, axis=1) / np.linalg.norm(to_aim, axis=1), -1, 1)))
            scanning = (horizontal < scan.distance_m[1] + 0.05) & (off < 15.0)
            seconds.append(scanning.sum() * (traj.times[1] - traj.times[0]))
        # Box after box, in order: each box scanned is viewed from the scan range, looking at it, for a second or more.
        scanned = [s >= 1.0 for s in seconds]
        assert sum(scanned) >= 3 and scanned[: sum(scanned)] == [True] * sum(scanned), seconds
    with pytest.raises(TrajectoryError, match="at least 2 objects"):
        generate_scan(objects[:1], config.motion.scan, scan, lo, hi, 5.0, rng)


def test_a_scan_sequence_has_its_boxes_and_no_clutter_on_its_path(config):
    plan = plan_sequence(SequenceSpec("lab", "scan", 3, 900, 64, 48), config)  # planned, not rendered
    assert plan.motion_group == "scan" and plan.trajectory_name == "scan_3"
    bare = build_scene(config.preset("lab"), 3, config.sensor)
    is_added = [not any(np.array_equal(b.lo, c.lo) for c in bare.boxes) for b in plan.scene.boxes]
    added = [b for b, new in zip(plan.scene.boxes, is_added) if new]
    assert config.scan.objects[0] <= len(added) <= config.scan.objects[1]
    positions = plan.trajectory.positions
    for box, new in zip(plan.scene.boxes, is_added):  # every box but the scanned ones keeps the path clearance
        nearest = np.min(np.linalg.norm(np.clip(positions, box.lo, box.hi) - positions, axis=1))
        assert nearest > (0.15 if new else config.scan.path_clearance_m)
    # Close views: boxes come within the scan distance of the camera, as no other group's boxes do.
    centres = np.array([(b.lo[:2] + b.hi[:2]) / 2 for b in added])
    gaps = np.linalg.norm(plan.trajectory.positions[:, None, :2] - centres[None], axis=2).min(axis=0)
    assert (gaps < config.scan.distance_m[1] + 0.05).sum() >= 3


def test_real_trajectories_are_placed_inside_the_smallest_room(config):
    scene = build_scene(config.preset("studio"), 0, config.sensor)
    lo, hi = scene.room_bounds()
    margin = config.trajectory.wall_margin_m
    for real in config.real_trajectories:
        loader = load_tum if real.format == "tum" else load_euroc
        full = loader(config.trajectory_path(real))
        placed = place_real(full.window(0.0, 30.0), lo, hi, config.trajectory, np.random.default_rng(1))
        assert (placed.positions >= lo + margin - 1e-9).all() and (placed.positions <= hi - margin + 1e-9).all()
        # Only turned about the vertical: the camera's tilt (z of its viewing direction) is kept.
        np.testing.assert_allclose(
            placed.rotations.as_matrix()[:, 2, 2], full.window(0.0, 30.0).rotations.as_matrix()[:, 2, 2], atol=1e-9
        )
        # Placement is a similarity: relative rotations are kept.
        rel_full = (full.rotations[0].inv() * full.rotations[5]).magnitude()
        rel_placed = (placed.rotations[0].inv() * placed.rotations[5]).magnitude()
        assert rel_placed == pytest.approx(rel_full, abs=1e-9)


def test_lens_distortion_keeps_the_centre_and_bends_the_edges(config):
    lens = LensDistortion.for_lens(config.camera.lens)
    cy, cx = int(config.camera.lens.cy), int(config.camera.lens.cx)
    assert abs(lens.map_x[cy, cx] - cx) < 0.5 and abs(lens.map_y[cy, cx] - cy) < 0.5
    # Barrel distortion (k1 < 0): a corner pixel of the image shows a point farther out in the pinhole render.
    assert lens.map_x[0, 0] < 0 and lens.map_y[0, 0] < 0


def _tiny(motion: str, **kw) -> SequenceSpec:
    return SequenceSpec("lab", motion, 7, frames=6, width=64, height=48, **kw)


@pytest.mark.system
def test_sequence_is_deterministic_tum_layout_with_metadata(config, tmp_path):
    one = tmp_path / "one"
    two = tmp_path / "two"
    records = render_sequence(_tiny("rapid", distortion=True), config, one, processes=1, show_progress=False)
    render_sequence(_tiny("rapid", distortion=True), config, two, processes=2, show_progress=False)
    assert png_bytes(one) == png_bytes(two) and len(png_bytes(one)) == 12

    for name in (
        "rgb.txt",
        "depth.txt",
        "associations.txt",
        "groundtruth.txt",
        "calibration.yaml",
        "metadata.json",
        "render_log.csv",
    ):
        assert (one / name).is_file(), name
    assoc = [line.split() for line in (one / "associations.txt").read_text().splitlines()]
    assert len(assoc) == 6
    gray = cv2.imread(str(one / assoc[0][1]), cv2.IMREAD_UNCHANGED)
    depth = cv2.imread(str(one / assoc[0][3]), cv2.IMREAD_UNCHANGED)
    assert gray.dtype == np.uint8 and gray.shape == (48, 64)
    assert depth.dtype == np.uint16 and depth.shape == (48, 64) and depth.max() > 0
    gt = np.loadtxt(one / "groundtruth.txt")
    assert gt.shape == (6, 8) and np.allclose(np.diff(gt[:, 0]), 1 / 30, atol=2e-6)
    assert np.allclose(np.linalg.norm(gt[:, 4:], axis=1), 1.0, atol=1e-5)
    meta = json.loads((one / "metadata.json").read_text())
    assert meta["environment"] == "lab" and meta["motion_group"] == "rapid" and meta["seed"] == 7
    calibration = (one / "calibration.yaml").read_text()
    assert "width: 64" in calibration and "fx: 52.5" in calibration and "-0.12" in calibration
    assert all(config.sensor.exposure_min_ms <= r.exposure_ms <= config.sensor.exposure_max_ms for r in records)


@pytest.mark.system
def test_a_batch_folder_is_the_same_sequence_whatever_else_the_batch_renders(config, tmp_path):
    """``basement__aiming__s0`` rendered alone and as part of a wider batch is the same sequence (same seed,
    same frames): extending a dataset with more environments or motions must not change what a name means."""
    template = _tiny("aiming")
    render_batch(template, ["basement"], ["aiming"], [0], config, tmp_path / "alone", processes=1)
    render_batch(template, ["lab", "basement"], ["rapid", "aiming"], [0], config, tmp_path / "wide", processes=1)
    alone, wide = tmp_path / "alone" / "basement__aiming__s0", tmp_path / "wide" / "basement__aiming__s0"
    assert (
        json.loads((alone / "metadata.json").read_text())["seed"]
        == json.loads((wide / "metadata.json").read_text())["seed"]
    )
    assert png_bytes(alone) == png_bytes(wide)
    lab_rapid = json.loads((tmp_path / "wide" / "lab__rapid__s0" / "metadata.json").read_text())
    assert lab_rapid["seed"] != json.loads((wide / "metadata.json").read_text())["seed"]


def test_motion_blur_comes_from_the_true_motion(config, tmp_path):
    """Same frames with and without blur: blur smooths the image (lower Laplacian variance) by an amount that
    the logged streak length accounts for."""
    blurred = render_sequence(_tiny("rapid"), config, tmp_path / "b", processes=1, show_progress=False)
    render_sequence(_tiny("rapid", blur=False), config, tmp_path / "s", processes=1, show_progress=False)
    assert max(r.blur_p99_px for r in blurred) > 0.5

    def lapvar(folder: Path) -> float:
        return float(
            np.mean(
                [cv2.Laplacian(cv2.imread(str(p), 0), cv2.CV_64F).var() for p in sorted((folder / "rgb").glob("*.png"))]
            )
        )

    assert lapvar(tmp_path / "b") < lapvar(tmp_path / "s")


@pytest.mark.system
def test_cli_render_diversity_and_errors(tmp_path):
    seesys = [sys.executable, "-m", "seesys", "synth"]
    out = subprocess.run(
        seesys
        + [
            "render",
            "--env",
            "gallery",
            "--motion",
            "real:tum_fr1_xyz",
            "--seed",
            "1",
            "--out",
            str(tmp_path / "seqs" / "a"),
            "--frames",
            "5",
            "--size",
            "64x48",
            "--processes",
            "1",
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "frames/s" in out.stdout
    meta = json.loads((tmp_path / "seqs" / "a" / "metadata.json").read_text())
    assert meta["trajectory"] == "tum_fr1_xyz" and meta["motion_group"] == "aiming"

    out = subprocess.run(
        seesys + ["diversity", str(tmp_path / "seqs"), "--out", str(tmp_path / "rep"), "--stride", "1"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "rep" / "diversity.png").stat().st_size > 1000
    assert "| gallery | 5 |" in (tmp_path / "rep" / "diversity.md").read_text()

    out = subprocess.run(
        seesys + ["render", "--env", "moon", "--motion", "patrol", "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "unknown environment preset 'moon'" in out.stderr
    out = subprocess.run(
        seesys + ["render", "--env", "lab", "--motion", "jumping", "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "unknown motion 'jumping'" in out.stderr


@pytest.mark.system
def test_camera_models_off_render_as_before_and_on_are_deterministic(config, tmp_path):
    """A model with every effect off gives the same bytes as the ideal camera, and its metadata does not list it;
    the D435-like model (every effect on) renders the same bytes on 1 and on 2 processes."""
    render_sequence(_tiny("rapid"), config, tmp_path / "ideal", processes=1, show_progress=False)
    render_sequence(_tiny("rapid"), with_camera(config), tmp_path / "off", processes=1, show_progress=False)
    assert png_bytes(tmp_path / "ideal") == png_bytes(tmp_path / "off")
    assert (tmp_path / "ideal" / "metadata.json").read_text() == (tmp_path / "off" / "metadata.json").read_text()
    d435 = dataclasses.asdict(config.camera_model("d435"))
    del d435["name"]
    real = with_camera(config, **d435)
    render_sequence(_tiny("rapid"), real, tmp_path / "one", processes=1, show_progress=False)
    render_sequence(_tiny("rapid"), real, tmp_path / "two", processes=2, show_progress=False)
    assert png_bytes(tmp_path / "one") == png_bytes(tmp_path / "two") != png_bytes(tmp_path / "ideal")
    assert json.loads((tmp_path / "one" / "metadata.json").read_text())["camera_model"]["rolling_shutter_s"] == 0.02


def test_misregistered_depth_is_shifted_by_the_configured_pixels(config, tmp_path):
    render_sequence(_tiny("rapid"), config, tmp_path / "ideal", processes=1, show_progress=False)
    render_sequence(
        _tiny("rapid"),
        with_camera(config, depth_misregistration_px=(3.0, 2.0)),
        tmp_path / "shifted",
        processes=1,
        show_progress=False,
    )
    for ideal, shifted in zip(depths(tmp_path / "ideal"), depths(tmp_path / "shifted")):
        assert np.array_equal(shifted[2:, 3:], ideal[:-2, :-3])  # every depth edge moved by (3, 2) px
        assert not shifted[:2].any() and not shifted[:, :3].any()  # uncovered pixels have no depth
    assert [g.tobytes() for g in grays(tmp_path / "ideal")] == [g.tobytes() for g in grays(tmp_path / "shifted")]


def test_unregistered_and_late_depth_is_the_depth_cameras_own_view(config, tmp_path):
    """Depth from a camera 5 cm to the side, captured 20 ms late: each depth image is the exact depth at that
    pose, not the colour camera's."""
    spec = _tiny("rapid", blur=False)
    late = with_camera(config, depth_offset_m=(0.05, 0.0, 0.0), depth_delay_s=0.02)
    render_sequence(spec, late, tmp_path / "late", processes=1, show_progress=False)
    render_sequence(spec, config, tmp_path / "ideal", processes=1, show_progress=False)
    plan = plan_sequence(spec, late)
    grid = RayGrid.for_camera(plan.camera)
    positions, rotations = plan.trajectory.interpolate(plan.frame_times + 0.02)
    late_depths, ideal = depths(tmp_path / "late"), depths(tmp_path / "ideal")
    for k, (p, r) in enumerate(zip(positions, rotations.as_matrix())):
        expected = render(plan.scene, r, p + r @ np.array([0.05, 0.0, 0.0]), grid).depth
        assert np.array_equal(late_depths[k], np.clip(np.rint(expected * config.camera.depth_factor), 0, 65535))
        assert np.abs(late_depths[k].astype(float) - ideal[k]).mean() > 10  # > 2 mm on average: another view
    assert [g.tobytes() for g in grays(tmp_path / "late")] == [g.tobytes() for g in grays(tmp_path / "ideal")]


def test_rolling_shutter_shears_an_edge_by_the_motion_during_readout(config):
    """A vertical edge, image motion −4 px at the first row's time and +4 px at the last row's: the edge is read
    4 px left at the top and 4 px right at the bottom, linearly in between."""
    grid = RayGrid.for_camera(config.camera.scaled(64, 48))
    image = np.zeros((48, 64), np.float32)
    image[:, 32:] = 1.0
    first, last = np.zeros((48, 64, 2), np.float32), np.zeros((48, 64, 2), np.float32)
    first[..., 0], last[..., 0] = -4.0, 4.0
    sheared = rolling_shutter(image, grid, first, last)
    edge = (sheared > 0.5).argmax(axis=1)  # first bright column of each row
    expected = np.rint(32 - 4 + 8 * np.arange(48) / 47 + 1e-6)
    assert np.abs(edge - expected).max() <= 1 and edge[0] == 28 and edge[-1] == 36


def test_auto_exposure_lags_and_overshoots_a_light_step():
    """A step of the exposure target at frame 30: the loop (0.3 s, damping 0.5) is still far from it one frame
    later, overshoots by exp(−πζ/√(1−ζ²)) = 16 %, and settles; critically damped it never overshoots."""
    target = np.r_[np.zeros(30), np.full(120, np.log(2.0))]
    lagged = auto_exposure_response(target, 30.0, 0.3, 0.5)
    step = np.log(2.0)
    assert lagged[29] == 0.0 and lagged[30] < 0.05 * step
    assert (lagged.max() - step) / step == pytest.approx(np.exp(-np.pi * 0.5 / np.sqrt(0.75)), abs=0.02)
    assert abs(lagged[-1] - step) < 0.01 * step
    damped = auto_exposure_response(target, 30.0, 0.3, 1.0)
    assert damped.max() <= step + 1e-9 and damped[45] < step
    np.testing.assert_array_equal(auto_exposure_response(target, 30.0, 0.0, 0.5), target)


def test_auto_exposure_lag_shows_in_the_exposure_schedule(config):
    spec = SequenceSpec("lab", "aiming", 7, frames=300, width=64, height=48)
    ideal = plan_sequence(spec, config)
    lagged = plan_sequence(spec, with_camera(config, auto_exposure_time_constant_s=0.5, auto_exposure_damping=0.5))
    assert lagged.exposure_s[0] == pytest.approx(ideal.exposure_s[0]) and np.array_equal(lagged.light, ideal.light)
    # The exposure trails the light: it is best matched by the ideal schedule some frames earlier.
    errors = [np.abs(lagged.exposure_s[30 + d :] - ideal.exposure_s[30 : 300 - d]).mean() for d in range(0, 30)]
    assert int(np.argmin(errors)) >= 5


def test_depth_noise_grows_with_the_square_of_depth():
    rng = np.random.default_rng(0)
    flat = np.concatenate(
        [np.full((100, 100), 1.0, np.float32), np.full((100, 100), 2.0, np.float32), np.zeros((10, 100), np.float32)]
    )
    noisy = depth_noise(flat, 0.0042, rng)
    assert np.std(noisy[:100]) == pytest.approx(0.0042, rel=0.05)
    assert np.std(noisy[100:200]) == pytest.approx(4 * 0.0042, rel=0.05)
    assert not noisy[200:].any()  # no depth stays no depth
    np.testing.assert_array_equal(noisy, depth_noise(flat, 0.0042, np.random.default_rng(0)))


def test_colour_noise_scale_scales_the_sensor_noise(config):
    spec = SequenceSpec("lab", "aiming", 7, frames=2, width=64, height=48)
    ideal = plan_sequence(spec, config).photometry
    noisy = plan_sequence(spec, with_camera(config, colour_noise_scale=2.0)).photometry
    flat = np.full((200, 200), 0.3, np.float32)
    sigma = [float(np.std(p.expose(flat, np.random.default_rng(1)).astype(float))) for p in (ideal, noisy)]
    assert sigma[1] / sigma[0] == pytest.approx(2.0, rel=0.1)


def test_a_resumed_batch_renders_again_only_what_a_retuned_preset_changes(config, tmp_path):
    template = _tiny("aiming")
    first = render_batch(template, ["lab", "basement"], ["aiming"], [0], config, tmp_path, processes=1)
    assert len(first.rendered) == 2
    lab = tmp_path / "lab__aiming__s0"
    before = png_bytes(lab)
    again = render_batch(template, ["lab", "basement"], ["aiming"], [0], config, tmp_path, processes=1)
    assert again.rendered == [] and len(again.skipped) == 2
    retuned = dataclasses.replace(
        config, presets=[dataclasses.replace(p, albedo=0.3) if p.name == "lab" else p for p in config.presets]
    )
    third = render_batch(template, ["lab", "basement"], ["aiming"], [0], retuned, tmp_path, processes=1)
    assert third.rendered == [lab] and third.skipped == [tmp_path / "basement__aiming__s0"]
    assert png_bytes(lab) != before and json.loads((lab / "metadata.json").read_text())["preset"]["albedo"] == 0.3
