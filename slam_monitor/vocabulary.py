"""ORB vocabularies in ORB-SLAM's DBoW2 text format: training from any frame source, writing, validating.

Format (what ORB-SLAM3's ``TemplatedVocabulary::loadFromTextFile`` reads): a header line ``k L scoring
weighting``, then one line per node after the implicit root, ``parent isLeaf d0 .. d31 weight`` (35 fields),
where a node's id is its line number (the header is line 0), so parents come before children. Leaves are the
words, in file order; ``d0..d31`` are the bytes of the cluster's 256-bit ORB descriptor and ``weight`` is the
word's IDF weight. The loader checks only the header and segfaults or silently misreads anything else, so
:func:`validate_vocabulary` checks every line before ORB-SLAM3 is given a file.

Training follows DBoW2: ORB descriptors (OpenCV's ORB uses ORB-SLAM's BRIEF pattern) are split into k clusters
by k-means++ seeding under the Hamming distance and Lloyd iterations with a bitwise-majority mean, recursively
to L levels; each word's weight is ln(N / n_i) over the N training images, n_i of which contain the word.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seesys.core.errors import SeesysError
from slam_monitor.frame import Frame

DESCRIPTOR_BYTES = 32
FIELDS_PER_NODE = 3 + DESCRIPTOR_BYTES
# The header ranges ORB-SLAM3's loader accepts.
MAX_BRANCHING = 20
MAX_LEVELS = 10
MAX_SCORING = 5
MAX_WEIGHTING = 3
L1_NORM_SCORING = 0
TF_IDF_WEIGHTING = 0
# ORB-SLAM's extractor ignores this many pixels at the border; OpenCV's default (31) would drop more.
ORB_EDGE_THRESHOLD = 19


class VocabularyError(SeesysError):
    """A vocabulary file is missing or not in DBoW2 text format (it would crash ORB-SLAM3)."""


@dataclass(frozen=True)
class TrainingConfig:
    branching: int
    levels: int
    max_iterations: int
    frame_step: int
    seed: int


@dataclass(frozen=True)
class Vocabulary:
    """The tree in file order: node ``i + 1`` has ``parents[i]``, ``is_leaf[i]``, ``descriptors[i]``, ``weights[i]``."""

    branching: int
    levels: int
    parents: np.ndarray
    is_leaf: np.ndarray
    descriptors: np.ndarray
    weights: np.ndarray

    @property
    def word_count(self) -> int:
        return int(self.is_leaf.sum())


@dataclass(frozen=True)
class VocabularyHeader:
    branching: int
    levels: int
    nodes: int
    words: int


def orb_extractor(features: int, scale_factor: float, levels: int, fast_threshold: int):
    """OpenCV's ORB configured like ORB-SLAM's extractor."""
    import cv2

    return cv2.ORB.create(
        nfeatures=features,
        scaleFactor=scale_factor,
        nlevels=levels,
        edgeThreshold=ORB_EDGE_THRESHOLD,
        fastThreshold=fast_threshold,
    )


def extract_descriptors(frames: Iterable[Frame], extractor, frame_step: int) -> list[np.ndarray]:
    """ORB descriptors, (n, 32) uint8, of every ``frame_step``-th frame (frames without features are skipped)."""
    per_image = []
    for frame in frames:
        if frame.index % frame_step:
            continue
        _, descriptors = extractor.detectAndCompute(frame.gray, None)
        if descriptors is not None and len(descriptors):
            per_image.append(descriptors)
    return per_image


def _hamming_to(bits: np.ndarray, centre_bits: np.ndarray) -> np.ndarray:
    """(n, c) Hamming distances between rows of 0/1 float32 bit matrices (n, 256) and (c, 256)."""
    return bits.sum(1, keepdims=True) + centre_bits.sum(1)[None, :] - 2.0 * (bits @ centre_bits.T)


def _kmeans_plus_plus(bits: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    centres = [bits[rng.integers(len(bits))]]
    nearest = _hamming_to(bits, centres[0][None, :])[:, 0]
    for _ in range(1, k):
        weights = nearest**2
        total = weights.sum()
        if total <= 0:
            break  # fewer than k distinct descriptors
        centre = bits[rng.choice(len(bits), p=weights / total)]
        centres.append(centre)
        nearest = np.minimum(nearest, _hamming_to(bits, centre[None, :])[:, 0])
    return np.stack(centres)


def _k_majority(bits: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Split rows of ``bits`` into at most k non-empty clusters; returns the member indices of each."""
    if len(bits) <= k:
        return [np.array([i]) for i in range(len(bits))]
    centres = _kmeans_plus_plus(bits, k, rng)
    assignment = None
    for _ in range(iterations):
        new_assignment = _hamming_to(bits, centres).argmin(axis=1)
        if assignment is not None and np.array_equal(new_assignment, assignment):
            break
        assignment = new_assignment
        centres = np.stack(
            [
                (bits[assignment == c].mean(axis=0) >= 0.5).astype(np.float32)
                if np.any(assignment == c)
                else centres[c]
                for c in range(len(centres))
            ]
        )
    return [members for c in range(len(centres)) if len(members := np.flatnonzero(assignment == c))]


