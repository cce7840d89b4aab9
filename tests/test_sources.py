import itertools

import cv2
import numpy as np
import pytest
from testkit.sample import SAMPLE, sample_frames

from slam_monitor.sources import SourceError, load_camera_config, open_source, parse_source_spec


def open_spec(text, with_depth=False):
    return open_source(parse_source_spec(text), load_camera_config(), with_depth)


def test_tum_sample_yields_gray_metric_depth_and_ground_truth():
    with open_spec(f"tum:{SAMPLE}", with_depth=True) as source:
        assert source.frame_count == 150
        assert source.fps == pytest.approx(30.0)
        assert (source.intrinsics.fx, source.intrinsics.cx, source.intrinsics.width) == (525.0, 319.5, 640)
        frames = list(itertools.islice(source.frames(), 3))
        truth = source.ground_truth()
    assert [f.index for f in frames] == [0, 1, 2]
    listed = [
        float(line.split()[0])
        for line in (SAMPLE / "rgb.txt").read_text().splitlines()
        if line and not line.startswith("#")
    ]
    assert [f.timestamp for f in frames] == pytest.approx(listed[:3], abs=1e-6)
    assert frames[1].timestamp - frames[0].timestamp == pytest.approx(1 / 30, abs=1e-5)
    assert frames[0].gray.dtype == np.uint8 and frames[0].gray.shape == (480, 640)
    assert frames[0].depth.dtype == np.float32
    valid = frames[0].depth[frames[0].depth > 0]
    assert 0.5 < np.median(valid) < 3.3  # the room's depth range, in metres
    assert truth.positions.shape == (150, 3) and truth.quaternions_xyzw.shape == (150, 4)


def test_tum_pairs_images_with_nearest_depth_and_drops_unpaired(small_tum):
    depth_lines = (small_tum / "depth.txt").read_text().splitlines()
    (small_tum / "depth.txt").write_text("\n".join(depth_lines[:5]) + "\n")
    with open_spec(f"tum:{small_tum}", with_depth=True) as source:
        assert source.frame_count == 5
    with open_spec(f"tum:{small_tum}", with_depth=False) as source:
        assert source.frame_count == 12 and not source.has_depth


def make_euroc(root, frames):
    cam0 = root / "mav0" / "cam0"
    (cam0 / "data").mkdir(parents=True)
    lines = ["#timestamp [ns],filename"]
    for f in frames:
        ns = int(round(f.timestamp * 1e9))
        cv2.imwrite(str(cam0 / "data" / f"{ns}.png"), f.gray)
        lines.append(f"{ns},{ns}.png")
    (cam0 / "data.csv").write_text("\n".join(lines) + "\n")
    (cam0 / "sensor.yaml").write_text(
        "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
        "  data: [1.0, 0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\n"
        "rate_hz: 20\nresolution: [640, 480]\ncamera_model: pinhole\n"
        "intrinsics: [458.654, 457.296, 367.215, 248.375]\ndistortion_model: radial-tangential\n"
        "distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n"
    )
    gt = root / "mav0" / "state_groundtruth_estimate0"
    gt.mkdir()
    rows = [f"{int(round(f.timestamp * 1e9))},{f.index * 0.01},0,0,1,0,0,0" for f in frames]
    (gt / "data.csv").write_text(
        "#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w,q_RS_x,q_RS_y,q_RS_z\n" + "\n".join(rows) + "\n"
    )


def test_euroc_reads_cam0_intrinsics_distortion_and_camera_ground_truth(tmp_path):
    frames = sample_frames(4, with_depth=False)
    make_euroc(tmp_path / "seq", frames)
    with open_spec(f"euroc:{tmp_path / 'seq'}") as source:
        assert source.fps == 20.0
        assert source.intrinsics.fx == pytest.approx(458.654)
        assert source.intrinsics.distortion[0] == pytest.approx(-0.28340811)
        got = list(source.frames())
        truth = source.ground_truth()
    assert len(got) == 4 and got[2].timestamp == pytest.approx(frames[2].timestamp, abs=1e-6)
    assert np.array_equal(got[1].gray, frames[1].gray)
    # cam0 sits 0.1 m along the body x axis (T_BS), so the camera track is the body track shifted by it
    assert truth.positions[:, 0] == pytest.approx([0.1, 0.11, 0.12, 0.13])


