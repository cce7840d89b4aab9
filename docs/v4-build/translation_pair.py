"""How much the label pair's σ changes when it is taken from the two frames' translation blocks alone, as a client
of the estimates has them (seesys.core.pose_covariance.translation_pair_covariance), instead of the full 6×6
covariances with the first frame's rotation (relative_translation_covariance, as seesys session export-bag and
seesys dataset coverage take it): the ratio of the two σ over every window-end pair of a build's kept sessions.

    .venv/bin/python docs/v4-build/translation_pair.py BUILD
"""

import sys
from pathlib import Path

import numpy as np

from seesys.core import session_layout
from seesys.core.pose_covariance import relative_translation_covariance, translation_pair_covariance
from seesys.io.core_settings import load_label_config, load_window_config
from seesys.io.rts_log import read_pose_covariance_log
from seesys.io.trajectory_files import read_tum

delta, stride = load_label_config().delta_frames, load_window_config().end_stride
ratios = []
for session in sorted((Path(sys.argv[1]) / "sessions").iterdir()):
    logged = read_pose_covariance_log(session)
    covariance = logged.by_frame()
    position = logged.positions(read_tum(session / session_layout.TRAJECTORY))
    for j in range(delta, int(logged.frame_index.max()) + 1, stride):
        i = j - delta
        if all(k in covariance and k in position for k in (i, j)):
            full = relative_translation_covariance(covariance[i], covariance[j], position[i], position[j])
            blocks = translation_pair_covariance(covariance[i][:3, :3], covariance[j][:3, :3])
            ratios.append(np.sqrt(np.trace(blocks) / np.trace(full)))
ratio = np.array(ratios)
print(f"{len(ratio)} window-end pairs; σ from the translation blocks / σ of the full pair:")
print("percentile 1, 5, 50, 95, 99: " + ", ".join(f"{v:.3f}" for v in np.percentile(ratio, [1, 5, 50, 95, 99])))
print(f"within ±5 %: {np.mean(np.abs(ratio - 1) <= 0.05):.3f}; min {ratio.min():.3f}, max {ratio.max():.3f}")
