"""The RTS monitor: an observer of the device worker that turns each tracked frame into a :class:`FeatureFrame`
(RTS row, and PSD on every frame that ends a model window: every ``end_stride``-th), logs it to the session
folder and publishes it on the feature stream.

Threading. :meth:`RtsMonitor.on_frame` runs in the tracking loop and only hands references to a bounded queue
(``queue_size``) with ``put_nowait``: tracking never waits for the monitor. When the queue is full the frame is
dropped and counted. The monitor's own thread does all the work (features, PSD, logs, stream); ORB-SLAM3
releases the GIL while it tracks, so the two run in parallel. An exception in the monitor thread stops the
monitor, not tracking; it is recorded in ``monitor_stats.json``.

Synchronisation. Everything in a FeatureFrame comes from one frame index: the image features from that frame's
gray image, the tracking features from the SLAM output of the same track call, and the relative motion from
that frame's pose and the pose of frame index − 1, which the tracking side records for every frame so that a
dropped frame never makes the motion span two frames.
"""

from __future__ import annotations

import json
import queue
import statistics
import threading
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from seesys.core import rts_schema
from seesys.core.camera import Intrinsics
from seesys.core.camera_normalisation import CameraNormalisation
from seesys.core.device_settings import DeviceSettings
from seesys.core.messages import FeatureFrame, stream_resolution
from seesys.core.psd import PsdGeometry, build_psd
from seesys.core.session_layout import POSE_COVARIANCE_COLUMNS, POSE_COVARIANCE_CSV, covariance_row
from seesys.core.tracking_state import TrackingState
from seesys.core.units import MM_PER_M
from seesys.io.config import replace_fields
from seesys.io.core_settings import load_device_settings
from seesys.io.logfiles import CsvLog
from seesys.io.network import load_network_config
from seesys.io.rts_log import PSD_DIR, RTS_CSV, PsdLogWriter, RtsCsvWriter
from slam_monitor.depth_features import DepthQuality
from slam_monitor.frame import Frame
from slam_monitor.image_features import image_features, keypoint_responses, reference_scale
from slam_monitor.local_map import LocalMap
from slam_monitor.monitor_config import MonitorConfig, load_monitor_config, resolve_device_id
from slam_monitor.observability import PoseObservability, frame_geometry
from slam_monitor.second_opinion import SecondOpinion
from slam_monitor.slam_features import RelativeMotion, SlamFeatures, project, relative_motion, slam_features, to_camera
from slam_monitor.stream import FeaturePublisher

MONITOR_STATS_JSON = "monitor_stats.json"


@dataclass(frozen=True)
class MonitorInput:
    """What the tracking loop hands to the monitor for one frame (references, no copies)."""

    frame: Frame
    state: TrackingState
    pose_cw: np.ndarray | None
    pose_wc: np.ndarray | None
    prev_pose_wc: np.ndarray | None
    num_tracked_points: int
    keypoints: np.ndarray
    map_points: np.ndarray
    map_changed: bool
    frames_skipped: int  # frames dropped before this one was queued: it travels with the frame's features

    @classmethod
    def of(cls, frame: Frame, result: Any, previous: PreviousPose, frames_skipped: int = 0) -> MonitorInput:
        """The input for ``frame`` and its :class:`slam_monitor.tracker.TrackOutput` ``result``; ``previous``
        follows the session's frames (called once per frame, in order)."""
        state = TrackingState(int(result.state))
        pose_wc = result.pose_wc if state.tracked else None
        return cls(
            frame,
            state,
            result.pose_cw,
            pose_wc,
            previous.step(frame.index, pose_wc),
            int(result.num_tracked_points),
            result.keypoints,
            result.map_points,
            bool(result.map_changed),
            frames_skipped,
        )


class PreviousPose:
    """The tracked pose of the frame before each frame, so that the relative motion never spans two frames: None
    when frame index − 1 was not tracked or never seen (dropped)."""

    def __init__(self) -> None:
        self._last: tuple[int, np.ndarray | None] = (-2, None)

    def step(self, index: int, pose_wc: np.ndarray | None) -> np.ndarray | None:
        """Record frame ``index``'s pose (None: not tracked) and return that of frame ``index`` − 1."""
        last_index, last_pose = self._last
        self._last = (index, pose_wc)
        return last_pose if last_index == index - 1 else None


