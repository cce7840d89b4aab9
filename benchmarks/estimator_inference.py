"""DeepSEE inference cost on the CPU: eager PyTorch against ONNX Runtime, at batch 1 and batched.

For each runtime and batch size it prints the median and p99 latency of one call and the throughput (samples/s =
batch / median latency), on ``--threads`` intra-op threads (default 1, the serving setting: a second thread helps
little on a 2-core box and backfires when anything else runs). The model is a trained checkpoint (``--model``,
default the shipped one) or, with ``--untrained``, a model of configs/estimator.toml's size with random weights
(latency does not depend on the weight values). It is exported to ONNX (weights inside the file) and the parity of
the two runtimes is checked first. The load average before and after is printed: co-tenants inflate the p99.

Usage: ``.venv/bin/python benchmarks/estimator_inference.py [--model M.pt | --untrained] [--runs 300]
[--batch 32] [--threads 1]``
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from estimator.artefact.transforms import LabelTransform
from estimator.deepsee.checkpoint import load_model
from estimator.deepsee.config import load_estimator_config
from estimator.deepsee.export import OnnxModel, example_inputs, export_onnx, parity
from estimator.deepsee.model import DeepSEE, InputShape
from seesys.core import rts_schema
from seesys.core.psd import PsdGeometry
from seesys.io import resources
from seesys.io.core_settings import load_window_config
from slam_monitor.monitor_config import load_monitor_config

WARMUP = 20


def untrained_model(seed: int) -> DeepSEE:
    windows = load_window_config()
    monitor = load_monitor_config()
    camera, psd = monitor.reference_camera, monitor.psd  # every camera's PSD is on the reference camera's grid
    rows, cols, _ = PsdGeometry(camera.width, camera.height, psd.patch_px, psd.expansion).shape
    torch.manual_seed(seed)
    shape = InputShape(windows.rts_length, rts_schema.NUM_CHANNELS, windows.psd_samples, rows, cols)
    return DeepSEE(load_estimator_config().model, shape).eval()


def timings(call, runs: int) -> np.ndarray:
    for _ in range(WARMUP):
        call()
    out = np.empty(runs)
    for k in range(runs):
        start = time.perf_counter()
        call()
        out[k] = time.perf_counter() - start
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, help="model checkpoint (default: the shipped model)")
    parser.add_argument("--untrained", action="store_true", help="random weights of the configured size")
    parser.add_argument("--runs", type=int, default=300, help="timed calls at batch 1 (a tenth at the batch size)")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    torch.set_num_interop_threads(1)
    transform = LabelTransform(load_estimator_config().label_transform.k)
    windows = load_window_config()
    if args.untrained:
        model, source = untrained_model(0), "untrained (configs/estimator.toml size)"
    else:
        path = args.model or resources.resolve(load_estimator_config().shipped_model)
        model, source = load_model(path, transform, windows)[0], str(path)
    params = sum(p.numel() for p in model.parameters())
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        onnx_model = OnnxModel(
            export_onnx(model, Path(tmp) / "m.onnx", windows, transform), transform, windows, threads=args.threads
        )
        difference = parity(model, onnx_model)
        print(f"model: {source}; {params / 1e6:.2f} M parameters; input {model.shape}")
        print(
            f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
            f"{args.threads} intra-op thread(s); torch {torch.__version__}; ONNX Runtime parity {difference:.1e}"
        )
        print(f"load average before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}")
        print(f"{'runtime':<14}{'batch':>6}{'p50 ms':>10}{'p99 ms':>10}{'samples/s':>12}")
        for batch, runs in ((1, args.runs), (args.batch, max(10, args.runs // 10))):
            rts, psd = example_inputs(model.shape, batch, seed=batch)
            with torch.inference_mode():
                eager = timings(lambda rts=rts, psd=psd: model(rts, psd), runs)
            rts_np, psd_np = rts.numpy(), psd.numpy()
            ort = timings(lambda rts_np=rts_np, psd_np=psd_np: onnx_model(rts_np, psd_np), runs)
            for name, t in (("eager torch", eager), ("onnxruntime", ort)):
                p50, p99 = np.percentile(t, [50, 99]) * 1000
                print(f"{name:<14}{batch:>6}{p50:>10.2f}{p99:>10.2f}{batch / (p50 / 1000):>12.0f}")
    load_after = os.getloadavg()
    print(f"load average after: {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")


if __name__ == "__main__":
    main()
