"""RealSense sources without hardware: real recordings made with rs.software_device + rs.recorder, played back
through the same pipeline code as a live camera."""

import dataclasses
import shutil
import time

import numpy as np
import pytest
from testkit.sample import REPO, record_realsense, run_seesys, sample_frames

from slam_monitor.sources import SourceError, load_camera_config, open_source, parse_source_spec


def camera_config(stream="color", real_time=False):
    config = load_camera_config()
    return dataclasses.replace(
        config,
        realsense=dataclasses.replace(config.realsense, stream=stream),
        recording=dataclasses.replace(config.recording, real_time=real_time),
    )


@pytest.fixture(scope="module")
def frames():
    return sample_frames(8)


@pytest.mark.parametrize("stream", ["color", "infrared"])
def test_recording_plays_back_every_frame_with_intrinsics_and_metric_depth(tmp_path, frames, stream):
    path = record_realsense(tmp_path / "rec.db3", frames, stream=stream)
    with open_source(parse_source_spec(f"rsbag:{path}"), camera_config(stream), with_depth=True) as source:
        assert source.description.startswith("RealSense recording")
        assert (source.intrinsics.fx, source.intrinsics.cx, source.intrinsics.height) == (525.0, 319.5, 480)
        assert source.fps == 30.0
        got = list(source.frames())
    assert [f.index for f in got] == list(range(len(frames)))
    assert [f.timestamp for f in got] == pytest.approx([n / 30 for n in range(len(frames))], abs=1e-6)
    for played, original in zip(got, frames, strict=True):
        assert np.array_equal(played.gray, original.gray)
        assert played.depth.dtype == np.float32
        both = (played.depth > 0) & (original.depth > 0)
        assert both.mean() > 0.9  # rs.align leaves a few holes at edges
        # 1 mm depth units; rs.align may move a few pixels across depth edges
        assert np.percentile(np.abs(played.depth[both] - original.depth[both]), 99) < 0.002


def test_real_time_playback_follows_the_recorded_pace(tmp_path, frames):
    path = record_realsense(tmp_path / "rec.db3", frames, push_period_s=0.05)  # ~0.35 s of recording
    with open_source(parse_source_spec(f"rsbag:{path}"), camera_config(real_time=True), with_depth=False) as source:
        start = time.perf_counter()
        count = sum(1 for _ in source.frames())
        elapsed = time.perf_counter() - start
    assert count >= len(frames) - 1  # real-time playback, like a camera, may skip a frame it is late for
    assert elapsed >= 0.25  # not faster than recorded (fast playback of such files takes a few ms per frame)


def test_a_slow_reader_gets_every_frame_when_played_as_fast_as_possible(tmp_path):
    frames = sample_frames(30)
    path = record_realsense(tmp_path / "rec.db3", frames)
    with open_source(parse_source_spec(f"rsbag:{path}"), camera_config(), with_depth=True) as source:
        got = []
        for frame in source.frames():
            got.append(round(frame.timestamp * 30))
            # slower than the file is read: the reader, not the recording's queue, sets the pace
            time.sleep(0.02)
    assert got == list(range(len(frames)))


def test_an_image_recorded_without_its_depth_is_left_out_of_rgbd_only(tmp_path, frames):
    path = record_realsense(tmp_path / "rec.db3", frames, without_depth=frozenset({3}))
    with open_source(parse_source_spec(f"rsbag:{path}"), camera_config(), with_depth=True) as source:
        rgbd = [round(f.timestamp * 30) for f in source.frames()]
    with open_source(parse_source_spec(f"rsbag:{path}"), camera_config(), with_depth=False) as source:
        mono = [round(f.timestamp * 30) for f in source.frames()]
    assert rgbd == [0, 1, 2, 4, 5, 6, 7]
    assert mono == list(range(len(frames)))


def test_closing_in_the_middle_of_a_recording_stops_its_playback(tmp_path):
    path = record_realsense(tmp_path / "rec.db3", sample_frames(30))
    source = open_source(parse_source_spec(f"rsbag:{path}"), camera_config(), with_depth=True)
    stream = source.frames()
    first = [next(stream) for _ in range(2)]
    sensors = source._sensors
    assert all(s.get_active_streams() for s in sensors)
    # the playback thread now waits on a full queue; closing must release it rather than hang
    source.close()
    assert [f.index for f in first] == [0, 1]
    assert not any(s.get_active_streams() for s in sensors)


def test_recording_must_be_bag_or_db3(tmp_path):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"x")
    with pytest.raises(SourceError, match=r"must be a \.bag or \.db3 file"):
        open_source(parse_source_spec(f"rsbag:{path}"), camera_config(), True)


def test_live_camera_missing_is_a_clear_error():
    with pytest.raises(SourceError, match="^no RealSense camera connected$"):
        open_source(parse_source_spec("realsense:"), load_camera_config(), with_depth=True)


@pytest.mark.slam
@pytest.mark.system
def test_track_cli_on_a_recording_tracks_like_the_dataset(tmp_path):
    path = record_realsense(tmp_path / "walk.db3", sample_frames(45))
    # as-fast-as-possible playback (configs/camera.toml [recording]) keeps the test independent of CPU load;
    # real-time playback is covered above
    configs = tmp_path / "configs"
    shutil.copytree(REPO / "configs", configs)
    camera = configs / "camera.toml"
    camera.write_text(camera.read_text().replace("real_time = true", "real_time = false"))
    out = tmp_path / "session"
    result = run_seesys(
        "track",
        "--source",
        f"rsbag:{path}",
        "--mode",
        "rgbd",
        "--out",
        str(out),
        env={"SEESYS_CONFIG_DIR": str(configs)},
    )
    assert result.returncode == 0, result.stderr
    rows = (out / "frames.csv").read_text().splitlines()[1:]
    assert len(rows) == 45
    assert sum(",OK," in row for row in rows) >= 0.95 * len(rows)
    assert f"frames:  {len(rows)}" in result.stdout
