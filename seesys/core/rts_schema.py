"""The runtime-status (RTS) channels of paper Table 1: order, units, meaning and normalisation.

This module is the one definition of an RTS row. The device writes rows in this order (``rts.csv`` columns and
the float32 vector on the wire), the dataset builder stores windows in this order, and the estimator normalises
with :func:`normalise`. Change a channel here and every part follows; bump :data:`SCHEMA_VERSION` when the
order, units or meaning change so that old logs and models are recognised as incompatible: every
``FeatureFrame`` and every ``rts.csv`` (its ``rts.json`` side file) carries the version and the schema's
:data:`FINGERPRINT`, and readers refuse another one. The fingerprint is recorded per version in
:data:`_FINGERPRINTS`, so a changed channel list without a new version fails at import.

Conventions (the authors' code differs; see docs/rts-features.md):

- Image features are computed on the gray frame SLAM tracks, intensities scaled to [0, 1]; the Laplacian at the
  reference camera's pixel size and pixel lengths in its pixels (camera normalisation,
  :mod:`seesys.core.camera_normalisation`: versioned on its own, so that these definitions, the same as before for
  the reference camera, keep the schema's fingerprint).
- Every value of a row comes from the same frame index (see slam_monitor/monitor.py); channels without a value on
  a frame (tracking and mapping channels on a frame without a tracked pose) are NaN.
- Relative motion is of the current frame t with respect to the previous tracked frame t−1:
  R_rel = R_wc(t−1)ᵀ · R_wc(t), and the translation is the camera displacement c(t) − c(t−1) expressed in the
  current camera frame, R_wc(t)ᵀ · (c(t) − c(t−1)). Camera axes are ORB-SLAM3's optical frame (x right,
  y down, z forward). The rotation is given as its rotation vector, split on the camera axes: pitch about x,
  yaw about y, roll about z (the optical axis). Each component keeps its sign; there is no Euler-angle range
  folding.
- Depths are z in the current camera frame. In monocular mode all lengths are in map units (arbitrary scale).
- Version 4 adds what the geometry of the tracked points says about the pose's precision (observability and
  residual channels, from the frame's matched inliers: slam_monitor/observability.py) and a second opinion on the
  motion (slam_monitor/second_opinion.py). A model of an earlier version takes its own channels from a newer row by
  name (:func:`columns_of`).
- Version 5 adds the residuals' shear (``residual_shear``, last): the part of the residual field no camera pose makes,
  which a rolling shutter's readout leaves (the D435-class camera's whole error excess, docs/camera-effects/).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from seesys.core.errors import SeesysError

SCHEMA_VERSION = 5


@dataclass(frozen=True)
class Channel:
    """One RTS channel: its raw unit and how the estimator normalises it.

    normalised = transform(raw) / scale, where transform is ``identity``, ``log1p`` (raw ≥ 0) or
    ``signed_log1p`` (sign(x)·log1p(|x|)).
    """

    name: str
    category: str
    unit: str
    description: str
    transform: str
    scale: float


CHANNELS: tuple[Channel, ...] = (
    Channel("brightness", "sensor_input", "fraction of full scale", "mean gray level / 255", "identity", 1.0),
    Channel(
        "contrast",
        "sensor_input",
        "fraction of full scale",
        "RMS contrast: standard deviation of gray level / 255",
        "identity",
        0.25,
    ),
    Channel("entropy", "sensor_input", "bits", "Shannon entropy of the 256-bin gray-level histogram", "identity", 8.0),
    Channel(
        "laplacian",
        "sensor_input",
        "(gray level)^2",
        "variance of the 3x3 Laplacian of the 8-bit gray frame at the reference camera's pixel size (low = blur)",
        "log1p",
        10.0,
    ),
    Channel(
        "matched_inliers", "tracking", "count", "map-point matches kept after pose optimisation", "identity", 500.0
    ),
    Channel(
        "outliers",
        "tracking",
        "count",
        "proxy for matches rejected by pose optimisation: non-inlier keypoints onto which a map point "
        "matched in the previous frame projects within the match gate",
        "identity",
        100.0,
    ),
    Channel(
        "matches_before_po",
        "tracking",
        "count",
        "proxy for map-point matches before pose optimisation: matched_inliers + outliers",
        "identity",
        500.0,
    ),
    Channel(
        "rel_tx",
        "tracking",
        "m/frame (map units in monocular)",
        "camera displacement since the previous frame, current camera x",
        "identity",
        0.05,
    ),
    Channel(
        "rel_ty",
        "tracking",
        "m/frame (map units in monocular)",
        "camera displacement since the previous frame, current camera y",
        "identity",
        0.05,
    ),
    Channel(
        "rel_tz",
        "tracking",
        "m/frame (map units in monocular)",
        "camera displacement since the previous frame, current camera z",
        "identity",
        0.05,
    ),
    Channel(
        "rel_roll",
        "tracking",
        "rad/frame",
        "relative rotation since the previous frame about the optical axis z",
        "identity",
        0.05,
    ),
    Channel(
        "rel_pitch",
        "tracking",
        "rad/frame",
        "relative rotation since the previous frame about camera x",
        "identity",
        0.05,
    ),
    Channel(
        "rel_yaw",
        "tracking",
        "rad/frame",
        "relative rotation since the previous frame about camera y",
        "identity",
        0.05,
    ),
    Channel(
        "avg_mp_depth",
        "mapping",
        "m (map units in monocular)",
        "mean z of the matched map points in the current camera",
        "identity",
        5.0,
    ),
    Channel(
        "var_mp_depth",
        "mapping",
        "m^2 (map units^2 in monocular)",
        "variance of z of the matched map points in the current camera",
        "log1p",
        2.0,
    ),
    Channel(
        "local_mapping_visual_error",
        "mapping",
        "px",
        "mean reprojection error of the matched map points in the current frame, in the reference camera's pixels "
        "(pyorbslam3 does not expose local bundle adjustment residuals)",
        "log1p",
        2.0,
    ),
    Channel(
        "depth_holes",
        "depth",
        "fraction of pixels",
        "share of the depth image's pixels with no depth (RGB-D only)",
        "identity",
        0.2,
    ),
    Channel(
        "depth_noise",
        "depth",
        "1/m",
        "depth noise sigma_z / z^2, from second differences of inverse depth (RGB-D only)",
        "identity",
        0.005,
    ),
    Channel(
        "depth_registration",
        "depth",
        "rad (px / focal length)",
        "offset of depth edges from the colour edges they outline that does not follow the image motion, over "
        "the focal length: a fit over the recent frames (RGB-D only)",
        "identity",
        0.005,
    ),
    Channel(
        "translation_sigma",
        "observability",
        "mm (map units / 1000 in monocular)",
        "predicted standard deviation of the camera position: sqrt of the trace of the translation block of the "
        "inverse of the pose-only information matrix of the matched inlier points' reprojections (and, in RGB-D, "
        "depths), the Cramér–Rao bound of the pose fit",
        "log1p",
        3.0,
    ),
    Channel(
        "weakest_information",
        "observability",
        "1/mm^2 (1/(map units/1000)^2 in monocular)",
        "smallest eigenvalue of the translation information with the rotation marginalised out: its weakest "
        "direction (a degeneracy)",
        "log1p",
        5.0,
    ),
    Channel(
        "inverse_condition",
        "observability",
        "ratio",
        "smallest over largest eigenvalue of that translation information: 1 for points spread round the camera, "
        "near 0 for a planar or one-sided point set",
        "identity",
        1.0,
    ),
    Channel(
        "image_coverage",
        "observability",
        "fraction of cells",
        "share of the cells of a coverage_grid x coverage_grid grid over the image holding a matched inlier keypoint",
        "identity",
        1.0,
    ),
    Channel(
        "depth_spread",
        "observability",
        "ratio",
        "(p90 - p10) / median of the matched inlier points' depths in the current camera",
        "identity",
        1.0,
    ),
    Channel(
        "residual_median",
        "residual",
        "px",
        "median distance of the matched map points' projections to their keypoints after the pose, in the "
        "reference camera's pixels",
        "log1p",
        1.0,
    ),
    Channel(
        "residual_p90",
        "residual",
        "px",
        "90th percentile of those distances, in the reference camera's pixels",
        "log1p",
        2.0,
    ),
    Channel(
        "residual_over_gate",
        "residual",
        "fraction",
        "share of the matched points whose squared distance in units of the keypoint noise exceeds the chi-square "
        "gate of two degrees of freedom at 95 % (5.991)",
        "identity",
        0.2,
    ),
    Channel(
        "flow_disagreement",
        "second_opinion",
        "mm",
        "disagreement of an optical-flow + PnP estimate of the motion over the label's span with ORB-SLAM3's, "
        "refreshed every hop_frames-th frame and held between (RGB-D only)",
        "log1p",
        3.0,
    ),
    Channel(
        "residual_shear",
        "residual",
        "px",
        "the part of the matched points' residual field (projection - keypoint, fitted as an affine function of the "
        "keypoint's position) that no in-plane rotation or scale explains, across the image height, in the "
        "reference camera's pixels: a rolling shutter's shear, which no camera pose makes",
        "log1p",
        1.0,
    ),
)


def fingerprint(channels: tuple[Channel, ...]) -> int:
    """CRC-32 of the channels' names, categories, units, transforms and scales, in order."""
    text = "\n".join(f"{c.name}|{c.category}|{c.unit}|{c.transform}|{c.scale!r}" for c in channels)
    return zlib.crc32(text.encode("utf-8"))