def test_image_folder_with_timestamp_list(tmp_path):
    frames = sample_frames(3, with_depth=False)
    lines = []
    for f in frames:
        cv2.imwrite(str(tmp_path / f"im{f.index}.png"), f.gray)
        lines.append(f"{f.timestamp:.6f} im{f.index}.png")
    (tmp_path / "timestamps.txt").write_text("\n".join(lines) + "\n")
    with open_spec(f"images:{tmp_path}") as source:
        got = list(source.frames())
        assert source.fps == pytest.approx(30.0, rel=1e-3)
    assert [np.array_equal(a.gray, b.gray) for a, b in zip(got, frames)] == [True] * 3


def test_video_file(tmp_path):
    frames = sample_frames(5, with_depth=False)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (640, 480), isColor=False)
    for f in frames:
        writer.write(f.gray)
    writer.release()
    with open_spec(f"video:{path}") as source:
        got = list(source.frames())
        assert source.fps == 15.0
    assert len(got) == 5 and got[4].timestamp == pytest.approx(4 / 15.0)
    assert np.abs(got[0].gray.astype(int) - frames[0].gray).mean() < 5  # MJPEG is lossy


@pytest.mark.parametrize(
    "spec, message",
    [
        ("nosuch:x", "unknown source kind 'nosuch'"),
        ("tum", "is not KIND:PATH"),
        ("tum:", "needs a path"),
        ("tum:/no/such/folder", "TUM source folder not found: /no/such/folder"),
        ("euroc:/no/such/folder", "EuRoC source folder not found"),
        ("video:/no/such.mp4", "video file not found"),
        ("rsbag:/no/such.db3", "RealSense recording not found"),
    ],
)
def test_bad_specs_name_the_problem(spec, message):
    with pytest.raises(SourceError, match=message.replace("(", r"\(")):
        open_spec(spec)


def test_depth_required_from_kinds_without_depth():
    with pytest.raises(SourceError, match="has no depth; use --mode mono"):
        open_spec("images:/tmp", with_depth=True)


def test_unreadable_image_is_reported_at_its_frame(small_tum):
    names = [line.split()[1] for line in (small_tum / "rgb.txt").read_text().splitlines()]
    (small_tum / names[3]).write_bytes(b"not a jpeg")
    with open_spec(f"tum:{small_tum}", with_depth=True) as source:
        frames = source.frames()
        assert [next(frames).index for _ in range(3)] == [0, 1, 2]
        with pytest.raises(SourceError, match=f"cannot read image .*{names[3]}"):
            next(frames)


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda d: d // 500, "outside 0.1-20.0 m: wrong depth scale"),  # written in centimetres, read as 1/5000 m
        (lambda d: d[:240, :320], r"has shape \(240, 320\), but the image is \(480, 640\)"),
        (lambda d: np.dstack([d, d, d]).astype(np.uint8), "expected a 16-bit single-channel PNG"),
    ],
)
def test_bad_depth_is_reported(small_tum, damage, message):
    name = (small_tum / "depth.txt").read_text().splitlines()[0].split()[1]
    raw = cv2.imread(str(small_tum / name), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(small_tum / name), damage(raw))
    with open_spec(f"tum:{small_tum}", with_depth=True) as source, pytest.raises(SourceError, match=message):
        next(source.frames())


@pytest.mark.parametrize(
    "text, message",
    [("width: 640\nheight: 480\nfy: 1.0\ncx: 1.0\ncy: 1.0\n", "missing key fx"), ("width: [640\n", "not valid YAML")],
)
def test_bad_calibration_file(small_tum, text, message):
    (small_tum / "calibration.yaml").write_text(text)
    with pytest.raises(SourceError, match=message):
        open_spec(f"tum:{small_tum}")
