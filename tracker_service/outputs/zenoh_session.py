"""A Zenoh session's configuration: a JSON5 file (TLS, access control, routers) with the
endpoints and scouting that the service's configuration and command line add to it.

Nothing given anywhere is silently dropped, and TLS never silently becomes plaintext:

- endpoints add: the file's first, then the caller's (each once); with none anywhere the
  session listens nowhere (Zenoh's own default is a peer on ``tcp/[::]:0``, every
  interface, plaintext);
- scouting (multicast and gossip) is off unless asked for, by the caller or by the file
  setting it explicitly: peers are the endpoints named, not whoever answers on the LAN;
- a file that configures TLS (certificates or keys, a TLS-only protocol list, TLS-only
  endpoints) gets no plaintext endpoint from the caller unless the caller allows it;
- relative file names in the file (certificates, keys, password dictionary, known keys)
  are taken from the file's directory, so that a configuration directory can move (into
  a container's volume) with its certificates.
"""

from __future__ import annotations

import errno
import json
import os
import re
import socket
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Literal, get_args

import zenoh

from tracker_service.outputs.port_probe import bind_probe

__all__ = [
    "LISTEN_FIX",
    "TLS_PROTOCOLS",
    "Mode",
    "PlaintextEndpointError",
    "ZenohConfigError",
    "ZenohEndpointError",
    "check_listen_endpoints",
    "endpoint_protocol",
    "open_session",
    "zenoh_config",
    "zenoh_error",
]

Mode = Literal["peer", "client", "router"]

TLS_PROTOCOLS = frozenset({"tls", "quic"})
"""Link protocols that are TLS (QUIC carries TLS 1.3)."""

_TLS = "transport/link/tls"
_FILE_FIELDS = (
    *(
        f"{_TLS}/{name}"
        for name in (
            "root_ca_certificate",
            "listen_certificate",
            "listen_private_key",
            "connect_certificate",
            "connect_private_key",
        )
    ),
    "transport/auth/usrpwd/dictionary_file",
    "transport/auth/pubkey/public_key_file",
    "transport/auth/pubkey/private_key_file",
    "transport/auth/pubkey/known_keys_file",
)
"""Fields of a Zenoh configuration that name a file."""
_TLS_MATERIAL = _FILE_FIELDS[:5]
_SCOUTING = ("scouting/multicast/enabled", "scouting/gossip/enabled")
# zenoh's errors end with the Rust source location, which says nothing to an operator.
_RUST_LOCATION = re.compile(r"\s+at /\S+\.rs:\d+\.?")
_JSON5_MESSAGE = re.compile(r'msg: "(.*?)", location')


class ZenohConfigError(ValueError):
    """A Zenoh configuration that cannot be used; the message says why and the fix."""


class ZenohEndpointError(ZenohConfigError):
    """A session that cannot open an endpoint it was told to listen on (the port in use,
    an address not of this host): the message names the endpoint and the fix."""


_LISTENER = re.compile(r"bound to (\S+?): \[")
_HOST_PORT = re.compile(r"^\[?(?P<host>[^\]]*?)\]?:(?P<port>\d+)$")
_STREAM_PROTOCOLS = frozenset({"tcp", "tls", "ws"})
_DATAGRAM_PROTOCOLS = frozenset({"udp", "quic"})

LISTEN_FIX = "listen on another port (--zenoh-listen, [zenoh] listen)"
"""Where the service's own session's endpoints come from, for the errors below."""


def _endpoint_error(endpoint: str, in_use: bool, fix: str) -> ZenohEndpointError:
    """The one line for a listen endpoint that cannot be had: its port ``in_use``, or
    its address not one of this host's."""
    port = endpoint.rpartition(":")[2]
    if in_use:
        return ZenohEndpointError(
            f"zenoh listen endpoint {endpoint}: the port is already in use (a second "
            f"tracker-service?): stop it (`ss -tlpn 'sport = :{port}'` names it) or {fix}"
        )
    return ZenohEndpointError(
        f"zenoh listen endpoint {endpoint}: the address is not one of this host's: "
        "give one of its addresses, or 0.0.0.0 for all"
    )


