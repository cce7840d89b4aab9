"""``seesys advisory`` subcommands: thin wrappers over the advisory library."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from advisory.conditions import LIVE_CONDITIONS, Condition, pulse_rule
from advisory.config import load_advisory_config
from advisory.estimate_log import read_estimate_log
from advisory.wav import WavWriter
from seesys.io.network import load_network_config
from seesys.io.processes import stop_on_signals

_CONDITIONS = list(LIVE_CONDITIONS)


def _out_dir(args: argparse.Namespace, cfg) -> Path:
    return Path(args.out) if args.out else Path(cfg.supervisor.session_folder)


def _run(args: argparse.Namespace) -> int:
    from advisory.supervisor import supervise

    cfg = load_advisory_config()
    with stop_on_signals() as stop:
        supervise(cfg, Condition(args.condition), _out_dir(args, cfg), stop)
    return 0


def _generator(args: argparse.Namespace) -> int:
    from advisory.generator import Generator

    cfg = load_advisory_config()
    generator = Generator(cfg, load_network_config(), Condition(args.condition), _out_dir(args, cfg))
    with stop_on_signals() as stop:
        generator.run(stop)
    return 0


def _player(args: argparse.Namespace) -> int:
    from advisory.player import Player

    cfg = load_advisory_config()
    player = Player(cfg, _out_dir(args, cfg), Path(args.capture) if args.capture else None)
    with stop_on_signals() as stop:
        player.run(stop)
    return 0


def _pulses(args: argparse.Namespace) -> int:
    condition = Condition.ROTATION if args.rotation else Condition.SEESYS
    print(pulse_rule(condition, load_advisory_config())(args.value))
    return 0


def _render(args: argparse.Namespace) -> int:
    from advisory.render import render_estimates

    cfg = load_advisory_config()
    rendering = render_estimates(read_estimate_log(Path(args.estimates)), cfg)
    wav = WavWriter(Path(args.out), cfg.audio.sample_rate)
    wav.write(rendering.samples)
    wav.close()
    pulses = sum(d.n_pulses for d in rendering.decisions)
    print(
        f"{args.out}: {rendering.samples.size / cfg.audio.sample_rate:.2f} s, "
        f"{len(rendering.decisions)} buffers, {pulses} pulses"
    )
    return 0


def _replay(args: argparse.Namespace) -> int:
    from advisory.replay import replay_estimates

    log = read_estimate_log(Path(args.estimates))
    sent_log = Path(args.sent_log) if args.sent_log else None
    sent = replay_estimates(
        log,
        load_advisory_config().replay,
        load_network_config(),
        show_progress=True,
        sent_log=sent_log,
        start_with_device=args.start_with_device,
    )
    print(f"published {sent} estimates" + (f"; send times in {sent_log}" if sent_log else ""))
    return 0


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite non-negative number, got {text}")
    return value


def register(subparsers: argparse._SubParsersAction) -> dict[str, argparse._SubParsersAction]:
    """Add this part's commands to the ``seesys`` command line."""
    parser = subparsers.add_parser("advisory", help="the audio error advisory (Equation 2, the study conditions)")
    commands = parser.add_subparsers(dest="advisory_command", metavar="COMMAND", required=True)

    out_help = "session folder for the logs (default: configs/advisory.toml session_folder)"
    p = commands.add_parser("run", help="run the generator and the player processes, restarting them if they exit")
    p.add_argument("--condition", choices=_CONDITIONS, required=True)
    p.add_argument("--out", help=out_help)
    p.set_defaults(func=_run)

    p = commands.add_parser("generator", help="run the receiver/generator process alone")
    p.add_argument("--condition", choices=_CONDITIONS, required=True)
    p.add_argument("--out", help=out_help)
    p.set_defaults(func=_generator)

    p = commands.add_parser("player", help="run the player process alone")
    p.add_argument("--out", help=out_help)
    p.add_argument("--capture", metavar="WAV", help="also write what the stream played to this WAV file")
    p.set_defaults(func=_player)

    p = commands.add_parser("pulses", help="print the number of pulses N for an error (or a rotation speed)")
    p.add_argument("value", type=_non_negative, help="pose error in metres (or °/s with --rotation)")
    p.add_argument("--rotation", action="store_true", help="apply the rotation rule to a speed in °/s")
    p.set_defaults(func=_pulses)

    p = commands.add_parser("render", help="render what a listener hears for an estimate log to a WAV file")
    p.add_argument("--estimates", required=True, metavar="CSV", help="CSV with columns timestamp,error_m")
    p.add_argument("--out", required=True, metavar="WAV")
    p.set_defaults(func=_render)

    p = commands.add_parser("replay", help="publish an estimate log over ZeroMQ at its original pace")
    p.add_argument("--estimates", required=True, metavar="CSV", help="CSV with columns timestamp,error_m")
    p.add_argument(
        "--sent-log",
        metavar="CSV",
        help="also write each estimate's send time to this CSV (frame_index,timestamp,sent_mono); it appears "
        "once the publisher is bound",
    )
    p.add_argument(
        "--start-with-device",
        metavar="ID",
        help="begin the schedule when this device's first feature frame arrives (features_endpoint)",
    )
    p.set_defaults(func=_replay)
    return {}
