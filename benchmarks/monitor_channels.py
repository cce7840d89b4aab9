"""The RTS monitor's cost per channel: each channel (or group of channels computed in one pass) timed alone on
every frame of a source, in thread CPU time, and the whole monitor beside them.

ORB-SLAM3 tracks the source once, unpaced, in this process (``slam_monitor.replay``); the monitor's inputs of
every frame are kept, and the monitor's intermediate results (the local map's lost points, the relative motion, the
inlier keypoints) are prepared once, so that each row below times only its own work. Each row runs over every
frame ``--repeats`` times and reports the median pass's mean thread CPU ms per frame (``time.thread_time``: not
inflated by waiting for a core on a loaded machine). Rows marked "per PSD frame" run only on the frames that end a
model window (every ``end_stride``-th, as on a device), and the second opinion's work is on its hop frames (every
``hop_frames``-th); their "per frame" figure is amortised over all frames.
"monitor thread, whole" is the monitor thread's own work per frame: its step (``MonitorStep``: features, PSD, the
pose covariance and every log) and the stream message's encoding, without the socket send; back to back, then paced
as on a device: one frame every 33 ms, the thread asleep in between. Paced, the same work costs more CPU time per
frame than back to back, with no other work on the machine (most likely colder caches and a core woken from idle);
beside ORB-SLAM3 (``benchmarks/monitor_overhead.py``) the monitor is paced so. Last, the feature stream's size: wire
bytes per message with and without a PSD, and kbit/s at 30 Hz.

With ``--flow-variants`` it also times the second opinion (``flow_disagreement``, the costliest channel) with other
settings of ``[second_opinion]`` in monitor.toml, one changed at a time, against the configured ones on the same
frames: its cost per frame, the share of frames with a value, and how far its values move (the absolute difference,
and Spearman's ρ with the configured values, on the frames where both have one). A setting that saves time changes
the channel's values, on which a model was trained: this says by how much, beside how far they move between two
ORB-SLAM3 trials of the same source with the configured settings (the source is tracked a second time).

With ``--library-calls`` it also times, inside the whole monitor thread back to back, each call into the compiled
libraries whose work defines the channels (OpenCV's functions and scipy's k-d tree), and the rest beside them
(Python, numpy, zlib, the logs): the calls' sum is what the monitor would cost with no Python around them, a floor
that only other channel definitions (a smaller image, fewer points) lower.

    .venv/bin/python benchmarks/monitor_channels.py [--source tum:data/sample] [--mode rgbd] [--repeats 5]
        [--flow-variants] [--library-calls]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from pacing import paced
from scipy.spatial import cKDTree
from scipy.stats import spearmanr

from seesys.core import messages
from seesys.core.camera_normalisation import CameraNormalisation
from seesys.core.units import MM_PER_M
from seesys.io.config import replace_fields
from seesys.io.core_settings import load_device_settings
from slam_monitor import slam_features
from slam_monitor.depth_features import (
    RegistrationFit,
    edge_crossings,
    hole_share,
    image_motion_px,
    inverse_depth,
    noise_over_z2,
)
from slam_monitor.device_worker import new_stream_session
from slam_monitor.image_features import (
    intensity_statistics,
    laplacian_variance,
    reference_scale,
)
from slam_monitor.local_map import LocalMap
from slam_monitor.monitor import FeatureExtractor, MonitorInput, MonitorStep, input_slam_features
from slam_monitor.monitor_config import MonitorConfig, load_monitor_config, resolve_device_id
from slam_monitor.observability import frame_geometry
from slam_monitor.orbslam_settings import SlamMode
from slam_monitor.replay import record_inputs
from slam_monitor.second_opinion import FlowConfig, SecondOpinion
from slam_monitor.slam_features import (
    RelativeMotion,
    SlamFeatures,
    relative_motion,
)
from slam_monitor.stream import zmtp_frame_overhead

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Prepared:
    """One frame's monitor input and the intermediate results the channels after the local map take."""

    item: MonitorInput
    normalisation: CameraNormalisation
    reference_gray: np.ndarray
    lost_points_w: np.ndarray | None  # None: no tracked pose
    motion: RelativeMotion | None
    moved: np.ndarray | None  # T_prev_cur for the depth registration, None without both poses
    slam: SlamFeatures | None  # the tracking channels and inlier keypoints the PSD takes