def input_slam_features(
    item: MonitorInput, motion: RelativeMotion, lost_points_w: np.ndarray, config: MonitorConfig
) -> SlamFeatures:
    """The SLAM-side channels of a tracked frame's input (its pose, keypoints and matched points), with the map
    points recently seen but not matched (``lost_points_w``)."""
    if item.pose_cw is None:
        raise ValueError("a frame without a pose has no SLAM-side channels")
    intr, features = item.frame.intrinsics, config.features
    return slam_features(
        pose_cw=item.pose_cw,
        motion=motion,
        matched_inliers=item.num_tracked_points,
        keypoints=item.keypoints,
        matched_points_w=item.map_points,
        lost_points_w=lost_points_w,
        camera_matrix=intr.matrix(),
        width=intr.width,
        height=intr.height,
        match_gate_px=features.match_gate_px,
        min_depth=features.min_depth,
    )


class FeatureExtractor:
    """Single-threaded core of the monitor: one :class:`MonitorInput` in, one :class:`FeatureFrame` out.

    Holds the monitor's local map, so inputs must come in frame order. Every frame carries ``stream_session`` and
    ``settings`` (the device's settings a model depends on; see :mod:`seesys.core.device_settings`). Pixel-valued
    channels, the Laplacian and the PSD are camera-normalised to ``config.reference_camera``
    (:mod:`seesys.core.camera_normalisation`): the PSD grid is always the reference camera's.
    """

    def __init__(self, config: MonitorConfig, stream_session: int = 0, settings: DeviceSettings | None = None):
        self.config = config
        self.stream_session, self.settings = stream_session, settings
        lm = config.local_map
        self.local_map = LocalMap(lm.voxel, lm.max_age_frames, lm.max_points)
        reference = config.reference_camera
        self._geometry = PsdGeometry(reference.width, reference.height, config.psd.patch_px, config.psd.expansion)
        self._normalisation: CameraNormalisation | None = None
        self._depth_quality = DepthQuality(config.depth)
        self._second_opinion = SecondOpinion(config.second_opinion)

    def _normalised(self, intrinsics: Intrinsics) -> CameraNormalisation:
        if self._normalisation is None or self._normalisation.camera != intrinsics:
            self._normalisation = CameraNormalisation(self.config.reference_camera, intrinsics)
        return self._normalisation

    def extract(self, item: MonitorInput) -> FeatureFrame:
        return self.extract_with_covariance(item)[0]

    def extract_with_covariance(self, item: MonitorInput) -> tuple[FeatureFrame, np.ndarray | None]:
        """The frame's features, and its predicted 6×6 pose covariance in the world's axes where it has one
        (``slam_monitor.observability``: a tracked frame with three or more paired points)."""
        frame, cfg = item.frame, self.config
        index = frame.index
        intr = frame.intrinsics
        normalisation = self._normalised(intr)
        reference_gray = reference_scale(frame.gray, normalisation)
        channels: dict[str, float] = dict.fromkeys(rts_schema.CHANNEL_NAMES, float("nan"))
        # vars, not asdict: the fields are floats, and asdict's deep copy cost 0.2 ms a frame.
        channels.update(vars(image_features(frame.gray, reference_gray)))

        slam: SlamFeatures | None = None
        covariance: np.ndarray | None = None
        if item.state.tracked and item.pose_cw is not None and item.pose_wc is not None:
            if item.map_changed or item.prev_pose_wc is None:
                # A loop closure or global BA moved the map, or tracking resumes (maybe in a new map): the kept
                # point positions are stale.
                self.local_map.clear()
            self.local_map.update(item.map_points, index)
            motion = (
                relative_motion(item.prev_pose_wc, item.pose_wc)
                if item.prev_pose_wc is not None
                else RelativeMotion.still()
            )
            slam = input_slam_features(item, motion, self.local_map.lost_points(), cfg)
            channels.update(_slam_channels(slam, normalisation))
            seen, covariance = frame_geometry(
                slam,
                intr.matrix(),
                intr.width,
                intr.height,
                frame.depth is not None,
                cfg.observability,
                item.pose_wc[:3, :3],
            )
            channels.update(_geometry_channels(seen, normalisation))
        # A map change (loop closure, global BA) moves ORB-SLAM3's poses within the span: the span starts again.
        disagreement = self._second_opinion.update(
            index, frame.gray, frame.depth, item.keypoints, intr.matrix(), None if item.map_changed else item.pose_wc
        )
        if disagreement is not None:
            channels["flow_disagreement"] = disagreement * MM_PER_M
        moved = (
            np.linalg.inv(item.prev_pose_wc) @ item.pose_wc
            if item.pose_wc is not None and item.prev_pose_wc is not None and not item.map_changed
            else None
        )
        channels.update(vars(self._depth_quality.frame(frame.depth, frame.gray, intr, moved)))

        psd = self._psd(item, slam, normalisation, reference_gray) if cfg.windows.is_psd_frame(index) else None
        # At the stream's resolution (float16 where a value fits): rts.csv, the stream and a dataset hold one value.
        rts = stream_resolution(np.array([channels[name] for name in rts_schema.CHANNEL_NAMES], dtype=np.float32))
        features = FeatureFrame(
            cfg.device_id,
            index,
            frame.timestamp,
            item.state,
            rts,
            psd,
            item.frames_skipped,
            stream_session=self.stream_session,
            settings=self.settings,
            translation_covariance=covariance[:3, :3] if covariance is not None else None,
        )
        return features, covariance

    def _psd(
        self,
        item: MonitorInput,
        slam: SlamFeatures | None,
        normalisation: CameraNormalisation,
        reference_gray: np.ndarray,
    ) -> np.ndarray:
        intr, cfg = item.frame.intrinsics, self.config
        keypoints = np.asarray(item.keypoints, dtype=np.float64).reshape(-1, 2)
        map_uv, map_z = np.zeros((0, 2)), np.zeros(0)
        if slam is not None and item.pose_cw is not None:  # features of a tracked frame, which has a pose
            points_c = to_camera(self.local_map.points, item.pose_cw)
            points_c = points_c[points_c[:, 2] > cfg.features.min_depth]
            map_uv, map_z = project(points_c, intr.matrix()), points_c[:, 2]
        return build_psd(
            self._geometry,
            keypoints=normalisation.reference_px(keypoints),
            responses=keypoint_responses(reference_gray, normalisation.resampled_px(keypoints)),
            inliers=slam.inlier_keypoints if slam is not None else np.zeros(len(keypoints), dtype=bool),
            map_points_uv=normalisation.reference_px(map_uv),
            map_points_depth=map_z,
            near_depth=cfg.psd.near_depth,
        )


