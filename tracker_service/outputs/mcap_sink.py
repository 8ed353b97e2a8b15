"""The MCAP log as a ``Sink``: each message on its channel of ``McapLog``."""

from __future__ import annotations

from collections.abc import Sequence

from asterix.containers import Datagram
from tracker_service.outputs.mcap_log import LoggedDatagram, McapLog
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.updates import LocalUpdate, SystemUpdate

__all__ = [
    "CAT062_TOPIC",
    "STATUS_TOPIC",
    "SYSTEM_TRACKS_TOPIC",
    "McapSink",
    "topic_name",
]

SYSTEM_TRACKS_TOPIC = "/system_tracks"
CAT062_TOPIC = "/cat062"
STATUS_TOPIC = "/status"


def topic_name(radar: str) -> str:
    """A radar's part of a topic: "25/11" -> "25_11"."""
    return radar.replace("/", "_")


class McapSink:
    """Logs into ``log``, which its owner closes."""

    name = "mcap"
    resends_tracks = False
    keeps_datagrams = True

    def __init__(self, log: McapLog) -> None:
        self.log = log

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        self.log.log_datagram(datagram, input_name)

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self.log.log_json(SYSTEM_TRACKS_TOPIC, SystemTrackMessage, payload, time)

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        topic = f"/local_tracks/{topic_name(message.radar)}"
        self.log.log_json(topic, LocalTrackMessage, payload, time)

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None:
        self.log.log_json_many(
            SYSTEM_TRACKS_TOPIC, SystemTrackMessage, [u.payload for u in updates], time
        )

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None:
        topic = f"/local_tracks/{topic_name(radar)}"
        self.log.log_json_many(topic, LocalTrackMessage, [u.payload for u in updates], time)

    def asterix(self, data: bytes, time: float) -> None:
        record = LoggedDatagram(input="cat062", time=time, src=None, dst=None, payload=data.hex())
        self.log.log(CAT062_TOPIC, record, time)

    def bias(self, message: BiasMessage, time: float) -> None:
        self.log.log(f"/bias/{topic_name(message.radar)}", message, time)

    def status(self, message: StatusMessage, time: float) -> None:
        self.log.log(STATUS_TOPIC, message, time)

    def close(self) -> None:
        """The log is its owner's to close."""