def prepare(inputs: Sequence[MonitorInput], config: MonitorConfig) -> list[Prepared]:
    """Replay the monitor's local map over ``inputs`` (as :class:`FeatureExtractor` does) and keep each frame's
    intermediate results."""
    lm = config.local_map
    local_map = LocalMap(lm.voxel, lm.max_age_frames, lm.max_points)
    prepared = []
    for item in inputs:
        normalisation = CameraNormalisation(config.reference_camera, item.frame.intrinsics)
        lost, motion = None, None
        if item.state.tracked and item.pose_cw is not None and item.pose_wc is not None:
            if item.map_changed or item.prev_pose_wc is None:
                local_map.clear()
            local_map.update(item.map_points, item.frame.index)
            lost = local_map.lost_points()
            motion = (
                relative_motion(item.prev_pose_wc, item.pose_wc)
                if item.prev_pose_wc is not None
                else RelativeMotion.still()
            )
        moved = (
            np.linalg.inv(item.prev_pose_wc) @ item.pose_wc
            if item.pose_wc is not None and item.prev_pose_wc is not None and not item.map_changed
            else None
        )
        prepared.append(
            Prepared(
                item,
                normalisation,
                reference_scale(item.frame.gray, normalisation),
                lost,
                motion,
                moved,
                input_slam_features(item, motion, lost, config) if motion is not None else None,
            )
        )
    return prepared


def _local_map_pass(config: MonitorConfig) -> Callable[[Sequence[Prepared]], None]:
    lm = config.local_map

    def run(frames: Sequence[Prepared]) -> None:
        local_map = LocalMap(lm.voxel, lm.max_age_frames, lm.max_points)
        for p in frames:
            item = p.item
            if p.motion is None:
                continue
            if item.map_changed or item.prev_pose_wc is None:
                local_map.clear()
            local_map.update(item.map_points, item.frame.index)
            local_map.lost_points()
            if config.windows.is_psd_frame(item.frame.index):
                len(local_map)  # the PSD reads the map, which merges the frames kept since the last read

    return run


