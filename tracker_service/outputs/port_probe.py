"""Whether a listening port can be had now, asked at start-up so that a port in use is
one line then rather than an output failing later (the live map's server, Zenoh's
listeners)."""

from __future__ import annotations

import socket

__all__ = ["bind_probe"]


def bind_probe(host: str, port: int, kind: socket.SocketKind = socket.SOCK_STREAM) -> None:
    """Binds ``host``:``port`` for a moment; ``OSError`` when it cannot be had. Bound, not
    listening: a client that tries the port meanwhile is refused, not accepted by the
    probe and reset. ``SO_REUSEADDR`` as the servers bind (the Foxglove SDK's, Zenoh's
    tokio listeners): a port left in TIME_WAIT by a service just stopped is free, one
    listened on is not."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, kind) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind((host, port))