#: The fingerprint of each released schema version.
_FINGERPRINTS = {1: 0x272A99E0, 2: 0xC231583F, 3: 0x8490F111, 4: 0x4722F1F7, 5: 0x0FD608E0}
FINGERPRINT = fingerprint(CHANNELS)
if _FINGERPRINTS.get(SCHEMA_VERSION) != FINGERPRINT:
    raise RuntimeError(
        f"the RTS channel list changed (fingerprint {FINGERPRINT:#010x}) but SCHEMA_VERSION is still "
        f"{SCHEMA_VERSION}: bump SCHEMA_VERSION and record the new fingerprint in _FINGERPRINTS"
    )


class SchemaMismatch(SeesysError):
    """Data or a model was made with another RTS schema than this one."""


def check_compatible(version: int, schema_fingerprint: int, source: str) -> None:
    """Raise :class:`SchemaMismatch` naming ``source`` unless it was made with this RTS schema."""
    if version != SCHEMA_VERSION or schema_fingerprint != FINGERPRINT:
        raise SchemaMismatch(
            f"{source} uses RTS schema v{version} (fingerprint {schema_fingerprint:#010x}); this "
            f"SEESys speaks v{SCHEMA_VERSION} ({FINGERPRINT:#010x}): its channels differ, so it "
            f"cannot be read or served here"
        )