def _slam_channels(slam: SlamFeatures, normalisation: CameraNormalisation) -> dict[str, float]:
    m = slam.motion
    return {
        "matched_inliers": slam.matched_inliers,
        "outliers": slam.outliers,
        "matches_before_po": slam.matches_before_po,
        "rel_tx": m.translation[0],
        "rel_ty": m.translation[1],
        "rel_tz": m.translation[2],
        "rel_roll": m.roll,
        "rel_pitch": m.pitch,
        "rel_yaw": m.yaw,
        "avg_mp_depth": slam.avg_mp_depth,
        "var_mp_depth": slam.var_mp_depth,
        "local_mapping_visual_error": slam.reprojection_error_px / normalisation.pixel_ratio,
    }


def _geometry_channels(seen: PoseObservability, normalisation: CameraNormalisation) -> dict[str, float]:
    return {
        "translation_sigma": seen.translation_sigma_m * MM_PER_M,
        # Per mm² and inverted: a float16 holds them (the stream sends a row as float16 only if every value fits).
        "weakest_information": seen.weakest_information / MM_PER_M**2,
        "inverse_condition": 1.0 / seen.condition_number,
        "image_coverage": seen.image_coverage,
        "depth_spread": seen.depth_spread,
        "residual_median": seen.residual_median_px / normalisation.pixel_ratio,
        "residual_p90": seen.residual_p90_px / normalisation.pixel_ratio,
        "residual_over_gate": seen.residual_over_gate,
        "residual_shear": seen.residual_shear_px / normalisation.pixel_ratio,
    }


