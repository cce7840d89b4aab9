"""What one training step of each DeepSEE stage costs here, and how long the reduced and full schedules of
configs/estimator.toml take for a given number of training windows (projected from the step costs).

Steps are timed on random windows of the real shape (96 × 128 PSD, 30 × 16 RTS) with the configured model and
batch sizes: (a) PSD masked reconstruction, (b) TS2Vec, the encoder pass that fills the stage (c) cache, (c) a step
on cached encodings, (d) a full forward-backward step, and a validation forward pass. Data loading from the
dataset's memory maps is not included. The load average is printed: co-tenants slow every step.

Usage: ``.venv/bin/python benchmarks/estimator_training_cost.py [--windows 50000] [--steps 5] [--threads 2]
[--device cuda]`` (on a GPU every timed call ends with a device synchronisation, so the figures are wall time).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import torch

from estimator.deepsee.config import Schedule, load_estimator_config
from estimator.deepsee.export import example_inputs
from estimator.deepsee.ssl import PsdReconstruction, ts2vec_loss

sys.path.insert(0, str(Path(__file__).resolve().parent))
from estimator_inference import untrained_model


def seconds_per_call(call, steps: int, device: torch.device) -> float:
    def timed() -> None:
        call()
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    timed()
    start = time.perf_counter()
    for _ in range(steps):
        timed()
    return (time.perf_counter() - start) / steps


def step(loss_fn, parameters):
    """One optimizer step of ``loss_fn`` on ``parameters``, as a callable."""
    optimizer = torch.optim.AdamW(parameters, lr=1e-4)

    def call() -> None:
        loss = loss_fn()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    return call


def project(schedule: Schedule, costs: dict[str, float], windows: int, ablation: bool) -> dict[str, float]:
    """Minutes per stage for ``windows`` training windows (all epochs run; early stopping only shortens)."""
    train = windows if schedule.max_train_samples <= 0 else min(windows, schedule.max_train_samples)
    val = max(1, windows // 8) if schedule.max_validation_samples <= 0 else schedule.max_validation_samples

    def steps(s) -> int:
        full = math.ceil(train / s.batch_size)
        return s.epochs * (min(full, s.steps_per_epoch) if s.steps_per_epoch > 0 else full)

    frozen, finetune = (
        (schedule.ablation_frozen, schedule.ablation_finetune)
        if ablation
        else (schedule.supervised_frozen, schedule.finetune)
    )
    out = (
        {}
        if ablation
        else {
            "a": steps(schedule.psd_ssl) * costs["psd_ssl"] + schedule.psd_ssl.epochs * 512 * costs["validate"],
            "b": schedule.rts_ssl.iterations * costs["ts2vec"],
        }
    )
    out["cache"] = (train + val) * costs["encode"]
    out["c"] = steps(frozen) * costs["head"]
    out["d"] = steps(finetune) * costs["full"] + finetune.epochs * val * costs["validate"]
    return {k: v / 60 for k, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--windows", type=int, default=50000, help="training windows to project for")
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    config = load_estimator_config()
    reduced = config.schedules.reduced
    model = untrained_model(0).to(device).train()
    load_before = os.getloadavg()
    batch = reduced.finetune.batch_size
    rts, psd = (t.to(device) for t in example_inputs(model.shape, batch))
    y = torch.rand(batch, device=device)
    generator = torch.Generator().manual_seed(0)
    recon = PsdReconstruction(model.psd_encoder, model.config.dim).to(device)
    costs = {
        "psd_ssl": seconds_per_call(
            step(lambda: recon.loss(model.psd_input(psd), 0.5, generator), list(recon.parameters())), args.steps, device
        ),
        "ts2vec": seconds_per_call(
            step(
                lambda: ts2vec_loss(model.rts_encoder, rts[:16], 0.5, 0.5, generator),
                list(model.rts_encoder.parameters()),
            ),
            args.steps,
            device,
        ),
        "full": seconds_per_call(
            step(lambda: torch.nn.functional.mse_loss(model(rts, psd), y), list(model.parameters())), args.steps, device
        ),
    }
    with torch.no_grad():
        model.eval()
        costs["encode"] = seconds_per_call(lambda: model.encode(rts, psd), args.steps, device) / batch
        costs["validate"] = seconds_per_call(lambda: model(rts, psd), args.steps, device) / batch
        r, p = model.encode(rts, psd)
    model.train()
    head_batch = reduced.supervised_frozen.batch_size
    r, p = r.repeat(head_batch // batch, 1, 1), p.repeat(head_batch // batch, 1, 1)
    head = [q for name, q in model.named_parameters() if not name.startswith(("rts_encoder", "psd_encoder"))]
    costs["head"] = seconds_per_call(
        step(lambda: torch.nn.functional.mse_loss(model.head(r, p), torch.rand(len(r), device=device)), head),
        args.steps,
        device,
    )
    hardware = torch.cuda.get_device_name(device) if device.type == "cuda" else f"{args.threads} torch threads"
    print(
        f"{hardware}, {os.cpu_count()} cores; load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}"
    )
    print(
        "seconds per step: "
        + ", ".join(f"{k} {v:.3f}" for k, v in costs.items() if k not in ("encode", "validate"))
        + f"; per window: encode {1000 * costs['encode']:.1f} ms, validate {1000 * costs['validate']:.1f} ms"
    )
    for name in ("reduced", "full"):
        schedule = config.schedules.get(name)
        deepsee = project(schedule, costs, args.windows, ablation=False)
        ablation = project(schedule, costs, args.windows, ablation=True)
        print(
            f"{name}: DeepSEE {sum(deepsee.values()):.0f} min ("
            + ", ".join(f"{k} {v:.1f}" for k, v in deepsee.items())
            + f"); each ablation {sum(ablation.values()):.0f} min, for {args.windows} training windows"
        )


if __name__ == "__main__":
    main()