CHANNEL_NAMES: tuple[str, ...] = tuple(c.name for c in CHANNELS)
#: The channel categories, in schema order: the paper's sensor_input, tracking and mapping, then depth,
#: observability, residual and second_opinion.
CATEGORIES: tuple[str, ...] = tuple(dict.fromkeys(c.category for c in CHANNELS))
#: The categories schema v4 added (and v5 added to), from the geometry of what ORB-SLAM3 tracked rather than from the
#: image or the motion: what the ``wo_geometry`` ablation removes and the channel table judges alone.
GEOMETRY_CATEGORIES: tuple[str, ...] = ("observability", "residual", "second_opinion")
NUM_CHANNELS = len(CHANNELS)
_INDEX = {name: i for i, name in enumerate(CHANNEL_NAMES)}


def channel_names(category: str) -> tuple[str, ...]:
    """The names of the channels of ``category`` (one of :data:`CATEGORIES`), in schema order."""
    return tuple(c.name for c in CHANNELS if c.category == category)


#: The relative-rotation channels (rad/frame), in roll, pitch, yaw order.
ROTATION_CHANNELS: tuple[str, str, str] = ("rel_roll", "rel_pitch", "rel_yaw")
#: The relative-translation channels (m/frame), in x, y, z order.
TRANSLATION_CHANNELS: tuple[str, str, str] = ("rel_tx", "rel_ty", "rel_tz")