@dataclass
class MonitorStats:
    """What the monitor did in a session (written to ``monitor_stats.json``)."""

    frames_seen: int = 0
    frames_processed: int = 0
    frames_dropped: int = 0
    psd_matrices: int = 0
    first_timestamp: float = float("nan")
    last_timestamp: float = float("nan")
    monitor_ms_mean: float = float("nan")
    monitor_ms_median: float = float("nan")
    monitor_ms_p90: float = float("nan")
    monitor_cpu_ms_mean: float = float("nan")
    stream: dict[str, Any] | None = None
    stream_kbit_per_s: float = float("nan")
    error: str | None = None
    error_traceback: str | None = None
    monitor_ms: list[float] = field(default_factory=list, repr=False)
    monitor_cpu_ms: list[float] = field(default_factory=list, repr=False)

    def summary(self) -> dict[str, Any]:
        data = asdict(self)
        del data["monitor_ms"], data["monitor_cpu_ms"]
        return data


_STOP = object()


class MonitorStep:
    """The monitor's step of the per-frame chain, synchronous: a tracked frame → its feature frame, published first
    (when there is a publisher: the estimate waits for the message, not for the logs) and then logged to the
    session's ``rts.csv`` and ``psd/``, with the frame's predicted pose covariance in ``pose_covariance.csv`` (when
    there is a session folder). The device's :class:`RtsMonitor` runs it on
    its own thread; the simulated study calls it in its loop, so both write the same logs from the same code."""

    def __init__(
        self,
        config: MonitorConfig,
        session_dir: Path | None = None,
        publisher: FeaturePublisher | None = None,
        stream_session: int = 0,
        settings: DeviceSettings | None = None,
    ):
        self.publisher = publisher
        self.psd_matrices = 0
        self._extractor = FeatureExtractor(config, stream_session, settings)
        self._rts_log = RtsCsvWriter(session_dir / RTS_CSV, settings) if session_dir is not None else None
        self._psd_log = (
            PsdLogWriter(session_dir / PSD_DIR, config.log.psd_chunk_records) if session_dir is not None else None
        )
        self._covariance_log = (
            CsvLog(session_dir / POSE_COVARIANCE_CSV, POSE_COVARIANCE_COLUMNS) if session_dir is not None else None
        )

    def step(self, item: MonitorInput) -> FeatureFrame:
        features, covariance = self._extractor.extract_with_covariance(item)
        # No log depends on the stream.
        if self.publisher is not None:
            self.publisher.publish(features)
        if self._rts_log is not None:
            self._rts_log.write(features)
        if self._covariance_log is not None and covariance is not None:
            self._covariance_log.write(features.frame_index, features.timestamp, *covariance_row(covariance))
        if features.psd is not None:
            self.psd_matrices += 1
            if self._psd_log is not None:
                self._psd_log.write(features.frame_index, features.timestamp, features.psd)
        return features

    def close_logs(self) -> None:
        """Close the logs (their files final); the publisher is its owner's to close."""
        for log in (self._rts_log, self._psd_log, self._covariance_log):
            if log is not None:
                log.close()


