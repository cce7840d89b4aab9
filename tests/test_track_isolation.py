"""ORB-SLAM3 taking the worker process down (exit status 255, SIGSEGV) or hanging becomes a clear error, and the
session files written before it stay valid. The crash is caused inside the real worker by an observer built from a spec,
exactly where a crash inside ORB-SLAM3's track call would happen."""

import contextlib
import ctypes
import os
import shutil
import subprocess
import sys
import time

import pandas as pd
import psutil
import pytest
from evo.tools import file_interface
from testkit.sample import REPO, SAMPLE

from seesys.core import session_layout
from seesys.core.errors import SeesysError
from seesys.io import session_files
from slam_monitor.device_worker import ObserverSpec, SessionOptions
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.supervisor import WorkerCrash, frames_logged, run_supervised_session

pytestmark = pytest.mark.slam


class Crasher:
    def __init__(self, at_frame, how):
        self.at_frame, self.how = at_frame, how

    def on_frame(self, frame, result):
        if frame.index == self.at_frame - 1:  # frame at_frame - 1 is logged, frame at_frame never will be
            if self.how == "hang":
                print("LM: Active map reset, Done!!!", flush=True)
                time.sleep(3600)  # as ORB-SLAM3 does when a map reset deadlocks with local mapping
            print("Stereo.b required parameter does not exist, aborting...", flush=True)
            if self.how == "exit":
                os._exit(255)
            ctypes.string_at(0)  # a real segmentation fault

    def close(self):
        pass


def crasher(context, at_frame, how):
    return Crasher(at_frame, how)


class Counter:
    def __init__(self, path):
        self.path = path
        self.count = 0

    def on_frame(self, frame, result):
        self.count += 1

    def close(self):
        self.path.write_text(str(self.count))


def counter(context):
    return Counter(context.out_dir / "observed.txt")


@pytest.mark.parametrize(
    "how, expected",
    [("segfault", "ORB-SLAM3 crashed (signal 11, SIGSEGV)"), ("exit", "ORB-SLAM3 exited with status 255")],
)
@pytest.mark.system
def test_crash_is_a_clear_error_and_keeps_the_logged_frames(tmp_path, how, expected):
    out = tmp_path / "s"
    options = SessionOptions(
        f"tum:{SAMPLE}",
        SlamMode.RGBD,
        out,
        observers=(ObserverSpec("test_track_isolation:crasher", {"at_frame": 6, "how": how}),),
    )
    with pytest.raises(WorkerCrash) as error:
        run_supervised_session(options)
    message = str(error.value)
    assert message.startswith(expected)
    assert 'after printing "Stereo.b required parameter does not exist, aborting..."' in message
    assert f"at frame 6; the session files up to frame 5 are kept in {out}" in message
    frames = pd.read_csv(out / session_layout.FRAMES_CSV)
    assert list(frames.frame_index) == list(range(6))
    assert file_interface.read_tum_trajectory_file(str(out / session_layout.TRAJECTORY)).num_poses == 6
    manifest = session_files.read_manifest(out)
    assert (manifest["status"], manifest["error"], manifest["frames"]) == ("crashed", message, 6)


@pytest.mark.system
def test_a_hung_worker_is_killed_after_the_stall_timeout_and_keeps_the_logged_frames(tmp_path):
    configs = tmp_path / "configs"
    shutil.copytree(REPO / "configs", configs)
    slam = configs / "slam.toml"
    slam.write_text(slam.read_text().replace("stall_timeout_s = 60.0", "stall_timeout_s = 3.0"))
    out = tmp_path / "s"
    options = SessionOptions(
        f"tum:{SAMPLE}",
        SlamMode.RGBD,
        out,
        config_dir=configs,
        observers=(ObserverSpec("test_track_isolation:crasher", {"at_frame": 6, "how": "hang"}),),
    )
    with pytest.raises(WorkerCrash) as error:
        run_supervised_session(options)
    message = str(error.value)
    assert message.startswith("ORB-SLAM3 stopped responding (no frame for 3 s; killed)")
    assert 'after printing "LM: Active map reset, Done!!!"' in message
    assert f"at frame 6; the session files up to frame 5 are kept in {out}" in message
    assert list(pd.read_csv(out / session_layout.FRAMES_CSV).frame_index) == list(range(6))
    manifest = session_files.read_manifest(out)
    assert (manifest["status"], manifest["error"]) == ("crashed", message)


