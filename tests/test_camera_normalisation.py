"""Camera normalisation: the monitor's inputs of one scene through a 640×480 camera (the reference) and a 1280×720
camera of the same horizontal field of view are the same numbers; the reference camera's inputs are what they were
before camera normalisation, to the bit; and a model refuses windows made under another normalisation version."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from estimator.artefact.compatibility import ModelMismatch, check_normalisation
from seesys.core import camera_normalisation, rts_schema
from seesys.core.camera import Intrinsics
from seesys.core.camera_normalisation import CameraNormalisation, ReferenceCamera
from seesys.core.messages import stream_resolution
from seesys.core.psd import INLIER_LAYER, KEYPOINT_LAYER, MAP_POINT_LAYER, PsdGeometry, build_psd
from seesys.core.tracking_state import TrackingState
from slam_monitor.frame import Frame
from slam_monitor.image_features import image_features, keypoint_responses, reference_scale
from slam_monitor.monitor import FeatureExtractor, MonitorInput
from slam_monitor.monitor_config import load_monitor_config

CONFIG = load_monitor_config()
REFERENCE = CONFIG.reference_camera
SMALL = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
# The same lens on a 1280-pixel-wide sensor cut to 16:9: twice the focal length, the same horizontal field of view;
# its vertical view is the reference camera's rows 60-419.
WIDE = Intrinsics(1280, 720, 1050.0, 1050.0, 639.5, 359.5)
FINE = 4  # the scene is drawn on a grid of 4 x 4 cells per reference pixel


def test_the_reference_camera_is_the_ideal_camera_and_maps_to_itself():
    assert ReferenceCamera(640, 480, 525.0, 525.0, 319.5, 239.5) == REFERENCE
    same = CameraNormalisation(REFERENCE, SMALL)
    uv = np.array([[0.1, 0.2], [639.9, 479.4], [-30.3, 500.7]])
    assert same.identity and same.pixel_ratio == 1.0 and same.resampled_size() == (640, 480)
    assert np.array_equal(same.reference_px(uv), uv) and np.array_equal(same.resampled_px(uv), uv)
    wide = CameraNormalisation(REFERENCE, WIDE)
    assert not wide.identity and wide.pixel_ratio == 2.0 and wide.resampled_size() == (640, 360)
    # A direction seen at (u, v) by the wide camera is seen by the reference camera at its own pixel.
    assert np.allclose(wide.reference_px(np.array([[639.5, 359.5], [1279.5, 719.5]])), [[319.5, 239.5], [639.5, 419.5]])


def _scene(seed: int) -> np.ndarray:
    """A textured plane filling the reference camera's view, on the fine grid (intensity 0-255, float): blurred
    noise, with detail down to about a reference pixel."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(REFERENCE.height * FINE, REFERENCE.width * FINE)).astype(np.float32)
    texture = cv2.GaussianBlur(noise, (0, 0), sigmaX=FINE * 0.8)
    return np.clip(128 + 60 * texture / texture.std(), 0, 255)


