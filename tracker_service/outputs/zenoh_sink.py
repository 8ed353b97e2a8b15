"""The Zenoh output as a ``Sink``: each message on its key of ``ZenohPublisher``."""

from __future__ import annotations

from collections.abc import Sequence

from asterix.containers import Datagram
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.updates import LocalUpdate, SystemUpdate
from tracker_service.outputs.zenoh_out import ZenohPublisher

__all__ = ["ZenohSink"]


def _sac_sic(radar: str) -> tuple[int, int]:
    sac, sic = radar.split("/")
    return int(sac), int(sic)


class ZenohSink:
    """Publishes on ``publisher``, which its owner closes."""

    name = "zenoh"
    resends_tracks = True
    keeps_datagrams = False

    def __init__(self, publisher: ZenohPublisher) -> None:
        self.publisher = publisher

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        """Raw datagrams are the log's only."""

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        if message.status == "ended":
            self.publisher.end_system_track(message.number, payload)
        else:
            self.publisher.put_system_track(message.number, payload)

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self.publisher.put_local_track(_sac_sic(message.radar), message.number, payload)

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None:
        # In the batch's order: the updates between two ends in one call.
        live: list[tuple[int, bytes]] = []
        for update in updates:
            if update.ended:
                self.publisher.put_system_tracks(live)
                live = []
                self.publisher.end_system_track(update.number, update.payload)
            else:
                live.append((update.number, update.payload))
        self.publisher.put_system_tracks(live)

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None:
        self.publisher.put_local_tracks(_sac_sic(radar), [(u.number, u.payload) for u in updates])

    def asterix(self, data: bytes, time: float) -> None:
        self.publisher.put_cat062(data)

    def bias(self, message: BiasMessage, time: float) -> None:
        self.publisher.put_bias(_sac_sic(message.radar), message)

    def status(self, message: StatusMessage, time: float) -> None:
        self.publisher.put_status(message)

    def close(self) -> None:
        """The publisher is its owner's to close."""
