"""The service's Zenoh side: tracks, biases, status and CAT062 under one key prefix.

Keys (``tracker`` being the default prefix):

- ``tracker/system_tracks/<number>``: JSON per system-track update; a track's end is a
  last message (status "ended") followed by a delete;
- ``tracker/local_tracks/<SAC>_<SIC>/<number>``, ``tracker/bias/<SAC>_<SIC>``,
  ``tracker/status``: JSON;
- ``tracker/cat062``: ASTERIX data blocks;
- ``tracker/picture`` and ``tracker/cat062/picture``: the periodic picture, when
  ``[zenoh] period_s`` asks for it (``zenoh_picture.py``);
- a queryable on ``tracker/system_tracks/**`` answering the latest message of every live
  track, so that a subscriber joining late gets the whole picture at once.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Sequence
from pathlib import Path

import zenoh
from pydantic import BaseModel

from tracker_service.closing import Closing
from tracker_service.outputs.zenoh_session import Mode, open_session, zenoh_config

__all__ = ["ZenohPublisher", "zenoh_config"]

DEFAULT_PREFIX = "tracker"


def _json(model: BaseModel | bytes) -> bytes:
    return model if isinstance(model, bytes) else model.model_dump_json().encode()


def _source_key(sac_sic: tuple[int, int]) -> str:
    sac, sic = sac_sic
    if not (0 <= sac <= 255 and 0 <= sic <= 255):
        raise ValueError(f"SAC/SIC {sac_sic} out of range 0..255")
    return f"{sac}_{sic}"


class ZenohPublisher(Closing):
    """Publishes the service's messages (any pydantic model, as JSON) on one session.
    A message may also come as its JSON already (bytes), when the caller serialised it
    once for every output."""

    def __init__(
        self,
        prefix: str = DEFAULT_PREFIX,
        *,
        mode: Mode | None = None,
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        config_file: str | Path | None = None,
        scouting: bool = False,
        allow_plaintext: bool = False,
    ) -> None:
        """The session is ``zenoh_session.zenoh_config`` of the arguments: endpoints add
        to the file's, scouting off unless asked for, TLS kept TLS."""
        if not prefix or prefix.startswith("/") or prefix.endswith("/") or "*" in prefix:
            raise ValueError(f"prefix {prefix!r} must be a key expression without wildcards")
        self.prefix = prefix
        self._session = open_session(
            zenoh_config(
                mode,
                listen,
                connect,
                config_file,
                scouting=scouting,
                allow_plaintext=allow_plaintext,
            )
        )
        # The queryable answers from Zenoh's own threads while the service publishes.
        self._lock = threading.Lock()
        self._picture: dict[str, bytes] = {}
        self._closed = False
        self._queryable = self._session.declare_queryable(
            f"{prefix}/system_tracks/**", self._answer, complete=True
        )

    def put_system_track(self, number: int, model: BaseModel | bytes) -> None:
        key = self._track_key(number)
        payload = _json(model)
        with self._lock:
            self._picture[key] = payload
        self._put_json(key, payload)

    def put_system_tracks(self, tracks: Sequence[tuple[int, bytes]]) -> None:
        """As :meth:`put_system_track` for each (number, JSON), the picture updated once."""
        keyed = [(self._track_key(number), payload) for number, payload in tracks]
        with self._lock:
            self._picture.update(keyed)
        self._put_many(keyed)

    def end_system_track(self, number: int, model: BaseModel | bytes) -> None:
        """Publishes the track's last message (the caller's, with status "ended") and then
        deletes its key; from then on the queryable no longer answers it."""
        key = self._track_key(number)
        with self._lock:
            self._picture.pop(key, None)
        # Blocking rather than dropped under congestion: a lost end leaves a ghost track
        # on every subscriber's picture.
        self._put_json(key, _json(model), zenoh.CongestionControl.BLOCK)
        self._session.delete(key, congestion_control=zenoh.CongestionControl.BLOCK)

    def put_local_track(
        self, sac_sic: tuple[int, int], number: int, model: BaseModel | bytes
    ) -> None:
        key = f"{self.prefix}/local_tracks/{_source_key(sac_sic)}/{number}"
        self._put_json(key, _json(model))

    def put_local_tracks(
        self, sac_sic: tuple[int, int], tracks: Iterable[tuple[int, bytes]]
    ) -> None:
        """As :meth:`put_local_track` for each (number, JSON) of one radar."""
        prefix = f"{self.prefix}/local_tracks/{_source_key(sac_sic)}/"
        self._put_many((prefix + str(number), payload) for number, payload in tracks)

    def put_bias(self, sac_sic: tuple[int, int], model: BaseModel | bytes) -> None:
        key = f"{self.prefix}/bias/{_source_key(sac_sic)}"
        self._put_json(key, _json(model))

    def put_status(self, model: BaseModel | bytes) -> None:
        self._put_json(f"{self.prefix}/status", _json(model))

    def put_cat062(self, data: bytes) -> None:
        self._session.put(
            f"{self.prefix}/cat062", data, encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM
        )

    def put_picture(self, payload: bytes) -> None:
        """The periodic picture (``zenoh_picture.py``): a JSON list of system-track
        messages, every track at one time."""
        self._put_json(f"{self.prefix}/picture", payload)

    def put_picture_cat062(self, data: bytes) -> None:
        """The periodic picture as CAT062 blocks and a CAT065 end of batch."""
        self._session.put(
            f"{self.prefix}/cat062/picture",
            data,
            encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM,
        )

    @property
    def live_tracks(self) -> list[int]:
        """The numbers of the tracks the queryable answers, sorted."""
        with self._lock:
            return sorted(int(key.rsplit("/", 1)[1]) for key in self._picture)

    def _track_key(self, number: int) -> str:
        if number < 0:
            raise ValueError(f"track number {number} must not be negative")
        return f"{self.prefix}/system_tracks/{number}"

    def _put_json(
        self,
        key: str,
        payload: bytes,
        congestion: zenoh.CongestionControl | None = None,
    ) -> None:
        self._session.put(
            key,
            payload,
            encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=congestion,
        )

    def _put_many(self, keyed: Iterable[tuple[str, bytes]]) -> None:
        put, json = self._session.put, zenoh.Encoding.APPLICATION_JSON
        for key, payload in keyed:
            put(key, payload, encoding=json)

    def _answer(self, query: zenoh.Query) -> None:
        with self._lock:
            picture = list(self._picture.items())
        # A query may name one track, or a subset, rather than the whole key space.
        for key, payload in picture:
            if query.key_expr.intersects(zenoh.KeyExpr(key)):
                query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)

    def close(self) -> None:
        """Undeclares the queryable and closes the session; later calls do nothing.
        Tracks still live are not ended here: the service decides what ending means."""
        if self._closed:
            return
        self._closed = True
        # zenoh's stubs leave both unannotated.
        self._queryable.undeclare()  # type: ignore[no-untyped-call]
        self._session.close()  # type: ignore[no-untyped-call]