def open_session(config: zenoh.Config, fix: str = LISTEN_FIX) -> zenoh.Session:
    """``zenoh.open(config)``; an endpoint it cannot listen on is a ``ZenohEndpointError``
    of one line, naming it and ``fix``."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        text = str(exc)
        found = _LISTENER.search(text)
        listen = json.loads(config.get_json("listen/endpoints"))
        endpoint = found.group(1) if found else ", ".join(map(str, listen)) or "?"
        if "Address already in use" in text:
            raise _endpoint_error(endpoint, True, fix) from None
        if "Cannot assign requested address" in text:
            raise _endpoint_error(endpoint, False, fix) from None
        raise


def check_listen_endpoints(config: zenoh.Config, fix: str = LISTEN_FIX) -> None:
    """Whether the session ``config`` describes could listen on its endpoints now: each
    with an address and a port is bound for a moment (``port_probe.bind_probe``). A
    ``ZenohEndpointError`` of one line, at start-up, rather than from ``open_session``
    after the process's warm-up (minutes on an empty numba cache). ``config`` is
    ``zenoh_config``'s (its endpoints one list); endpoints it cannot read (a Unix socket,
    a serial line) are left to ``open_session``."""
    for endpoint in json.loads(config.get_json("listen/endpoints")):
        protocol, _, rest = str(endpoint).partition("/")
        address = re.split(r"[?#]", rest, maxsplit=1)[0]
        found = _HOST_PORT.match(address)
        if found is None or protocol not in _STREAM_PROTOCOLS | _DATAGRAM_PROTOCOLS:
            continue
        host, port = found.group("host"), int(found.group("port"))
        if port == 0:
            continue
        kind = socket.SOCK_STREAM if protocol in _STREAM_PROTOCOLS else socket.SOCK_DGRAM
        try:
            bind_probe(host, port, kind)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise _endpoint_error(endpoint, True, fix) from None
            if exc.errno == errno.EADDRNOTAVAIL:
                raise _endpoint_error(endpoint, False, fix) from None
            # A name that does not resolve, a family this host lacks: Zenoh says at open.


class PlaintextEndpointError(ZenohConfigError):
    """A plaintext endpoint added to a configuration file that configures TLS."""

    def __init__(self, direction: Literal["listen", "connect"], endpoint: str, file: Path):
        self.direction = direction
        self.endpoint = endpoint
        self.file = file
        super().__init__(self.describe(f"{direction} endpoint", "allow plaintext explicitly"))

    @property
    def tls_endpoint(self) -> str:
        """The same address over TLS."""
        return "tls/" + self.endpoint.partition("/")[2]

    def describe(self, option: str, allow: str) -> str:
        """The one-line error, naming the option the endpoint came from and how to allow
        it when plaintext is really meant."""
        return (
            f"{option} {self.endpoint} is plaintext but {self.file} configures TLS: "
            f"use {option} {self.tls_endpoint}, or {allow} to add it anyway"
        )


def endpoint_protocol(endpoint: str) -> str:
    """``tcp`` of ``tcp/127.0.0.1:7447``."""
    return endpoint.partition("/")[0]


def zenoh_error(exc: Exception) -> str:
    """A Zenoh error's message without the Rust source locations."""
    text = str(exc)
    inner = _JSON5_MESSAGE.search(text)
    return _RUST_LOCATION.sub("", inner.group(1) if inner else text).strip()


def _get(config: zenoh.Config, key: str) -> object:
    value: object = json.loads(config.get_json(key))
    return value


def _set(config: zenoh.Config, key: str, value: object) -> None:
    config.insert_json5(key, json.dumps(value))


def _endpoints(config: zenoh.Config, key: str, mode: Mode) -> list[str]:
    """A file's endpoints for the session's mode (Zenoh allows a list or a list per
    mode); none when the file leaves Zenoh's default (a peer on ``tcp/[::]:0``)."""
    value = _get(config, key)
    if value == _get(zenoh.Config(), key):
        return []
    if isinstance(value, dict):
        value = value.get(mode)
    return [str(endpoint) for endpoint in value] if isinstance(value, list) else []


def _configures_tls(config: zenoh.Config, endpoints: Iterable[str]) -> bool:
    if any(_get(config, key) is not None for key in _TLS_MATERIAL):
        return True
    protocols = _get(config, "transport/link/protocols")
    if isinstance(protocols, list) and protocols and set(protocols) <= TLS_PROTOCOLS:
        return True
    protocols = {endpoint_protocol(endpoint) for endpoint in endpoints}
    return bool(protocols) and protocols <= TLS_PROTOCOLS