def _render(scene: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """The 8-bit image of ``scene`` through ``intrinsics`` (one of the two test cameras): each pixel the mean of the
    fine cells it covers, as a sensor integrates its footprint."""
    block = round(FINE * REFERENCE.fx / intrinsics.fx)
    top = round((REFERENCE.cy + 0.5 - (intrinsics.cy + 0.5) * REFERENCE.fy / intrinsics.fy) * FINE)
    view = scene[top : top + intrinsics.height * block, : intrinsics.width * block]
    means = view.reshape(intrinsics.height, block, intrinsics.width, block).mean(axis=(1, 3))
    return np.rint(means).astype(np.uint8)


def _points(seed: int) -> np.ndarray:
    """World points in front of the camera (identity pose) that both cameras see."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.8, 6.0, 400)
    x, y = rng.uniform(-0.58, 0.58, 400) * z, rng.uniform(-0.32, 0.32, 400) * z
    return np.column_stack([x, y, z])


def _project(intrinsics: Intrinsics, points: np.ndarray) -> np.ndarray:
    uvw = points @ intrinsics.matrix().T
    return uvw[:, :2] / uvw[:, 2:]


def _extract(intrinsics: Intrinsics, gray: np.ndarray, points: np.ndarray, offset_ref_px: float):
    """The monitor's feature frame of one tracked frame: the camera at the origin, every point matched, each
    keypoint ``offset_ref_px`` reference pixels right of its point's projection."""
    keypoints = _project(intrinsics, points) + (offset_ref_px * intrinsics.fx / REFERENCE.fx, 0.0)
    pose = np.eye(4)
    item = MonitorInput(
        Frame(0, 0.0, gray, intrinsics), TrackingState.OK, pose, pose, pose, len(points), keypoints, points, False, 0
    )
    return FeatureExtractor(CONFIG).extract(item)


def test_the_same_scene_gives_the_same_normalised_inputs_at_640x480_and_1280x720():
    scene, points = _scene(1), _points(2)
    small, wide = _render(scene, SMALL), _render(scene, WIDE)
    a = _extract(SMALL, small, points, 1.0)
    b = _extract(WIDE, wide, points, 1.0)
    # The same grid, cells of the same angle: the keypoints, inliers and map points fall into the same cells.
    assert a.psd.shape == b.psd.shape == PsdGeometry(640, 480, CONFIG.psd.patch_px, CONFIG.psd.expansion).shape
    for layer in (INLIER_LAYER, MAP_POINT_LAYER):
        assert np.array_equal(a.psd[..., layer], b.psd[..., layer])
    occupied = a.psd[..., KEYPOINT_LAYER] > 0
    assert np.array_equal(occupied, b.psd[..., KEYPOINT_LAYER] > 0)
    # Keypoint responses on the image at the reference scale: the 8-bit roundings of the two renders (at most one
    # gray level apart after area averaging) move a FAST-circle contrast by about a level; unnormalised, the wide
    # camera's circle spans half the angle and its contrast is far lower.
    difference = np.abs(a.psd[..., KEYPOINT_LAYER].astype(int) - b.psd[..., KEYPOINT_LAYER])[occupied]
    assert np.median(difference) <= 1 and difference.max() <= 4
    raw = keypoint_responses(wide, _project(WIDE, points) + (2.0, 0.0))
    assert np.median(raw) < 0.85 * np.median(keypoint_responses(small, _project(SMALL, points) + (1.0, 0.0)))
    # The reprojection error: 1 reference pixel is 1 px at 640x480 and 2 px at 1280x720, 1 after normalisation
    # (a little less: a few points lie nearer another point's keypoint, the same ones through both cameras).
    error = rts_schema.index_of("local_mapping_visual_error")
    assert b.rts[error] == pytest.approx(a.rts[error], rel=1e-5) and a.rts[error] == pytest.approx(1.0, abs=0.02)
    # The Laplacian at the reference scale, compared over the same view (the wide camera sees rows 60-419 of the
    # small one). The two renders differ only by 8-bit rounding: independent errors of variance <= 2/12 level² per
    # pixel, whose Laplacian (weights 1, 1, 1, 1, -4) has variance <= 20 * 2/12 = 3.3 level² against the scene's
    # ~7,000 here, so the variances agree to well within 1 % (measured: 2e-5), and the normalised channel,
    # log1p(x) / 10, to within 1e-3. Without normalisation the wide camera's Laplacian variance is an eighth.
    laplacian = rts_schema.index_of("laplacian")
    same_view = image_features(small[60:420]).laplacian
    assert b.rts[laplacian] == pytest.approx(same_view, rel=0.01)
    assert image_features(wide).laplacian < 0.5 * same_view


def test_the_reference_camera_gives_the_inputs_it_gave_before_camera_normalisation():
    """What the monitor computed before camera normalisation: the Laplacian of the frame itself, the reprojection
    error in its pixels, the PSD of its own grid with responses on the frame itself."""
    scene, points = _scene(3), _points(4)
    gray = _render(scene, SMALL)
    got = _extract(SMALL, gray, points, 0.7)
    laplacian = stream_resolution(np.float32([image_features(gray).laplacian]))[0]  # the monitor's row's resolution
    assert got.rts[rts_schema.index_of("laplacian")] == laplacian
    keypoints = _project(SMALL, points) + (0.7, 0.0)
    before = build_psd(
        PsdGeometry(640, 480, CONFIG.psd.patch_px, CONFIG.psd.expansion),
        keypoints=keypoints,
        responses=keypoint_responses(gray, keypoints),
        inliers=np.ones(len(points), bool),
        map_points_uv=_project(SMALL, points),
        map_points_depth=points[:, 2],
        near_depth=CONFIG.psd.near_depth,
    )
    assert np.array_equal(got.psd, before)
    assert got.settings is None  # settings travel from the device's configs, not the extractor's


def test_a_model_refuses_windows_of_another_camera_normalisation_in_one_line_naming_both_versions():
    record = {"device": {"camera_normalisation": camera_normalisation.VERSION}}
    check_normalisation(record, pd.Series([1, 1, pd.NA]), "session s1")  # NA: a log that states none
    with pytest.raises(ModelMismatch) as refused:
        check_normalisation(record, pd.Series([0, 1]), "session s1")
    message = str(refused.value)
    assert "\n" not in message and "session s1: made under camera normalisation v0, the model takes v1" in message
    with pytest.raises(ModelMismatch, match="made under camera normalisation v1, the model takes v0"):
        check_normalisation({"device": {}}, [1], "session s2")  # a model made before it records none: v0


def test_the_shipped_model_refuses_a_session_logged_before_camera_normalisation(tmp_path):
    """A session whose rts.json states device settings without a camera normalisation version (logged before it:
    v0) is refused by the model in one line naming both versions; the same session stating v1 is served."""
    import dataclasses
    import json

    from testkit.deepsee import write_session

    from estimator.artefact.transforms import LabelTransform
    from estimator.deepsee.config import load_estimator_config
    from estimator.deepsee.data import DataError, session_windows
    from estimator.deepsee.predictors import load_predictor
    from seesys.io.core_settings import load_device_settings, load_window_config
    from seesys.io.resources import resolve
    from seesys.io.rts_log import RTS_JSON, schema_metadata

    session = write_session(tmp_path / "old", seed=5, frames=60)
    settings = load_device_settings("rgbd", 30.0)
    record = dataclasses.asdict(settings)
    del record["camera_normalisation"]
    (session / RTS_JSON).write_text(json.dumps({**schema_metadata(), "device_settings": record}))
    windows = load_window_config()
    transform = LabelTransform(load_estimator_config().label_transform.k)
    predictor = load_predictor(resolve("data/models/deepsee.onnx"), transform, 8, windows=windows)
    with pytest.raises(ModelMismatch) as refused:
        predictor.metres(session_windows(session, windows, labelled=False))
    assert "\n" not in str(refused.value)
    assert "windows of old: made under camera normalisation v0, the model takes v1" in str(refused.value)
    (session / RTS_JSON).write_text(json.dumps(schema_metadata(settings)))
    stated = session_windows(session, windows, labelled=False)
    assert set(stated.meta.camera_normalisation) == {1}
    with pytest.raises(DataError, match="another PSD grid"):  # accepted, then refused for its tiny test PSD
        predictor.metres(stated)


@pytest.mark.parametrize("environment", ["lab", "gallery"])
def test_a_render_at_640x480_and_1280x720_gives_the_same_normalised_image_statistics(environment):
    """The renderer's room seen from one pose through the 640x480 reference camera and a 1280x720 camera of the same
    horizontal field of view (no noise, no blur). The renderer picks each pixel's texture detail by its footprint
    (mip-mapping), so the two renders are close to, not exactly, area averages of one scene: over four presets their
    Laplacian variances over the same view agree to 0.1-2.3 % and their keypoint responses to 1-2.5 % in the median,
    against about half without normalisation. Allowed: 5 %, i.e. 0.005 of the normalised Laplacian (log1p / 10),
    a fourteenth of what the augmentation's smallest Laplacian gain (x 0.5) moves it."""
    import dataclasses

    from synth.config import load_synth_config
    from synth.environments import build_scene
    from synth.renderer import RayGrid, render

    synth = load_synth_config()
    preset = synth.preset(environment)
    scene = build_scene(preset, 3, synth.sensor)
    centre = np.array([preset.room_m[0] / 2, preset.room_m[1] / 2 - 0.5, 1.4])
    looking_along_y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # optical frame, world z up
    images = {}
    for intrinsics in (SMALL, WIDE):
        grid = RayGrid.for_camera(dataclasses.replace(synth.camera, lens=intrinsics))
        radiance = render(scene, looking_along_y, centre, grid).radiance
        images[intrinsics.width] = np.clip(np.rint(255 * synth.sensor.signal_scale * radiance), 0, 255).astype(np.uint8)
    small, wide = images[640], images[1280]
    wide_normalisation = CameraNormalisation(REFERENCE, WIDE)
    at_reference_scale = reference_scale(wide, wide_normalisation)
    same_view = image_features(small[60:420]).laplacian
    assert image_features(wide, at_reference_scale).laplacian == pytest.approx(same_view, rel=0.05)
    assert image_features(wide).laplacian < 0.6 * same_view
    corners = np.array([k.pt for k in cv2.FastFeatureDetector_create(20).detect(small[60:420])]) + (0.0, 60.0)
    assert len(corners) > 20
    seen_wide = (corners - (SMALL.cx, SMALL.cy)) * 2 + (WIDE.cx, WIDE.cy)  # the same directions
    reference = np.median(keypoint_responses(small, corners))
    normalised = keypoint_responses(at_reference_scale, wide_normalisation.resampled_px(seen_wide))
    assert np.median(normalised) == pytest.approx(reference, rel=0.05)
    assert np.median(keypoint_responses(wide, seen_wide)) < 0.7 * reference
