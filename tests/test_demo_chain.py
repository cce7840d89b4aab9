"""The offline preview chain on a short run: device session → true per-frame error → advisory preview (what a
researcher runs to hear what the advisory would have played for a recorded session)."""

import numpy as np
import pandas as pd
import pytest
from scipy.io import wavfile
from testkit.sample import SAMPLE, run_seesys


@pytest.mark.slam
@pytest.mark.system
def test_session_labels_feed_the_advisory_renderer(tmp_path):
    session_dir = tmp_path / "session"
    done = run_seesys(
        "monitor", "run", "--source", f"tum:{SAMPLE}", "--mode", "rgbd", "--out", str(session_dir), "--max-frames", "60"
    )
    assert done.returncode == 0, done.stderr

    every = tmp_path / "labels.csv"
    done = run_seesys("dataset", "label", str(session_dir), "--out", str(every))
    assert done.returncode == 0, done.stderr
    labels = pd.read_csv(every)
    assert len(labels) == 60 and list(labels.columns) == ["timestamp", "error_m", "status", "scale"]
    assert (labels.status.iloc[:10] != "labelled").all()  # a 10-frame RPE needs 10 frames before it
    labelled = labels[labels.status == "labelled"]
    assert len(labelled) >= 45 and np.isfinite(labelled.error_m).all() and (labelled.error_m < 0.05).all()
    assert f"{len(labelled)} of 60 frames labelled" in done.stdout

    estimates = tmp_path / "estimates.csv"
    assert run_seesys("dataset", "label", str(session_dir), "--out", str(estimates), "--labelled-only").returncode == 0
    pd.testing.assert_frame_equal(pd.read_csv(estimates), labelled.reset_index(drop=True))

    wav = tmp_path / "preview.wav"
    done = run_seesys("advisory", "render", "--estimates", str(estimates), "--out", str(wav))
    assert done.returncode == 0, done.stderr
    rate, audio = wavfile.read(wav)
    span = labelled.timestamp.iloc[-1] - labelled.timestamp.iloc[0]
    assert rate > 0 and span <= len(audio) / rate <= span + 1.5  # the render covers the whole log


@pytest.mark.system
def test_label_of_a_folder_that_is_no_session_is_a_one_line_error(tmp_path):
    done = run_seesys("dataset", "label", str(tmp_path), "--out", str(tmp_path / "x.csv"))
    assert done.returncode == 2
    assert done.stderr.strip() == f"seesys: error: {tmp_path} is not a session folder (no session.json)"
