"""Bad inputs through the real command line: one-line error naming the problem, exit status 2, no traceback,
and session files that are consistent (every frame before the problem logged, session.json 'failed')."""

import shutil

import cv2
import pandas as pd
import pytest
from testkit.sample import REPO, SAMPLE, run_seesys

from seesys.core import session_layout
from seesys.core.camera import Intrinsics
from seesys.io import session_files
from slam_monitor.orbslam_settings import SlamMode, build_settings, load_slam_config, write_settings


def assert_one_line_error(result, *fragments):
    assert result.returncode == 2, result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("seesys: error: ")
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]
    return lines[0]


def assert_failed_session(out, frames_logged, error_line):
    manifest = session_files.read_manifest(out)
    assert manifest["status"] == "failed"
    assert error_line.endswith(manifest["error"])
    frames = pd.read_csv(out / session_layout.FRAMES_CSV)
    assert list(frames.frame_index) == list(range(frames_logged))
    assert manifest["frames"] == frames_logged


def track(source, out, *extra, env=None):
    return run_seesys("track", "--source", source, "--mode", "rgbd", "--out", str(out), *extra, env=env)


@pytest.mark.parametrize(
    "source, fragment",
    [
        ("tum:/no/such/folder", "TUM source folder not found: /no/such/folder"),  # missing folder
        ("realsense:", "no RealSense camera connected"),  # camera not connected
    ],
)
@pytest.mark.system
def test_source_that_cannot_open(tmp_path, source, fragment):
    out = tmp_path / "s"
    line = assert_one_line_error(track(source, out), fragment)
    assert_failed_session(out, 0, line)


@pytest.mark.system
def test_unknown_source_kind(tmp_path):
    out = tmp_path / "s"
    assert_one_line_error(track("kinect:/dev/video0", out), "unknown source kind 'kinect'", "tum, euroc")
    assert not out.exists()  # refused before anything starts


@pytest.mark.slam
@pytest.mark.system
def test_unreadable_image(small_tum, tmp_path):
    name = (small_tum / "rgb.txt").read_text().splitlines()[3].split()[1]
    (small_tum / name).write_bytes(b"\xff\xd8 truncated")
    out = tmp_path / "s"
    line = assert_one_line_error(track(f"tum:{small_tum}", out), "cannot read image", name)
    assert_failed_session(out, 3, line)


@pytest.mark.slam
@pytest.mark.parametrize(
    "damage, fragment",
    [(lambda d: d // 500, "wrong depth scale"), (lambda d: d[::2, ::2], "has shape (240, 320), but the image is")],
)
@pytest.mark.system
def test_bad_depth(small_tum, tmp_path, damage, fragment):
    name = (small_tum / "depth.txt").read_text().splitlines()[2].split()[1]
    cv2.imwrite(str(small_tum / name), damage(cv2.imread(str(small_tum / name), cv2.IMREAD_UNCHANGED)))
    out = tmp_path / "s"
    line = assert_one_line_error(track(f"tum:{small_tum}", out), fragment, name)
    assert_failed_session(out, 2, line)


@pytest.mark.parametrize("how", ["option", "environment"])
@pytest.mark.system
def test_corrupt_vocabulary(small_tum, tmp_path, how):
    bad = tmp_path / "ORBvoc.txt"
    bad.write_text("hello")  # this file segfaults ORB-SLAM3 when loaded unchecked
    out = tmp_path / "s"
    if how == "option":
        result = track(f"tum:{small_tum}", out, "--vocabulary", str(bad))
    else:
        result = track(f"tum:{small_tum}", out, env={"PYORBSLAM3_VOCAB": str(bad)})
    line = assert_one_line_error(result, f"vocabulary {bad}: first line is not 'k L scoring weighting'")
    assert_failed_session(out, 0, line)


@pytest.mark.system
def test_settings_missing_a_key(small_tum, tmp_path):
    settings = tmp_path / "settings.yaml"
    valid = build_settings(Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5), 30.0, SlamMode.RGBD, load_slam_config())
    text = write_settings(settings, valid).read_text()
    settings.write_text("".join(line + "\n" for line in text.splitlines() if not line.startswith("Stereo.b:")))
    out = tmp_path / "s"
    line = assert_one_line_error(
        track(f"tum:{small_tum}", out, "--settings", str(settings)), "lack the required key Stereo.b (rgbd mode)"
    )
    assert_failed_session(out, 0, line)


@pytest.mark.system
def test_config_with_a_missing_key(tmp_path):
    configs = tmp_path / "configs"
    shutil.copytree(REPO / "configs", configs)
    slam = configs / "slam.toml"
    slam.write_text(slam.read_text().replace("th_depth = 20.0\n", ""))
    result = track(f"tum:{SAMPLE}", tmp_path / "s", env={"SEESYS_CONFIG_DIR": str(configs)})
    assert_one_line_error(result, "slam.toml.rgbd: missing key(s) th_depth")


@pytest.mark.system
def test_calibration_that_does_not_fit_the_images(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    for n in range(3):
        shutil.copyfile(next(SAMPLE.glob("rgb/*.jpg")), folder / f"{n}.jpg")
    (folder / "timestamps.txt").write_text("".join(f"{n / 30:.6f} {n}.jpg\n" for n in range(3)))
    (folder / "calibration.yaml").write_text("width: 320\nheight: 240\nfx: 260.0\nfy: 260.0\ncx: 160.0\ncy: 120.0\n")
    out = tmp_path / "s"
    result = run_seesys("track", "--source", f"images:{folder}", "--mode", "mono", "--out", str(out))
    line = assert_one_line_error(result, "frame 0 is 640x480, but the source's intrinsics are for 320x240")
    assert_failed_session(out, 0, line)
