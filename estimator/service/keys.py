"""CurveZMQ for the service: key pairs, the server's socket options, and the ZAP handler that lets in only the
clients whose public keys are in an allow-list folder (a client's options: :class:`ClientKeys`, from
:mod:`seesys.io.transport`, which every client uses).

Key files are ZeroMQ's certificate files (``NAME.key`` holds the public key, ``NAME.key_secret`` both), written by
:func:`make_key_pair` (``seesys estimator keys``). The server's sockets use its secret key; every client (device,
advisory, study logger) uses its own key pair and the server's public key. The allow-list is a folder of client
``.key`` files: the ZAP handler (pyzmq's :class:`zmq.auth.thread.ThreadAuthenticator`) refuses every other client
during the handshake, so such a client's messages never reach the service and it receives nothing.
"""

from __future__ import annotations

from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from seesys.io.transport import ClientKeys, CurveKeyError, load_curve_key

__all__ = ["ClientKeys", "CurveKeyError", "make_key_pair", "server_socket_options", "start_authenticator"]


def make_key_pair(folder: Path, name: str) -> tuple[Path, Path]:
    """Write ``NAME.key`` (public) and ``NAME.key_secret`` into ``folder``; refuses to overwrite a key pair."""
    folder = Path(folder)
    if (folder / f"{name}.key").exists() or (folder / f"{name}.key_secret").exists():
        raise CurveKeyError(f"a key pair named {name!r} already exists in {folder}")
    folder.mkdir(parents=True, exist_ok=True)
    public, secret = zmq.auth.create_certificates(str(folder), name)
    Path(secret).chmod(0o600)
    return Path(public), Path(secret)


def server_socket_options(secret_key_file: Path) -> dict[int, int | bytes]:
    """Options of a socket that accepts Curve clients (checked by the ZAP handler)."""
    public, secret = load_curve_key(Path(secret_key_file), secret=True)
    return {zmq.CURVE_SERVER: 1, zmq.CURVE_PUBLICKEY: public, zmq.CURVE_SECRETKEY: secret}


def start_authenticator(ctx: zmq.Context, allowed_clients: Path) -> ThreadAuthenticator:
    """The ZAP handler of ``ctx``: Curve clients whose public key is a ``.key`` file in ``allowed_clients``.

    Must run before the server's sockets bind; stop it after they close."""
    folder = Path(allowed_clients)
    if not folder.is_dir() or not any(folder.glob("*.key")):
        raise CurveKeyError(f"the allow-list folder {folder} holds no client public keys (*.key)")
    authenticator = ThreadAuthenticator(ctx)
    authenticator.start()
    authenticator.configure_curve(domain="*", location=str(folder))
    return authenticator
