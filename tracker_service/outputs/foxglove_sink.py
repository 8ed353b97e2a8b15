"""Foxglove as ``Sink``s: the map scene (``foxglove_scene.py``) into the MCAP log and,
live, through the Foxglove SDK's WebSocket server.

The log's Foxglove channels ride on the log's own output (``with_map_channels``: the
"mcap" sink, its thread, its failures: a full disk is one outage of the log, not two
outputs flapping on one file). The live view is an output of its own, "foxglove"
(``--foxglove-listen HOST:PORT``, open ``ws://HOST:PORT`` in the app), isolated like the
others. The SDK (``pip install 'tracker-service[foxglove]'``) is needed by the live view
only: it is a 19 MB compiled extension, so an optional extra rather than a dependency; the
log's channels are written without it.
"""

from __future__ import annotations

import functools
import json
import logging
from collections.abc import Sequence
from typing import Protocol

from asterix.containers import Datagram
from tracker_service.outputs.foxglove_scene import (
    CHANNELS,
    SCHEMAS,
    FoxgloveMessage,
    MapRadar,
    MapScene,
)
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.port_probe import bind_probe
from tracker_service.outputs.sink import Sink
from tracker_service.outputs.updates import LocalUpdate, SystemBatch, SystemUpdate

__all__ = [
    "FoxgloveListenError",
    "FoxgloveSink",
    "LiveServer",
    "McapChannels",
    "check_listen",
    "live_sink",
    "parse_listen",
    "with_map_channels",
]

log = logging.getLogger(__name__)

_NS_PER_S = 1_000_000_000


class FoxgloveListenError(ValueError):
    """A ``--foxglove-listen`` that cannot work: the message names it and the fix."""


class ChannelWriter(Protocol):
    def write(self, messages: Sequence[FoxgloveMessage]) -> None:
        """The messages, in order."""

    def close(self) -> None: ...


class McapChannels:
    """The scene's channels in the service's log (``McapLog``, closed by its owner)."""

    def __init__(self, log: McapLog) -> None:
        self.log = log

    def write(self, messages: Sequence[FoxgloveMessage]) -> None:
        """Each run of messages on one topic in one call of the log."""
        start = 0
        for end in range(1, len(messages) + 1):
            if end < len(messages) and messages[end].topic == messages[start].topic:
                continue
            first = messages[start]
            self.log.log_encoded_many(
                first.topic,
                first.schema,
                functools.partial(SCHEMAS.__getitem__, first.schema),
                [(m.data, m.time) for m in messages[start:end]],
            )
            start = end

    def close(self) -> None:
        """The log is its owner's to close."""