def _registration_pass(config: MonitorConfig) -> Callable[[Sequence[Prepared]], None]:
    cfg = config.depth

    def run(frames: Sequence[Prepared]) -> None:
        fit = RegistrationFit(cfg)
        s = cfg.stride
        for p in frames:
            frame = p.item.frame
            if frame.depth is None:
                continue
            w_sub = inverse_depth(frame.depth[s // 2 :: s, s // 2 :: s])
            crossings = edge_crossings(frame.depth, frame.gray, w_sub, cfg)
            motion = image_motion_px(crossings, frame.intrinsics, p.moved) if p.moved is not None else None
            fit.update(crossings, motion, frame.depth.shape[0])

    return run


def _whole_monitor(
    config: MonitorConfig, with_logs: bool, period_s: float = 0.0
) -> Callable[[Sequence[Prepared]], None]:
    """The whole monitor over the frames; with ``period_s``, the device's step one frame every ``period_s`` seconds,
    the thread asleep in between (as on a device paced by its camera)."""
    settings = load_device_settings(SlamMode.RGBD.value, 30.0)

    def run(frames: Sequence[Prepared]) -> None:
        if not with_logs:
            extractor = FeatureExtractor(config, 1, settings)
            for p in frames:
                extractor.extract_with_covariance(p.item)
            return
        # the device's own step: features, PSD, covariance and every log, then the stream message's encoding
        with tempfile.TemporaryDirectory() as tmp:
            step = MonitorStep(config, Path(tmp), None, 1, settings)
            # A period of 0 (back to back): every turn is due at once.
            for k in paced(len(frames), period_s):
                messages.encode(step.step(frames[k].item))
            step.close_logs()

    return run


def _each(step: Callable[[Prepared], object]) -> Callable[[Sequence[Prepared]], None]:
    def run(frames: Sequence[Prepared]) -> None:
        for p in frames:
            step(p)

    return run


def _depth_only(step: Callable[[np.ndarray], object]) -> Callable[[Prepared], object]:
    return lambda p: step(p.item.frame.depth) if p.item.frame.depth is not None else None


# Where a row's work happens: on every frame, on PSD frames only (its pass gets those), or on the second opinion's hop
# frames (its pass gets every frame, as the channel must see every frame, and its per-call figure is per hop frame).
FRAME, PSD, HOP = "frame", "psd", "hop"


def _second_opinion_pass(flow: FlowConfig) -> Callable[[Sequence[Prepared]], None]:
    def run(frames: Sequence[Prepared]) -> None:
        flow_values(flow, frames)

    return run


# Other settings of the second opinion, one changed at a time (--flow-variants).
FLOW_VARIANTS = {
    "window_px 11": {"window_px": 11},
    "window_px 9": {"window_px": 9},
    "pyramid_levels 2": {"pyramid_levels": 2},
    "max_points 100": {"max_points": 100},
    "max_points 75": {"max_points": 75},
}


def flow_values(flow: FlowConfig, frames: Sequence[Prepared]) -> np.ndarray:
    """The second opinion's value (m; NaN: none) on every frame, as the monitor computes it."""
    opinion = SecondOpinion(flow)
    values = []
    for p in frames:
        frame = p.item.frame
        value = opinion.update(
            frame.index,
            frame.gray,
            frame.depth,
            p.item.keypoints,
            frame.intrinsics.matrix(),
            None if p.item.map_changed else p.item.pose_wc,
        )
        values.append(np.nan if value is None else value)
    return np.array(values)


def flow_variants(
    config: MonitorConfig, frames: Sequence[Prepared], second_trial: Sequence[Prepared], repeats: int
) -> list[dict[str, object]]:
    """Per setting (the configured one first): thread CPU ms per frame, share of frames with a value, the values'
    median (mm), and their median and p90 absolute difference (mm) and Spearman ρ against the configured setting's;
    last, the configured setting on ``second_trial`` (the same source tracked again by ORB-SLAM3): how far the values
    move between two SLAM trials of the same frames, the noise a model of this channel already sees."""
    configured = config.second_opinion
    settings = {label: (replace_fields(configured, **change), frames) for label, change in FLOW_VARIANTS.items()}
    runs = {
        "configured": (configured, frames),
        **settings,
        "configured, a second ORB-SLAM3 trial": (configured, second_trial),
    }
    values_of = {label: flow_values(flow, trial) for label, (flow, trial) in runs.items()}
    reference = values_of["configured"]
    rows = []
    for label, (flow, trial) in runs.items():
        values = values_of[label]
        both = np.isfinite(reference) & np.isfinite(values)
        difference_mm = np.abs(values[both] - reference[both]) * MM_PER_M
        rows.append(
            {
                "setting": label,
                "ms_per_frame": thread_ms_per_call(_second_opinion_pass(flow), trial, repeats),
                "with_value": float(np.isfinite(values).mean()),
                "median_mm": float(np.nanmedian(values) * MM_PER_M) if np.isfinite(values).any() else float("nan"),
                "difference_median_mm": float(np.median(difference_mm)) if both.any() else float("nan"),
                "difference_p90_mm": float(np.percentile(difference_mm, 90)) if both.any() else float("nan"),
                "spearman": float(spearmanr(values[both], reference[both])[0]) if both.sum() > 2 else float("nan"),
            }
        )
    return rows


PACED_ROW = "monitor thread, whole, paced: one frame every 33 ms, asleep in between"

# The compiled calls that define the channels (--library-calls): OpenCV's functions the monitor calls, and scipy's
# k-d tree of the keypoint pairing. What they cost is the floor of these channels' definitions, whatever the Python
# and numpy around them cost.
OPENCV_CALLS = (
    "calcOpticalFlowPyrLK",
    "solvePnPRansac",
    "Laplacian",
    "calcHist",
    "meanStdDev",
    "resize",
    "countNonZero",
    "cvtColor",
    "copyMakeBorder",
    "sumElems",
    "norm",
    "Rodrigues",
)
KD_TREE_BUILD, KD_TREE_QUERY = "scipy cKDTree (build)", "scipy cKDTree.query"


@contextmanager
def timed_library_calls(spent: dict[str, float]) -> Iterator[None]:
    """While open, every call of :data:`OPENCV_CALLS` and of the pairing's k-d tree adds its thread CPU seconds to
    ``spent`` under its name (the monitor looks both up at call time: ``cv2.<name>``, ``slam_features.cKDTree``)."""

    def timed(name: str, call: Callable) -> Callable:
        def run(*args: object, **kwargs: object) -> object:
            start = time.thread_time()
            try:
                return call(*args, **kwargs)
            finally:
                spent[name] += time.thread_time() - start

        return run

    class TimedTree:
        def __init__(self, *args: object, **kwargs: object):
            self._tree = timed(KD_TREE_BUILD, cKDTree)(*args, **kwargs)
            self.query = timed(KD_TREE_QUERY, self._tree.query)

    originals = {name: getattr(cv2, name) for name in OPENCV_CALLS}
    try:
        for name, call in originals.items():
            setattr(cv2, name, timed(f"cv2.{name}", call))
        slam_features.cKDTree = TimedTree
        yield
    finally:
        for name, call in originals.items():
            setattr(cv2, name, call)
        slam_features.cKDTree = cKDTree


@dataclass(frozen=True)
class LibraryCalls:
    """Thread CPU ms per frame of one pass of the whole monitor: in each library call (costliest first), in them
    together, the whole, and the rest (Python, numpy, zlib, the logs)."""

    calls: dict[str, float]
    library: float
    whole: float
    rest: float


def library_calls(config: MonitorConfig, frames: Sequence[Prepared], repeats: int) -> LibraryCalls:
    """The whole monitor thread back to back (features, PSD, encoding, logs), ``repeats`` passes with every library
    call of :func:`timed_library_calls` timed: the pass whose whole is the median."""
    passes = []
    for _ in range(repeats):
        spent: dict[str, float] = defaultdict(float)
        with timed_library_calls(spent):
            start = time.thread_time()
            _whole_monitor(config, with_logs=True)(frames)
            whole = time.thread_time() - start
        passes.append((whole, spent))
    whole, spent = sorted(passes, key=lambda p: p[0])[len(passes) // 2]
    per_frame = {name: s * 1000.0 / len(frames) for name, s in sorted(spent.items(), key=lambda kv: -kv[1])}
    library = sum(per_frame.values())
    whole_ms = whole * 1000.0 / len(frames)
    return LibraryCalls(per_frame, library, whole_ms, whole_ms - library)


def stages(config: MonitorConfig, encoded: dict[int, messages.FeatureFrame]) -> dict[str, tuple[Callable, str]]:
    """Row label → (a pass over the frames, where its work happens: FRAME, PSD or HOP)."""
    s = config.depth.stride
    edge_jump = config.depth.edge_jump
    extractor = FeatureExtractor(config)
    return {
        "brightness, contrast, entropy": (_each(lambda p: intensity_statistics(p.item.frame.gray)), FRAME),
        "laplacian (with the reference-scale resampling)": (
            _each(lambda p: laplacian_variance(reference_scale(p.item.frame.gray, p.normalisation))),
            FRAME,
        ),
        "local map (update, lost points)": (_local_map_pass(config), FRAME),
        "matched_inliers, outliers, matches_before_po, avg/var_mp_depth, local_mapping_visual_error": (
            _each(
                lambda p: (
                    input_slam_features(p.item, p.motion, p.lost_points_w, config) if p.motion is not None else None
                )
            ),
            FRAME,
        ),
        "rel_tx/ty/tz, rel_roll/pitch/yaw": (
            _each(
                lambda p: (
                    relative_motion(p.item.prev_pose_wc, p.item.pose_wc)
                    if p.motion is not None and p.item.prev_pose_wc is not None
                    else None
                )
            ),
            FRAME,
        ),
        "depth_holes": (_each(_depth_only(hole_share)), FRAME),
        "depth_noise": (
            _each(_depth_only(lambda d: noise_over_z2(inverse_depth(d[s // 2 :: s, s // 2 :: s]), edge_jump))),
            FRAME,
        ),
        "depth_registration": (_registration_pass(config), FRAME),
        "translation_sigma ... residual_over_gate, residual_shear, and the pose covariance (one information matrix)": (
            _each(
                lambda p: (
                    frame_geometry(
                        p.slam,
                        p.item.frame.intrinsics.matrix(),
                        p.item.frame.intrinsics.width,
                        p.item.frame.intrinsics.height,
                        p.item.frame.depth is not None,
                        config.observability,
                        p.item.pose_wc[:3, :3],
                    )
                    if p.slam is not None and p.item.pose_wc is not None
                    else None
                )
            ),
            FRAME,
        ),
        "flow_disagreement (second opinion; per hop frame)": (_second_opinion_pass(config.second_opinion), HOP),
        "PSD matrix": (_each(lambda p: extractor._psd(p.item, p.slam, p.normalisation, p.reference_gray)), PSD),
        "FeatureFrame encoding (stream)": (_each(lambda p: messages.encode(encoded[p.item.frame.index])), FRAME),
    }


def thread_ms_per_call(run: Callable[[Sequence[Prepared]], None], frames: Sequence[Prepared], repeats: int) -> float:
    """Median over ``repeats`` passes of the thread CPU ms per frame of ``frames``."""
    passes = []
    for _ in range(repeats):
        start = time.thread_time()
        run(frames)
        passes.append((time.thread_time() - start) * 1000.0 / max(len(frames), 1))
    return statistics.median(passes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--source", default=f"tum:{REPO / 'data' / 'sample'}", help="KIND:PATH (default the sample)")
    parser.add_argument("--mode", choices=[m.value for m in SlamMode], default=SlamMode.RGBD.value)
    parser.add_argument("--repeats", type=int, default=5, help="passes over the frames per row (median reported)")
    parser.add_argument("--json", type=Path, help="also write the figures to this file")
    parser.add_argument(
        "--flow-variants", action="store_true", help="also time the second opinion with other settings (see above)"
    )
    parser.add_argument(
        "--library-calls",
        action="store_true",
        help="also time the OpenCV and k-d tree calls inside the whole monitor (see above)",
    )
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    config = load_monitor_config()
    inputs = record_inputs(args.source, SlamMode(args.mode))
    # As in a device process (slam_monitor.monitor.create_observer): OpenCV on the calling thread, so that the thread
    # CPU time holds all of a channel's work.
    cv2.setNumThreads(1)
    frames = prepare(inputs, config)
    psd_frames = [p for p in frames if config.windows.is_psd_frame(p.item.frame.index)]
    # The frames as the device sends them: its device id and settings, a fresh stream session.
    device = replace_fields(config, device_id=resolve_device_id(config.device_id, args.source))
    extractor = FeatureExtractor(device, new_stream_session(), load_device_settings(args.mode, 30.0))
    encoded = {item.frame.index: extractor.extract(item) for item in inputs}
    rows: dict[str, dict[str, float]] = {}
    hops = sum(p.item.frame.index % config.second_opinion.hop_frames == 0 for p in frames)
    for label, (run, cadence) in stages(config, encoded).items():
        subset = psd_frames if cadence == PSD else frames
        per_frame = thread_ms_per_call(run, subset, args.repeats) * len(subset) / len(frames)
        per_call = per_frame * len(frames) / {FRAME: len(frames), PSD: len(psd_frames), HOP: hops}[cadence]
        rows[label] = {"per_call_ms": per_call, "per_frame_ms": per_frame}
    for label, with_logs, period_s in (
        ("monitor features, whole (FeatureExtractor.extract)", False, 0.0),
        ("monitor thread, whole (features, PSD, encoding, logs)", True, 0.0),
        (PACED_ROW, True, 1.0 / 30.0),
    ):
        per_frame = thread_ms_per_call(_whole_monitor(config, with_logs, period_s), frames, args.repeats)
        rows[label] = {"per_call_ms": per_frame, "per_frame_ms": per_frame}
    tracked = sum(p.motion is not None for p in frames)
    print(
        f"{len(frames)} frames ({tracked} tracked, {len(psd_frames)} PSD frames), {args.mode}, "
        f"{args.repeats} passes per row, load average {os.getloadavg()[0]:.2f} (1 min)"
    )
    print("| channel(s) | thread CPU ms per frame | per PSD or hop frame |")
    print("|---|---|---|")
    sparse = {label for label, (_, cadence) in stages(config, encoded).items() if cadence != FRAME}
    for label, row in rows.items():
        per_call = f"{row['per_call_ms']:.3f}" if label in sparse else ""
        print(f"| {label} | {row['per_frame_ms']:.3f} | {per_call} |")
    whole = rows["monitor thread, whole (features, PSD, encoding, logs)"]["per_frame_ms"]
    paced = rows[PACED_ROW]["per_frame_ms"]
    print(
        f"monitor thread: {whole:.2f} ms per frame = {whole * 30 / 10:.1f} % of a core at 30 Hz back to back; "
        f"{paced:.2f} ms = {paced * 30 / 10:.1f} % paced at 30 Hz, asleep between frames"
    )
    stream = stream_size(encoded.values())
    print(
        f"stream (device id {device.device_id!r}): {stream['plain_bytes']:.0f} B per frame without a PSD, "
        f"{stream['psd_bytes']:.0f} B with one, {stream['kbit_per_s']:.1f} kbit/s at 30 Hz with ZeroMQ's framing; "
        f"a PSD {stream['psd_stream_code_bytes']:.0f} B in the stream's code, "
        f"{stream['psd_log_code_bytes']:.0f} B in the log's"
    )
    figures: dict[str, object] = {"channels": rows, "stream": stream}
    if args.flow_variants:
        second_trial = prepare(record_inputs(args.source, SlamMode(args.mode)), config)
        variants = flow_variants(config, frames, second_trial, args.repeats)
        print("the second opinion (flow_disagreement) with other settings, one changed at a time:")
        print(
            "| setting | thread CPU ms per frame | frames with a value | median value (mm) "
            "| abs. difference median / p90 (mm) | ρ |"
        )
        print("|---|---|---|---|---|---|")
        for row in variants:
            print(
                f"| {row['setting']} | {row['ms_per_frame']:.3f} | {row['with_value']:.2f} | {row['median_mm']:.2f} | "
                f"{row['difference_median_mm']:.2f} / {row['difference_p90_mm']:.2f} | {row['spearman']:.3f} |"
            )
        figures["flow_variants"] = variants
    if args.library_calls:
        calls = library_calls(config, frames, args.repeats)
        print(
            "inside the compiled calls that define the channels, in the whole monitor thread back to back "
            "(the median of the passes):"
        )
        print("| call | thread CPU ms per frame |")
        print("|---|---|")
        for name, ms in calls.calls.items():
            print(f"| {name} | {ms:.3f} |")
        print(f"| these calls, together | {calls.library:.3f} |")
        print(f"| the rest (Python, numpy, zlib, logs) | {calls.rest:.3f} |")
        print(f"| monitor thread, whole, in these passes | {calls.whole:.3f} |")
        figures["library_calls"] = asdict(calls)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")


def stream_size(frames: Iterable[messages.FeatureFrame]) -> dict[str, float]:
    """Wire bytes of the feature stream's messages: per frame with and without a PSD, and kbit/s at 30 Hz."""
    sizes, psd_codes = {False: [], True: []}, {"stream": [], "log": []}
    for frame in frames:
        parts = messages.encode(frame)
        sizes[frame.psd is not None].append(sum(len(p) + zmtp_frame_overhead(len(p)) for p in parts))
        if frame.psd is not None:
            psd_codes["stream"].append(len(messages.pack_stream_psd(frame.psd)))
            psd_codes["log"].append(len(messages.pack_psd(frame.psd)))
    total = sum(sizes[False]) + sum(sizes[True])
    count = len(sizes[False]) + len(sizes[True])
    return {
        "plain_bytes": float(np.mean(sizes[False])),
        "psd_bytes": float(np.mean(sizes[True])),
        "kbit_per_s": total * 8 * 30 / count / 1000,
        "psd_stream_code_bytes": float(np.mean(psd_codes["stream"])),
        "psd_log_code_bytes": float(np.mean(psd_codes["log"])),
    }


if __name__ == "__main__":
    main()