@pytest.mark.system
def test_observer_specs_are_built_in_the_worker(tmp_path):
    out = tmp_path / "s"
    options = SessionOptions(
        f"tum:{SAMPLE}", SlamMode.RGBD, out, max_frames=7, observers=(ObserverSpec("test_track_isolation:counter"),)
    )
    events = []
    result = run_supervised_session(options, progress=events.append)
    assert result.frames == 7 and (out / "observed.txt").read_text() == "7"
    assert events[0].frame_count == 7 and [e.frame_index for e in events[1:]] == list(range(7))


def crash_at_start(context):
    os._exit(255)


@pytest.mark.system
def test_crash_before_the_first_frame(tmp_path):
    out = tmp_path / "s"
    options = SessionOptions(
        f"tum:{SAMPLE}", SlamMode.RGBD, out, observers=(ObserverSpec("test_track_isolation:crash_at_start"),)
    )
    with pytest.raises(WorkerCrash, match=r"^ORB-SLAM3 exited with status 255 .*before the first frame; see "):
        run_supervised_session(options)
    assert session_files.read_manifest(out)["status"] == "crashed"
    assert (out / session_layout.FRAMES_CSV).read_text().splitlines() == [session_layout.FRAMES_HEADER]


class Faulty:
    def on_frame(self, frame, result):
        if frame.index == 2:
            raise ZeroDivisionError("observer bug")

    def close(self):
        pass


def faulty(context):
    return Faulty()


@pytest.mark.system
def test_a_bug_in_the_worker_is_reported_in_one_line_and_the_session_marked_failed(tmp_path):
    out = tmp_path / "s"
    options = SessionOptions(
        f"tum:{SAMPLE}", SlamMode.RGBD, out, observers=(ObserverSpec("test_track_isolation:faulty"),)
    )
    with pytest.raises(
        SeesysError,
        match=r"^internal error in the device worker: ZeroDivisionError: observer bug "
        r"\(traceback in .*orbslam3.log\)$",
    ):
        run_supervised_session(options)
    manifest = session_files.read_manifest(out)
    assert (manifest["status"], manifest["error"], manifest["frames"]) == (
        "failed",
        "ZeroDivisionError: observer bug",
        3,
    )
    assert "Traceback" in (out / session_layout.SLAM_LOG).read_text()


@pytest.mark.system
def test_killing_the_command_takes_the_orbslam3_worker_with_it(tmp_path):
    """``kill -9`` of a running ``seesys track`` (no chance to clean up) must not leave its ORB-SLAM3 worker
    running: the worker dies with it, and the frames logged until then stay readable."""
    out = tmp_path / "session"
    command = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "seesys",
            "track",
            "--source",
            f"tum:{SAMPLE}",
            "--mode",
            "rgbd",
            "--pace",
            "--out",
            str(out),
        ],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    frames_csv = out / session_layout.FRAMES_CSV
    workers = []
    try:
        deadline = time.monotonic() + 120
        while frames_logged(out) < 10:  # the worker is tracking, at camera rate (150 frames take 5 s)
            assert command.poll() is None and time.monotonic() < deadline, "seesys track never got going"
            time.sleep(0.05)
        workers = [
            p for p in psutil.Process(command.pid).children(recursive=True) if "spawn_main" in " ".join(p.cmdline())
        ]
        assert len(workers) == 1
        command.kill()
        command.wait()
        gone, alive = psutil.wait_procs(workers, timeout=10)
        assert not alive, "the ORB-SLAM3 worker outlived its command"
    finally:
        for process in [command, *workers]:  # nothing left running when the test fails
            with contextlib.suppress(ProcessLookupError, psutil.NoSuchProcess):
                process.kill()
    logged = pd.read_csv(frames_csv)
    assert 10 <= len(logged) < 150  # it stopped with the command, not at the end of the sample
