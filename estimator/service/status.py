"""``seesys estimator status``: ask a running service for its state and print it."""

from __future__ import annotations

import zmq

from estimator.service import envelope
from estimator.service.broker import ServiceError
from seesys.io.transport import open_socket


def query_status(endpoint: str, timeout_ms: int) -> dict:
    """The service's status; :class:`ServiceError` when it does not answer within ``timeout_ms``."""
    ctx: zmq.Context = zmq.Context.instance()
    sock = open_socket(ctx, zmq.REQ, endpoint, "estimator status", bind=False)
    try:
        sock.send(b"status")
        if not sock.poll(timeout_ms):
            raise ServiceError(
                f"no estimator service answered at {endpoint} within {timeout_ms} ms "
                f"(is `seesys estimator serve` running?)"
            )
        return envelope.unpack_json(sock.recv())
    finally:
        sock.close()


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _provider(name: str) -> str:
    """``CPUExecutionProvider`` → ``CPU``: the column stays narrow."""
    return name.removesuffix("ExecutionProvider")


def format_status(status: dict) -> str:
    """A plain-text report of :meth:`estimator.service.broker.Broker.status`."""
    lat = status["server_ms"]
    lines = [
        f"estimator service: model {status['model_version']}, up {status['uptime_s']:.0f} s, "
        f"Curve {'on' if status['curve'] else 'off'}, {status['estimates_per_s']:.1f} estimates/s, server "
        f"latency p50/p90/p99 {_ms(lat['p50'])}/{_ms(lat['p90'])}/{_ms(lat['p99'])} ms",
        "rejected messages: "
        + ", ".join(f"{k} {v}" for k, v in status["rejected"].items())
        + f"; refused workers {status['refused_workers']}",
        "where the time goes, p50 ms: "
        + (", ".join(f"{stage} {_ms(t['p50'])}" for stage, t in status["stages_ms"].items()) or "-"),
        "",
        f"{'worker':<24}{'pid':>8}{'provider':>10}{'devices':>9}{'queue':>7}{'estimates':>11}{'batch p50':>11}"
        f"{'batch p99':>11}{'mean batch':>12}",
    ]
    for w in status["workers"]:
        mean = "-" if w["batch_size_mean"] is None else f"{w['batch_size_mean']:.2f}"
        lines.append(
            f"{w['name']:<24}{w['pid']:>8}{_provider(w['provider']):>10}{len(w['devices']):>9}{w['queue_depth']:>7}"
            f"{w['estimates'] or 0:>11}{_ms(w['batch_ms_p50']):>11}{_ms(w['batch_ms_p99']):>11}{mean:>12}"
        )
    lines += [
        "",
        f"{'device':<20}{'worker':<16}{'frames/s':>9}{'est/s':>7}{'estimates':>10}{'lost':>6}"
        f"{'p50 ms':>8}{'p99 ms':>8}  dropped (by reason)",
    ]
    notes = []
    for name, d in status["devices"].items():
        lines.append(
            f"{name:<20}{d['worker'] or '-':<16}{d['frames_per_s']:>9.1f}{d['estimates_per_s']:>7.1f}"
            f"{d['estimates']:>10}{d['lost_in_transit']:>6}{_ms(d['server_ms']['p50']):>8}"
            f"{_ms(d['server_ms']['p99']):>8}  {dropped_text(d['dropped'])}"
        )
        if d.get("settings_refused"):
            notes.append(f"{name}: frames refused, settings differ from the model's: {d['settings_refused']}")
        if d.get("nonfinite"):
            notes.append(f"{name}: {d['nonfinite']} RTS values not finite (NaN, inf), given to the model as 0")
        if d.get("takeovers"):
            notes.append(
                f"{name}: id taken over {d['takeovers']} time(s) by a restarted device (stream session now "
                f"{d['stream_session']})"
            )
    return "\n".join(lines + ([""] + notes if notes else []))


def dropped_text(dropped: dict[str, int]) -> str:
    """Every non-zero drop reason by name, ``-`` for none."""
    return ", ".join(f"{reason} {n}" for reason, n in dropped.items() if n) or "-"