class RtsMonitor:
    """Device-worker observer: ``on_frame`` from the tracking loop, ``close`` at the end of the session."""

    def __init__(
        self,
        config: MonitorConfig,
        session_dir: Path | None = None,
        publisher: FeaturePublisher | None = None,
        stream_session: int = 0,
        settings: DeviceSettings | None = None,
    ):
        self.config = config
        self.session_dir = session_dir
        self.publisher = publisher
        self.stats = MonitorStats()
        self._step = MonitorStep(config, session_dir, publisher, stream_session, settings)
        self._queue: queue.Queue = queue.Queue(maxsize=config.queue_size)
        self._previous = PreviousPose()
        self._thread = threading.Thread(target=self._run, name="rts-monitor", daemon=True)
        self._thread.start()

    def on_frame(self, frame: Frame, result: Any) -> None:
        """Hand one tracked frame to the monitor thread; never blocks (drops and counts when behind).

        ``result`` is the worker's :class:`slam_monitor.tracker.TrackOutput`.
        """
        self.stats.frames_seen += 1
        item = MonitorInput.of(frame, result, self._previous, self.stats.frames_dropped)
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.stats.frames_dropped += 1

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            if self.stats.error is not None:
                continue
            try:
                self._process(item)
            except Exception as e:  # a monitor bug must not stop tracking: recorded, the monitor stops
                self.stats.error = f"frame {item.frame.index}: {type(e).__name__}: {e}"
                self.stats.error_traceback = traceback.format_exc()

    def _process(self, item: MonitorInput) -> None:
        start, start_cpu = time.perf_counter(), time.thread_time()
        features = self._step.step(item)
        self.stats.psd_matrices = self._step.psd_matrices
        self.stats.monitor_ms.append((time.perf_counter() - start) * 1000.0)
        # CPU time of this thread: what the monitor costs, unlike wall time not inflated by waiting for a core
        self.stats.monitor_cpu_ms.append((time.thread_time() - start_cpu) * 1000.0)
        if self.stats.frames_processed == 0:
            self.stats.first_timestamp = features.timestamp
        self.stats.last_timestamp = features.timestamp
        self.stats.frames_processed += 1

    def close(self) -> MonitorStats:
        """Process what is queued, stop the thread, close logs and stream, write ``monitor_stats.json``.

        Never raises for a failure inside the monitor thread (the device worker must still finish its session
        files): such a failure is in ``stats.error`` / ``error_traceback`` and ``monitor_stats.json``.
        """
        self._queue.put(_STOP)
        self._thread.join()
        self._step.close_logs()
        if self.publisher is not None:
            self.stats.stream = asdict(self.publisher.stats)
            frames = self.stats.frames_processed
            span = self.stats.last_timestamp - self.stats.first_timestamp
            if frames > 1 and span > 0:
                # At the camera's rate, whatever the pacing: bits over the sequence time the frames cover.
                duration_s = span * frames / (frames - 1)
                self.stats.stream_kbit_per_s = self.publisher.stats.wire_bytes * 8 / 1000 / duration_s
            self.publisher.close()
        times = self.stats.monitor_ms
        if times:
            self.stats.monitor_ms_mean = statistics.fmean(times)
            self.stats.monitor_ms_median = statistics.median(times)
            self.stats.monitor_ms_p90 = float(np.percentile(times, 90))
            self.stats.monitor_cpu_ms_mean = statistics.fmean(self.stats.monitor_cpu_ms)
        if self.session_dir is not None:
            (self.session_dir / MONITOR_STATS_JSON).write_text(json.dumps(self.stats.summary(), indent=2) + "\n")
        return self.stats


def create_observer(
    context: Any, stream: bool = False, device_id: str | None = None, end_stride: int | None = None
) -> RtsMonitor:
    """Observer factory for :class:`slam_monitor.device_worker.ObserverSpec`: a monitor logging into the
    session folder and, when ``stream`` is true, publishing on ``features_endpoint`` of network.toml (and to the
    estimator service's ``ingest_endpoint``, encrypted, when its ``[curve]`` is set).
    ``device_id`` replaces the one of monitor.toml (``auto`` there: :func:`resolve_device_id` of the source);
    ``end_stride`` the windows' end stride of windows.toml (the dataset builder computes the PSD on every frame,
    ``end_stride = 1``; a stride that does not divide ``psd_stride`` raises ``ValueError``). Frames carry the
    session's stream session and the device's settings (mode, frame rate, ORB features, PSD)."""
    # OpenCV's own threads (the second opinion's flow and PnP, the image statistics) would take the cores ORB-SLAM3
    # tracks on, and their work would not count in the monitor thread's CPU time: the monitor runs on its one thread.
    cv2.setNumThreads(1)
    config_dir = context.options.config_dir
    config = load_monitor_config(config_dir)
    config = replace_fields(config, device_id=resolve_device_id(device_id or config.device_id, context.options.source))
    if end_stride is not None:
        config = replace_fields(config, windows=replace_fields(config.windows, end_stride=end_stride))
    publisher = None
    if stream:
        network = load_network_config(config_dir)
        publisher = FeaturePublisher.for_network(network)
    settings = load_device_settings(context.mode.value, context.fps, config_dir)
    return RtsMonitor(config, context.out_dir, publisher, context.stream_session, settings)