def train_vocabulary(descriptors_per_image: list[np.ndarray], config: TrainingConfig) -> Vocabulary:
    """Build the DBoW2 tree (breadth first, so parents precede children) and its IDF word weights."""
    if not descriptors_per_image:
        raise VocabularyError("no ORB features found in the training frames")
    if not (1 <= config.branching <= MAX_BRANCHING and 1 <= config.levels <= MAX_LEVELS):
        raise VocabularyError(f"branching must be 1-{MAX_BRANCHING} and levels 1-{MAX_LEVELS} for ORB-SLAM3's loader")
    rng = np.random.default_rng(config.seed)
    descriptors = np.concatenate(descriptors_per_image)
    image_of = np.repeat(np.arange(len(descriptors_per_image)), [len(d) for d in descriptors_per_image])
    bits = np.unpackbits(descriptors, axis=1).astype(np.float32)

    parents: list[int] = []
    is_leaf: list[bool] = []
    centres: list[np.ndarray] = []
    word_members: dict[int, np.ndarray] = {}
    queue: deque[tuple[int, np.ndarray, int]] = deque([(0, np.arange(len(descriptors)), 0)])
    while queue:
        node, members, level = queue.popleft()
        for cluster in _k_majority(bits[members], config.branching, config.max_iterations, rng):
            child_members = members[cluster]
            parents.append(node)
            child = len(parents)
            centres.append(bits[child_members].mean(axis=0) >= 0.5)
            leaf = level + 1 >= config.levels or len(child_members) <= 1
            is_leaf.append(leaf)
            if leaf:
                word_members[child] = child_members
            else:
                queue.append((child, child_members, level + 1))

    image_count = len(descriptors_per_image)
    weights = np.zeros(len(parents))
    for node, members in word_members.items():
        weights[node - 1] = np.log(image_count / len(np.unique(image_of[members])))
    return Vocabulary(
        config.branching,
        config.levels,
        np.array(parents),
        np.array(is_leaf),
        np.packbits(np.array(centres, dtype=np.uint8), axis=1),
        weights,
    )


def write_vocabulary(path: Path, vocabulary: Vocabulary) -> Path:
    """Write the text format. No newline after the last node: ORB-SLAM3's loader would read it as a phantom node."""
    lines = [f"{vocabulary.branching} {vocabulary.levels} {L1_NORM_SCORING} {TF_IDF_WEIGHTING}"]
    for parent, leaf, descriptor, weight in zip(
        vocabulary.parents, vocabulary.is_leaf, vocabulary.descriptors, vocabulary.weights
    ):
        lines.append(f"{parent} {int(leaf)} {' '.join(map(str, descriptor))} {weight:.6g}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
    return path


def validate_vocabulary(path: Path) -> VocabularyHeader:
    """Check a vocabulary file line by line as ORB-SLAM3 will read it; raise :class:`VocabularyError` if bad."""
    import pandas as pd

    if not path.is_file():
        raise VocabularyError(f"vocabulary file not found: {path}")
    with open(path, "rb") as f:
        header = f.readline().decode("ascii", "replace").split()
    try:
        branching, levels, scoring, weighting = (int(v) for v in header)
    except ValueError:
        raise VocabularyError(
            f"vocabulary {path}: first line is not 'k L scoring weighting' (not a DBoW2 text file)"
        ) from None
    if not (
        0 <= branching <= MAX_BRANCHING
        and 1 <= levels <= MAX_LEVELS
        and 0 <= scoring <= MAX_SCORING
        and 0 <= weighting <= MAX_WEIGHTING
    ):
        raise VocabularyError(f"vocabulary {path}: header {' '.join(header)} is outside ORB-SLAM3's limits")
    try:
        nodes = pd.read_csv(path, sep=r"\s+", header=None, skiprows=1, dtype=np.float64, engine="c").to_numpy()
    except pd.errors.EmptyDataError:
        raise VocabularyError(f"vocabulary {path}: no nodes after the header") from None
    except (pd.errors.ParserError, ValueError) as e:
        raise VocabularyError(f"vocabulary {path}: malformed node line ({str(e).strip().splitlines()[-1]})") from None
    if nodes.shape[1] != FIELDS_PER_NODE:
        raise VocabularyError(f"vocabulary {path}: node lines have {nodes.shape[1]} fields, expected {FIELDS_PER_NODE}")
    ids = np.arange(1, len(nodes) + 1)
    bad = (
        np.isnan(nodes).any(axis=1)
        | (nodes[:, 0] < 0)
        | (nodes[:, 0] >= ids)
        | (nodes[:, 0] != np.round(nodes[:, 0]))
        | ~np.isin(nodes[:, 1], (0, 1))
        | (nodes[:, 2:34] < 0).any(axis=1)
        | (nodes[:, 2:34] > 255).any(axis=1)
        | (nodes[:, 2:34] != np.round(nodes[:, 2:34])).any(axis=1)
    )
    if bad.any():
        line = int(np.flatnonzero(bad)[0]) + 2
        raise VocabularyError(
            f"vocabulary {path}: line {line} is not 'parent isLeaf d0..d31 weight' with a parent defined before it"
        )
    words = int(nodes[:, 1].sum())
    if words == 0:
        raise VocabularyError(f"vocabulary {path}: no words (leaf nodes)")
    return VocabularyHeader(branching, levels, len(nodes), words)
