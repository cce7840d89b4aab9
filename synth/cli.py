"""``seesys synth``: render synthetic sequences (``render``, ``batch``)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from seesys.core.errors import SeesysError
from synth.batch import expand_environments, expand_motions, render_batch
from synth.config import load_synth_config
from synth.sequence import SequenceSpec, render_sequence


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"image size {text} is too small")
    return w, h


def _add_render_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", type=int, help="frames per sequence (default: the configured duration)")
    p.add_argument(
        "--size",
        type=_size,
        help="image size WIDTHxHEIGHT (default: the camera model's, else configs/synth.toml camera)",
    )
    p.add_argument("--processes", type=int, help="worker processes (default: configs/synth.toml)")
    p.add_argument("--no-blur", action="store_true", help="render without motion blur")
    p.add_argument("--distortion", action="store_true", help="apply the configured lens distortion")


def _template(args: argparse.Namespace, environment: str, motion: str, seed: int) -> SequenceSpec:
    if args.frames is not None and args.frames < 1:
        raise SeesysError("--frames must be at least 1")
    width, height = args.size or (None, None)
    return SequenceSpec(environment, motion, seed, args.frames, width, height, not args.no_blur, args.distortion)


def _render(args: argparse.Namespace) -> int:
    config = load_synth_config()
    spec = _template(args, args.env, args.motion, args.seed)
    start = time.perf_counter()
    records = render_sequence(spec, config, args.out, args.processes)
    seconds = time.perf_counter() - start
    workers = args.processes or config.processes
    print(
        f"rendered {len(records)} frames to {args.out} in {seconds:.1f} s: {len(records) / seconds:.1f} frames/s "
        f"on {workers} process(es)"
    )
    return 0


def _batch(args: argparse.Namespace) -> int:
    config = load_synth_config()
    environments = expand_environments(args.envs.split(","), config)
    motions = expand_motions(args.motions.split(","), config)
    seeds = [int(s) for s in args.seeds.split(",")]
    result = render_batch(
        _template(args, environments[0], motions[0], seeds[0]),
        environments,
        motions,
        seeds,
        config,
        args.out,
        args.processes,
    )
    print(
        f"rendered {len(result.rendered)} sequences ({result.frames} frames, {result.frames_per_second:.1f} "
        f"frames/s), skipped {len(result.skipped)} already complete, under {args.out}"
    )
    return 0


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add ``seesys synth`` to the command line; return its subcommands, to which a part above adds its own."""
    synth = subparsers.add_parser("synth", help="render synthetic training sequences and report on them")
    sub = synth.add_subparsers(dest="synth_command", metavar="SYNTH_COMMAND", required=True)

    p = sub.add_parser("render", help="render one sequence (TUM RGB-D folder) in a procedural environment")
    p.add_argument("--env", required=True, help="environment preset (configs/synth.toml)")
    p.add_argument("--motion", required=True, help="patrol | aiming | rapid | scan | real:<trajectory name>")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    _add_render_options(p)
    p.set_defaults(func=_render)

    p = sub.add_parser("batch", help="render environments × motions × seeds, one folder each (resumable)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--envs", default="all", help="comma-separated presets, or all (default)")
    p.add_argument(
        "--motions",
        default="patrol,aiming,rapid",
        help="comma-separated motions: patrol, aiming, rapid, scan, real:<name>, real (every real one), all",
    )
    p.add_argument("--seeds", default="0", help="comma-separated batch seeds")
    _add_render_options(p)
    p.set_defaults(func=_batch)

    return {"synth": sub}