def parse_listen(text: str) -> tuple[str, int]:
    """ "HOST:PORT" (e.g. 127.0.0.1:8765, 0.0.0.0:8765) -> (host, port)."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise FoxgloveListenError(
            f"--foxglove-listen {text!r}: expected HOST:PORT, e.g. 127.0.0.1:8765"
        )
    return host.strip("[]"), int(port)


def check_listen(text: str) -> tuple[str, int]:
    """``parse_listen``, and whether the port can be had now and the SDK is installed:
    a one-line error at start-up rather than a failing output later."""
    host, port = parse_listen(text)
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise FoxgloveListenError(
            "--foxglove-listen needs the Foxglove SDK: pip install 'tracker-service[foxglove]'"
        ) from None
    if port:
        try:
            bind_probe(host, port)
        except OSError as exc:
            raise FoxgloveListenError(
                f"--foxglove-listen {text}: {exc.strerror or exc} (another tracker-service or "
                "Foxglove bridge there?): give another port"
            ) from None
    return host, port


class LiveServer:
    """The Foxglove SDK's WebSocket server (protocol ``foxglove.sdk.v1``), its own
    context, one JSON channel per topic with the scene's JSON schema. A client that
    subscribes gets the messages from then on: the picture within a second, the sites
    within ``MapScene.sites_period_s``."""

    def __init__(self, host: str, port: int, name: str = "tracker-service") -> None:
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()
        # Every channel before the server starts: each client is advertised them all when
        # it connects (a channel made while a client subscribes can be refused to it as
        # unknown, seen with SDK 0.30).
        self._channels = {
            topic: foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=schema, encoding="jsonschema", data=json.dumps(SCHEMAS[schema]).encode()
                ),
                message_encoding="json",
                context=self._context,
            )
            for topic, schema in CHANNELS.items()
        }
        try:
            self.server = foxglove.start_server(
                name=name, host=host, port=port, context=self._context
            )
        except RuntimeError as exc:
            raise FoxgloveListenError(f"--foxglove-listen {host}:{port}: {exc}") from None
        log.info("foxglove: live view on ws://%s:%d (open it in the Foxglove app)", host, self.port)

    @property
    def port(self) -> int:
        port: int = self.server.port
        return port

    def write(self, messages: Sequence[FoxgloveMessage]) -> None:
        for message in messages:
            self._channels[message.topic].log(
                message.data, log_time=round(message.time * _NS_PER_S)
            )

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()
        self.server.stop()


class FoxgloveSink:
    """The scene's messages to one ``ChannelWriter``; each call goes first to ``inner``,
    when given (the log's own sink, whose log the writer writes into)."""

    def __init__(
        self, name: str, writer: ChannelWriter, scene: MapScene, inner: Sink | None = None
    ) -> None:
        self.name = name
        self.writer = writer
        self.scene = scene
        self.inner = inner
        self.resends_tracks = False if inner is None else inner.resends_tracks
        self.keeps_datagrams = False if inner is None else inner.keeps_datagrams

    def _write(self, messages: list[FoxgloveMessage]) -> None:
        if messages:
            self.writer.write(messages)

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        if self.inner is not None:
            self.inner.datagram(input_name, datagram)

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        if self.inner is not None:
            self.inner.system(message, payload, time)
        self._write(self.scene.update(message, time))

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        if self.inner is not None:
            self.inner.local(message, payload, time)

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None:
        """A batch (``updates.py``): the inner sink takes it whole when it takes batches;
        the scene reads each update's values, no model built."""
        inner = self.inner
        batch = None if inner is None else getattr(inner, "system_updates", None)
        if batch is not None:
            batch(updates, time)
        elif inner is not None:
            for update in updates:
                inner.system(update.message(), update.payload, time)
        for batch in SystemBatch.runs(updates):
            self._write(self.scene.updates(batch, time))

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None:
        inner = self.inner
        if inner is None:
            return
        batch = getattr(inner, "local_updates", None)
        if batch is not None:
            batch(radar, updates, time)
            return
        for update in updates:
            inner.local(update.message(), update.payload, time)

    def asterix(self, data: bytes, time: float) -> None:
        if self.inner is not None:
            self.inner.asterix(data, time)
        # Once a second of data time: the picture goes on while no track updates.
        self._write(self.scene.tick(time))

    def bias(self, message: BiasMessage, time: float) -> None:
        if self.inner is not None:
            self.inner.bias(message, time)

    def status(self, message: StatusMessage, time: float) -> None:
        if self.inner is not None:
            self.inner.status(message, time)
        self._write(self.scene.tick(time))

    def close(self) -> None:
        try:
            self.writer.close()
        finally:
            if self.inner is not None:
                self.inner.close()


def with_map_channels(
    log_sink: Sink,
    log: McapLog,
    sites: Sequence[MapRadar],
    *,
    trail_s: float = 180.0,
    picture_period_s: float = 1.0,
) -> FoxgloveSink:
    """The log's sink (``McapSink``) with the scene's channels in the same ``log``: one
    output, named as the log's."""
    scene = MapScene(sites, trail_s=trail_s, picture_period_s=picture_period_s)
    return FoxgloveSink(log_sink.name, McapChannels(log), scene, inner=log_sink)


def live_sink(
    sites: Sequence[MapRadar],
    listen: str,
    *,
    trail_s: float = 180.0,
    picture_period_s: float = 1.0,
) -> FoxgloveSink:
    """The live view on ``listen`` ("HOST:PORT"): the output "foxglove"."""
    host, port = parse_listen(listen)
    scene = MapScene(sites, trail_s=trail_s, picture_period_s=picture_period_s)
    return FoxgloveSink("foxglove", LiveServer(host, port), scene)
