"""The periodic picture over Zenoh as a ``Sink``: every ``[zenoh] period_s`` seconds of
data time, every live system track extrapolated to one common time
(``periodic.PeriodicPicture``), published as one JSON list on ``<prefix>/picture`` and as
CAT062 (then a CAT065 end of batch) on ``<prefix>/cat062/picture``; what ATC displays and
safety nets expect beside the updates, which go on as they are."""

from __future__ import annotations

from asterix.containers import Datagram
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.cat062 import encode_cat065, encode_system_tracks
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.periodic import PeriodicPicture
from tracker_service.outputs.sdps import SdpsIdentity
from tracker_service.outputs.zenoh_out import ZenohPublisher

__all__ = ["ZenohPictureSink"]


class ZenohPictureSink:
    """Publishes on ``publisher``, which its owner closes."""

    name = "zenoh_picture"
    resends_tracks = False
    keeps_datagrams = False

    def __init__(
        self,
        publisher: ZenohPublisher,
        plane: SystemPlane,
        sdps: SdpsIdentity,
        period_s: float,
    ) -> None:
        self.publisher = publisher
        self.sdps = sdps
        self.picture = PeriodicPicture(plane, period_s)
        self._batch = 0

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        self._tick(datagram.time)

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self._tick(time)
        self.picture.update(message)

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self._tick(time)

    def asterix(self, data: bytes, time: float) -> None:
        self._tick(time)

    def bias(self, message: BiasMessage, time: float) -> None:
        self._tick(time)

    def status(self, message: StatusMessage, time: float) -> None:
        self._tick(time)

    def close(self) -> None:
        """The publisher is its owner's to close."""

    def _tick(self, time: float) -> None:
        due = self.picture.due(time)
        if due is None:
            return
        tracks = self.picture.at(due)
        payload = b"[" + b",".join(m.model_dump_json().encode() for m in tracks) + b"]"
        self.publisher.put_picture(payload)
        data = encode_system_tracks(tracks, self.sdps)
        data += encode_cat065("end_of_batch", due, self._batch, self.sdps)
        self._batch += 1
        self.publisher.put_picture_cat062(data)