def index_of(name: str) -> int:
    """Column of channel ``name`` in an RTS row."""
    try:
        return _INDEX[name]
    except KeyError:
        raise KeyError(f"unknown RTS channel {name!r}; channels are {', '.join(CHANNEL_NAMES)}") from None


def columns_of(names: Sequence[str], recorded_fingerprint: int, source: str) -> np.ndarray:
    """The columns of this schema's rows that hold the channels ``names`` a model was made with, in its order.

    A model records its input channels by name and their :func:`fingerprint`; it takes any rows whose schema has
    those channels with the same definitions (a model of schema v1 takes the first 16 columns of v2's rows).
    Raises :class:`SchemaMismatch` naming ``source`` when a channel is unknown here or defined otherwise."""
    unknown = [name for name in names if name not in _INDEX]
    if unknown:
        raise SchemaMismatch(f"{source} takes RTS channels this SEESys does not have: {', '.join(unknown)}")
    columns = np.array([_INDEX[name] for name in names], dtype=np.intp)
    if fingerprint(tuple(CHANNELS[i] for i in columns)) != recorded_fingerprint:
        raise SchemaMismatch(
            f"{source} takes RTS channels {', '.join(names)} defined otherwise than here (fingerprint "
            f"{recorded_fingerprint:#010x}): their units, transforms or scales differ"
        )
    return columns


_SCALES = np.array([c.scale for c in CHANNELS], dtype=np.float64)
# The columns of each transform, as index arrays (a window at a time, as the service normalises, costs mostly numpy's
# per-call overhead: these, in-place operations and one mask make it about a third cheaper than boolean masks).
_LOG1P = np.flatnonzero([c.transform == "log1p" for c in CHANNELS])
_SIGNED_LOG1P = np.flatnonzero([c.transform == "signed_log1p" for c in CHANNELS])


def normalise(rows: np.ndarray) -> np.ndarray:
    """Normalise raw RTS rows (..., NUM_CHANNELS) for the model; NaN (no value) and ±inf become 0
    (:func:`normalise_counted` also says how many)."""
    return normalise_counted(rows)[0]


def normalise_counted(rows: np.ndarray, columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`normalise` and keep ``columns`` (:func:`columns_of`; all by default), and per row (shape
    ``rows.shape[:-1]``) how many of the kept values were not finite after the transform and were replaced by 0: a
    channel without a value (NaN) or out of range (±inf). The model cannot tell such a 0 from a real one, so a
    receiver counts them."""
    out = np.array(rows, dtype=np.float64)
    if out.shape[-1] != NUM_CHANNELS:
        raise ValueError(f"RTS rows must have {NUM_CHANNELS} channels, got shape {out.shape}")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        x = out[..., _LOG1P]
        out[..., _LOG1P] = np.log1p(np.maximum(x, 0.0, out=x), out=x)
        x = out[..., _SIGNED_LOG1P]
        out[..., _SIGNED_LOG1P] = np.sign(x) * np.log1p(np.abs(x))
        out /= _SCALES
    if columns is not None:
        out = out[..., columns]
    not_finite = ~np.isfinite(out)
    out[not_finite] = 0.0
    return out.astype(np.float32), np.count_nonzero(not_finite, axis=-1)
