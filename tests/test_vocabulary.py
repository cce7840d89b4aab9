import numpy as np
import pytest
from testkit.sample import REPO, sample_frames

from slam_monitor.orbslam_settings import load_slam_config
from slam_monitor.vocabulary import (
    TrainingConfig,
    VocabularyError,
    extract_descriptors,
    orb_extractor,
    train_vocabulary,
    validate_vocabulary,
    write_vocabulary,
)


@pytest.fixture(scope="module")
def descriptors():
    orb = load_slam_config().orb
    extractor = orb_extractor(orb.features, orb.scale_factor, orb.levels, orb.ini_fast_threshold)
    return extract_descriptors(sample_frames(6, with_depth=False), extractor, frame_step=2)


def test_trained_tree_is_valid_dbow2_text(tmp_path, descriptors):
    assert len(descriptors) == 3 and all(d.shape[1] == 32 and d.dtype == np.uint8 for d in descriptors)
    vocabulary = train_vocabulary(
        descriptors, TrainingConfig(branching=5, levels=3, max_iterations=10, frame_step=1, seed=0)
    )
    path = write_vocabulary(tmp_path / "voc.txt", vocabulary)
    text = path.read_text()
    assert not text.endswith("\n")  # a trailing newline is a phantom node for ORB-SLAM3's loader
    lines = text.split("\n")
    assert lines[0] == "5 3 0 0"
    header = validate_vocabulary(path)
    assert header.nodes == len(lines) - 1 and header.words == vocabulary.word_count
    assert 5**2 < header.words <= 5**3
    nodes = [line.split() for line in lines[1:]]
    assert all(len(n) == 35 for n in nodes)
    parents = np.array([int(n[0]) for n in nodes])
    assert np.all(parents < np.arange(1, len(nodes) + 1))  # breadth-first: a parent precedes its children
    assert sum(p == 0 for p in parents) == 5
    weights = np.array([float(n[34]) for n in nodes])
    leaves = np.array([n[1] == "1" for n in nodes])
    assert np.all(weights[~leaves] == 0)
    # IDF ln(N / n_i) with N = 3 images: a word in all images weighs 0, one in a single image ln 3
    assert set(np.round(weights[leaves], 4)) <= {0.0, round(np.log(3 / 2), 4), round(np.log(3), 4)}


def test_majority_centres_are_real_cluster_means():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 256, (2, 32), dtype=np.uint8)
    noisy = [np.repeat(base, 20, axis=0) ^ (rng.random((40, 32)) < 0.02).astype(np.uint8)]
    vocabulary = train_vocabulary(noisy, TrainingConfig(2, 1, 10, 1, 0))
    assert vocabulary.word_count == 2
    assert sorted(map(bytes, vocabulary.descriptors)) == sorted(map(bytes, base))


def test_shipped_vocabulary_is_valid():
    header = validate_vocabulary(REPO / load_slam_config().vocabulary)
    assert (header.branching, header.levels) == (10, 4) and header.words > 9000


@pytest.mark.parametrize(
    "text, message",
    [
        ("hello", "first line is not 'k L scoring weighting'"),
        ("10 40 0 0\n", "outside ORB-SLAM3's limits"),
        ("10 4 0 0", "no nodes after the header"),
        ("10 4 0 0\n0 1 " + "7 " * 32 + "0.5\n0 1 1 2 3", "line 3 is not"),
        ("10 4 0 0\n0 1 " + "7 " * 32 + "0.5\n0 1 " + "7 " * 33 + "0.5", "Expected 35 fields in line 3, saw 36"),
        ("10 4 0 0\n0 1 1 2 3", "node lines have 5 fields, expected 35"),
        ("10 4 0 0\n0 1 " + "7 " * 31 + "300 0.5", "line 2 is not"),
        ("10 4 0 0\n5 1 " + "7 " * 32 + "0.5", "line 2 is not 'parent isLeaf d0..d31 weight' with a parent"),
        ("10 4 0 0\n0 0 " + "7 " * 32 + "0", "no words"),
    ],
)
def test_corrupt_files_are_rejected(tmp_path, text, message):
    path = tmp_path / "voc.txt"
    path.write_text(text)
    with pytest.raises(VocabularyError, match=message):
        validate_vocabulary(path)


@pytest.mark.slam
@pytest.mark.system
def test_cli_trained_vocabulary_loads_into_orbslam3_and_tracks(small_tum, tmp_path):
    from testkit.sample import run_seesys

    vocabulary = tmp_path / "voc.txt"
    trained = run_seesys("vocab", "train", "--source", f"tum:{small_tum}", "--out", str(vocabulary), "--levels", "3")
    assert trained.returncode == 0, trained.stderr
    assert "k=10, L=3" in trained.stdout and "trained on 12 images" in trained.stdout
    assert validate_vocabulary(vocabulary).levels == 3
    out = tmp_path / "s"
    tracked = run_seesys("track", "--source", f"tum:{small_tum}", "--out", str(out), "--vocabulary", str(vocabulary))
    assert tracked.returncode == 0, tracked.stderr
    assert "tracked: 12 (100.0 %)" in tracked.stdout
    assert "Vocabulary loaded" in (out / "orbslam3.log").read_text()