def _load(file: Path) -> zenoh.Config:
    try:
        config = zenoh.Config.from_file(str(file))
    except zenoh.ZError as exc:
        raise ZenohConfigError(
            f"{file}: not a usable Zenoh configuration: {zenoh_error(exc)}"
        ) from None
    for key in _FILE_FIELDS:
        name = _get(config, key)
        if not isinstance(name, str):
            continue
        path = Path(name) if Path(name).is_absolute() else (file.parent / name).absolute()
        # Zenoh would say so only when a link opens, in the output process, at length.
        if not path.is_file():
            raise ZenohConfigError(
                f"{file}: {key} {path}: no such file (certificates and keys: "
                "config/zenoh/make-certs.sh, docs/security.md)"
            )
        if not os.access(path, os.R_OK):
            raise ZenohConfigError(
                f"{file}: {key} {path}: not readable by this user (uid {os.getuid()}): "
                "give it read access (e.g. chown)"
            )
        _set(config, key, str(path))
    return config


def _file_mode(config: zenoh.Config) -> Mode:
    value = _get(config, "mode")
    return next((mode for mode in get_args(Mode) if mode == value), "peer")


def _refuse_plaintext(file: Path, listen: Sequence[str], connect: Sequence[str]) -> None:
    added: tuple[tuple[Literal["listen", "connect"], Sequence[str]], ...] = (
        ("listen", listen),
        ("connect", connect),
    )
    for direction, endpoints in added:
        for endpoint in endpoints:
            if endpoint_protocol(endpoint) not in TLS_PROTOCOLS:
                raise PlaintextEndpointError(direction, endpoint, file)


def _require_listen_certificate(config: zenoh.Config, listen: Iterable[str]) -> None:
    # Zenoh would say so when the listener opens, in the output process.
    if _get(config, f"{_TLS}/listen_certificate") and _get(config, f"{_TLS}/listen_private_key"):
        return
    for endpoint in listen:
        # An endpoint may carry its own TLS settings after '#'.
        if endpoint_protocol(endpoint) in TLS_PROTOCOLS and "#" not in endpoint:
            raise ZenohConfigError(
                f"listen endpoint {endpoint} is TLS but no certificate is configured: give "
                f"a Zenoh configuration file with {_TLS}/listen_certificate and "
                "listen_private_key (config/zenoh/service.json5, docs/security.md)"
            )


def _merged(first: Iterable[str], then: Iterable[str]) -> list[str]:
    return list(dict.fromkeys([*first, *then]))


def zenoh_config(
    mode: Mode | None = None,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | Path | None = None,
    *,
    scouting: bool = False,
    allow_plaintext: bool = False,
) -> zenoh.Config:
    """The session configuration: ``config_file`` when given, with ``listen`` and
    ``connect`` added to its endpoints (see the module's rules).

    ``mode`` None is the file's mode, or peer. ``scouting`` turns multicast and gossip
    scouting on; False leaves them off unless the file turns them on. Raises
    ``PlaintextEndpointError`` for a plaintext endpoint added to a TLS configuration
    (unless ``allow_plaintext``), ``ZenohConfigError`` for a file or an endpoint Zenoh
    refuses.
    """
    file = None if config_file is None else Path(config_file)
    if file is None:
        config = zenoh.Config()
        own_listen: list[str] = []
        own_connect: list[str] = []
        mode = mode or "peer"
    else:
        config = _load(file)
        mode = mode or _file_mode(config)
        own_listen = _endpoints(config, "listen/endpoints", mode)
        own_connect = _endpoints(config, "connect/endpoints", mode)
        if not allow_plaintext and _configures_tls(config, own_listen + own_connect):
            _refuse_plaintext(file, listen, connect)
    _require_listen_certificate(config, [*own_listen, *listen])
    try:
        _set(config, "mode", mode)
        _set(config, "listen/endpoints", _merged(own_listen, listen))
        _set(config, "connect/endpoints", _merged(own_connect, connect))
        for key in _SCOUTING:
            if scouting or _get(config, key) is None:
                _set(config, key, scouting)
    except zenoh.ZError as exc:
        raise ZenohConfigError(zenoh_error(exc)) from None
    return config
