"""The project's embedded demo sample (``data/sample``), made by the project's own generator.

:func:`make_sample` renders one short sequence (``[sample]`` of configs/dataset.toml) in the TUM RGB-D layout and
re-encodes its gray frames as JPEG, so that the sample stays small enough to ship in the repository; depth stays
lossless 16-bit PNG. The vocabulary shipped beside it is trained on the sample's frames with
``seesys vocab train --source tum:data/sample --out data/vocabulary/<name>.txt`` (docs/dataset.md).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2

from estimator.dataset.config import SampleSequenceConfig
from seesys.core.errors import SeesysError
from slam_monitor.orbslam_settings import load_slam_config
from synth.config import SynthConfig
from synth.sequence import SequenceSpec, render_sequence

RGB_LISTS = ("rgb.txt", "associations.txt")
README = "README.md"


@dataclass(frozen=True)
class SampleResult:
    folder: Path
    frames: int
    bytes: int


def _reencode(folder: Path, jpeg_quality: int) -> None:
    """Gray PNG frames → JPEG (the list files follow); depth PNGs → maximum lossless compression."""
    for png in sorted((folder / "rgb").glob("*.png")):
        image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if image is None or not cv2.imwrite(
            str(png.with_suffix(".jpg")), image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality]
        ):
            raise SeesysError(f"cannot re-encode {png} as JPEG")
        png.unlink()
    for png in sorted((folder / "depth").glob("*.png")):
        depth = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        if depth is None or not cv2.imwrite(str(png), depth, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            raise SeesysError(f"cannot re-compress {png}")
    for name in RGB_LISTS:
        path = folder / name
        path.write_text(_rgb_names_to_jpeg(path.read_text()))


def _rgb_names_to_jpeg(text: str) -> str:
    """In ``rgb.txt`` and ``associations.txt`` the gray image is the second field of every data line."""
    lines = []
    for line in text.splitlines():
        fields = line.split()
        if len(fields) >= 2 and not line.startswith("#"):
            fields[1] = fields[1].replace(".png", ".jpg")
            line = " ".join(fields)
        lines.append(line)
    return "\n".join(lines) + "\n"


def make_sample(config: SampleSequenceConfig, synth: SynthConfig, out: Path) -> SampleResult:
    """Render the sample sequence into ``out`` (replaced), re-encode it and write its README."""
    vocabulary = load_slam_config().vocabulary
    staging = out.with_name(out.name + ".partial")
    shutil.rmtree(staging, ignore_errors=True)
    spec = SequenceSpec(config.environment, config.motion, config.seed, config.frames)
    records = render_sequence(spec, synth, staging)
    _reencode(staging, config.jpeg_quality)
    (staging / "render_log.csv").unlink(missing_ok=True)
    (staging / README).write_text(
        f"# Embedded sample: {len(records)} frames rendered by the project's generator, RGB-D, with ground truth\n\n"
        f"Made with `seesys dataset sample --out {out}` ([sample] of configs/dataset.toml: environment "
        f"`{config.environment}`, motion `{config.motion}`, seed {config.seed}, {config.frames} frames at "
        f"{synth.camera.lens.width}x{synth.camera.lens.height}, {synth.camera.fps:g} Hz), TUM RGB-D layout, so that "
        f"the demo and the tests need no download.\n\n"
        f"- `rgb/*.jpg`: 8-bit gray, JPEG quality {config.jpeg_quality} (the rendered PNGs re-encoded to keep the "
        f"sample small).\n- `depth/*.png`: 16-bit z-depth, metres x {synth.camera.depth_factor:g}.\n"
        f"- `groundtruth.txt`: T_world_camera, camera optical frame; `calibration.yaml`; `metadata.json`: the "
        f"environment, trajectory and sensor draws.\n\n"
        f"The project's vocabulary (`vocabulary` of configs/slam.toml) is trained on the embedded sample's frames: "
        f"`seesys vocab train --source tum:data/sample --out {vocabulary}`.\n"
    )
    shutil.rmtree(out, ignore_errors=True)
    staging.rename(out)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return SampleResult(out, len(records), size)
