"""ZeroMQ sockets as every SEESys part opens them, after the ZeroMQ guide's publish–subscribe patterns.

One function opens a socket, so every socket gets the same treatment:

- **Options before bind/connect.** ZeroMQ fixes high-water marks per connection when the connection is made, so an
  option set after ``bind`` or ``connect`` silently does nothing for it; :func:`open_socket` sets them all first.
- **LINGER 0**: closing never waits for unsent messages (a device that stops must stop; its own logs are on disk).
- **Exact topics.** Subscriptions are prefix matches; the topics of :mod:`seesys.core.messages` end in a
  terminator, so subscribing to ``messages.topic(kind, "dev-1")`` cannot also match ``dev-10``.
- **Clear failures**: a bind or connect that fails (address in use, malformed endpoint) is a
  :class:`TransportError` naming the endpoint and what it was for.
- **CurveZMQ clients**: :class:`ClientKeys` turns a client's key files (``seesys estimator keys``) into the socket
  options of an encrypted, authenticated connection to the estimator service; every client (device, advisory,
  study logger) connects the same way.

A PUB socket never blocks and never reports what it drops (no subscriber, or one past its high-water mark): a
sender cannot know its losses, so receivers count them from gaps in frame indices with :class:`LossCounter`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, overload

import zmq
import zmq.auth

from seesys.core.errors import SeesysError
from seesys.core.messages import FeatureFrame


class TransportError(SeesysError):
    """A ZeroMQ endpoint cannot be bound or connected."""


class CurveKeyError(SeesysError):
    """A Curve key file is missing or malformed."""


# Asked for the secret key, a caller gets one: a file without it is a CurveKeyError.
@overload
def load_curve_key(path: Path, secret: Literal[True]) -> tuple[bytes, bytes]: ...


@overload
def load_curve_key(path: Path, secret: bool) -> tuple[bytes, bytes | None]: ...


def load_curve_key(path: Path, secret: bool) -> tuple[bytes, bytes | None]:
    """The public and secret key of a ZeroMQ certificate file (``NAME.key``: public only; ``NAME.key_secret``:
    both); :class:`CurveKeyError` when it cannot be read, or holds no secret key where ``secret`` asks for one."""
    try:
        public_key, secret_key = zmq.auth.load_certificate(str(path))
    except (OSError, ValueError) as e:
        raise CurveKeyError(f"cannot read the Curve key file {path}: {e}") from None
    if secret and secret_key is None:
        raise CurveKeyError(f"{path} holds no secret key (pass the .key_secret file)")
    return public_key, secret_key


@dataclass(frozen=True)
class ClientKeys:
    """A client's key pair and the server's public key: what a device or subscriber needs to connect to a Curve
    server. The server refuses, during the handshake, a client whose public key it does not allow: such a client
    sends nothing that arrives and receives nothing."""

    secret_key_file: Path
    server_public_key_file: Path

    def socket_options(self) -> dict[int, bytes]:
        public, secret = load_curve_key(self.secret_key_file, secret=True)
        return {
            zmq.CURVE_PUBLICKEY: public,
            zmq.CURVE_SECRETKEY: secret,
            zmq.CURVE_SERVERKEY: load_curve_key(self.server_public_key_file, secret=False)[0],
        }


def open_socket(
    ctx: zmq.Context,
    socket_type: int,
    endpoint: str,
    what: str,
    *,
    bind: bool,
    send_hwm: int | None = None,
    receive_hwm: int | None = None,
    conflate: bool = False,
    subscribe: Iterable[bytes] = (),
    options: Mapping[int, int | bytes] | None = None,
) -> zmq.Socket:
    """A socket of ``socket_type`` with its options set, then bound to or connected to ``endpoint``.

    ``what`` names the socket's purpose in error messages. ``conflate`` keeps only the newest message (single-part
    messages only, a ZeroMQ restriction). ``subscribe`` lists SUB topics (``b""`` for everything). ``options`` are
    further ``zmq`` socket options (CurveZMQ keys, ROUTER_MANDATORY, ...), also set before bind/connect.
    """
    sock = ctx.socket(socket_type)
    sock.setsockopt(zmq.LINGER, 0)
    for option, value in (options or {}).items():
        sock.setsockopt(option, value)
    if send_hwm is not None:
        sock.setsockopt(zmq.SNDHWM, send_hwm)
    if receive_hwm is not None:
        sock.setsockopt(zmq.RCVHWM, receive_hwm)
    if conflate:
        sock.setsockopt(zmq.CONFLATE, 1)
    for topic in subscribe:
        sock.setsockopt(zmq.SUBSCRIBE, topic)
    try:
        if bind:
            sock.bind(endpoint)
        else:
            sock.connect(endpoint)
    except zmq.ZMQError as e:
        sock.close()
        action, hint = ("bind", " (is another one running?)") if bind else ("connect to", "")
        raise TransportError(f"cannot {action} the {what} endpoint {endpoint}: {e}{hint}") from None
    return sock


def publisher(
    ctx: zmq.Context,
    endpoint: str,
    what: str,
    send_hwm: int,
    bind: bool = True,
    options: Mapping[int, int | bytes] | None = None,
) -> zmq.Socket:
    """A PUB socket (bound by default: the side that outlives its peers binds)."""
    return open_socket(ctx, zmq.PUB, endpoint, what, bind=bind, send_hwm=send_hwm, options=options)


def subscriber(
    ctx: zmq.Context,
    endpoint: str,
    what: str,
    topics: Iterable[bytes],
    *,
    conflate: bool = False,
    receive_hwm: int | None = None,
    bind: bool = False,
    options: Mapping[int, int | bytes] | None = None,
) -> zmq.Socket:
    """A SUB socket for ``topics`` (connected by default; ZeroMQ reconnects it after its peer restarts)."""
    return open_socket(
        ctx,
        zmq.SUB,
        endpoint,
        what,
        bind=bind,
        receive_hwm=receive_hwm,
        conflate=conflate,
        subscribe=topics,
        options=options,
    )


def bound_endpoint(sock: zmq.Socket) -> str:
    """The endpoint a socket actually bound (with the port chosen for a wildcard ``tcp://host:*``)."""
    return sock.getsockopt_string(zmq.LAST_ENDPOINT)


@dataclass
class DeviceLoss:
    """One device's feature stream as a receiver saw it.

    ``skipped_by_device`` are frames the device tracked but never published (it says so in every message);
    ``lost_in_transit`` are the other frames missing between the first and the last one received (dropped by a
    high-water mark, or while the receiver was disconnected). ``out_of_order`` counts frames older than one
    already received (a device restart starts its indices again and is counted as such, not as a loss).
    """

    received: int = 0
    lost_in_transit: int = 0
    skipped_by_device: int = 0
    out_of_order: int = 0
    last_index: int = -1
    last_skipped: int = 0


@dataclass
class LossCounter:
    """Counts, per device, the feature frames that never reached this receiver, from gaps in frame indices."""

    devices: dict[str, DeviceLoss] = field(default_factory=dict)

    def observe(self, frame: FeatureFrame) -> int:
        """Account for ``frame``; returns how many frames were lost in transit just before it."""
        loss = self.devices.get(frame.device_id)
        if loss is None:
            self.devices[frame.device_id] = DeviceLoss(
                received=1, last_index=frame.frame_index, last_skipped=frame.frames_skipped
            )
            return 0
        loss.received += 1
        if frame.frame_index <= loss.last_index:
            loss.out_of_order += 1
            loss.last_index, loss.last_skipped = frame.frame_index, frame.frames_skipped
            return 0
        gap = frame.frame_index - loss.last_index - 1
        skipped = max(0, min(gap, frame.frames_skipped - loss.last_skipped))
        loss.skipped_by_device += skipped
        loss.lost_in_transit += gap - skipped
        loss.last_index, loss.last_skipped = frame.frame_index, frame.frames_skipped
        return gap - skipped

    @property
    def lost_in_transit(self) -> int:
        return sum(d.lost_in_transit for d in self.devices.values())


def peer_answers(endpoint: str, timeout_s: float, options: Mapping[int, int | bytes] | None = None) -> bool:
    """True when a ZeroMQ peer at ``endpoint`` completes a handshake within ``timeout_s`` (a SUB socket with
    ``options``, Curve keys included, connects and a socket monitor reports the handshake); False when nothing
    answers (connection refused, no route, a listener that is not ZeroMQ, Curve keys it refuses).

    A PUB endpoint sends nothing until there is something to publish, so its first message cannot tell that it is
    there; the handshake can."""
    from zmq.utils.monitor import recv_monitor_message

    ctx: zmq.Context = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    for option, value in (options or {}).items():
        sock.setsockopt(option, value)
    monitor = sock.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED)
    try:
        sock.connect(endpoint)
        return (
            bool(monitor.poll(int(timeout_s * 1000)))
            and recv_monitor_message(monitor)["event"] == zmq.EVENT_HANDSHAKE_SUCCEEDED
        )
    except zmq.ZMQError as e:
        raise TransportError(f"cannot connect to {endpoint}: {e}") from None
    finally:
        sock.disable_monitor()
        monitor.close()
        sock.close()
