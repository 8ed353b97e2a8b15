"""Track updates as plain data with their JSON already written: the batch path of the
outputs, without a pydantic model (nor a dict) per update.

``MessageMapper.local_updates`` and ``MessageMapper.system_updates`` (``mapping.py``) turn
the chain's rows into these, their JSON written for the whole batch at once
(``message_json``), and the sinks carry a whole batch in one call (``sink.BatchSink``).
A system update is a row of its batch's columns (``SystemBatch``: what CAT062 and the
Foxglove map read) with its JSON; its plain values (``SystemValues``), its
values as a dict and its model are made only where a consumer asks for them (the picture,
a sink without batch support, a track's end). ``LOCAL_FIELDS``/``SYSTEM_FIELDS``: the
models' field order, which the JSON keeps (a test holds the JSON to the models' own
``model_dump_json``, byte for byte).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from pydantic_core import to_json

from tracker_service.outputs.messages import (
    DAP_NAMES,
    DownlinkedParameter,
    LastPlot,
    LocalTrackMessage,
    SensorAges,
    SystemTrackMessage,
    TrackSource,
)

__all__ = [
    "LOCAL_FIELDS",
    "STATUSES",
    "SYSTEM_FIELDS",
    "LocalUpdate",
    "SystemBatch",
    "SystemUpdate",
    "SystemValues",
    "python_json_numbers",
    "system_json",
    "system_model",
]


LOCAL_FIELDS = (
    "radar",
    "number",
    "time",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "covariance",
    "flight_level",
    "climb_rate_fpm",
    "status",
    "plot_id",
    "mode3a",
    "address",
    "model_probabilities",
)
"""``LocalTrackMessage``'s field order, which its JSON keeps (checked by a test)."""

SYSTEM_FIELDS = (
    "number",
    "time",
    "time_iso",
    "lat",
    "lon",
    "altitude_m",
    "flight_level",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "ground_speed_mps",
    "track_angle_deg",
    "climb_rate_fpm",
    "covariance",
    "position_sigma_m",
    "address",
    "callsign",
    "mode3a",
    "mode3a_changed",
    "first",
    "sources",
    "status",
    "last_plot",
    "ages",
    "duplicate_address",
    "adsb_inconsistent",
    "daps",
)
"""``SystemTrackMessage``'s field order, which its JSON keeps (checked by a test)."""


def system_json(doc: Mapping[str, Any]) -> bytes:
    """A system-track update's values (keys in ``SYSTEM_FIELDS`` order, nested values as
    ``model_dump()`` gives them) as ``SystemTrackMessage.model_dump_json`` writes them: by
    pydantic-core's own JSON writer, non-finite numbers as null as the model's serialiser
    writes them."""
    return to_json(doc, inf_nan_mode="null")


def python_json_numbers(values: Sequence[float]) -> list[str]:
    """Each float's JSON text as ``json.dumps`` writes it (``float.__repr__``; NaN,
    Infinity), by pydantic-core's writer for the whole list (``repr`` costs about 500 ns a
    float): the same digits, except where ``repr`` writes an exponent below -4
    (pydantic-core writes "0.00001" and "1.5e-7" where ``repr`` writes "1e-05" and
    "1.5e-07"): those few are written by ``repr`` of the value read back, which is the
    value (the shortest text that reads back to it)."""
    if not values:
        return []
    text = to_json(values, inf_nan_mode="constants").decode()
    texts = text[1:-1].split(",")
    if "e" not in text and "0.0000" not in text:
        return texts  # no number below 1e-4 nor an exponent: the texts are repr's
    return [
        repr(float(text)) if "e" in text or text.startswith(_BELOW_1E_4) else text for text in texts
    ]


_BELOW_1E_4 = ("0.0000", "-0.0000")
"""pydantic-core's fixed notation of a number below 1e-4 (``repr``: an exponent)."""


def system_model(doc: Mapping[str, Any]) -> SystemTrackMessage:
    """The model of a system update's values, unvalidated (values that hold no bound, such
    as a non-finite one, serialised as pydantic writes them)."""
    plot = doc["last_plot"]
    return SystemTrackMessage.model_construct(
        **(
            dict(doc)
            | {
                "sources": [TrackSource.model_construct(**s) for s in doc["sources"]],
                "last_plot": None if plot is None else LastPlot.model_construct(**plot),
                "ages": SensorAges.model_construct(**doc["ages"]),
                "daps": [DownlinkedParameter.model_construct(**d) for d in doc["daps"]],
            }
        )
    )


SENSORS = ("psr", "ssr", "mode_s", "adsb")
"""The keys of ``SystemTrackMessage.ages``, in its order."""
STATUSES = ("confirmed", "coasting", "ended")
"""``SystemTrackMessage.status`` by its code in ``SystemBatch.status``."""


class SystemValues(NamedTuple):
    """What CAT062 and the Foxglove map read of a system-track update: its message's
    fields of these names (None where the message has null; the
    covariance flat, row-major), ``sources`` the radars of its local tracks in their
    order, ``ages`` the sensor ages (PSR, SSR, Mode S, ADS-B), ``plot_*`` the radar,
    slant range and azimuth of its last plot, ``daps`` (name, value, age) in the
    message's order. A tuple of plain values: no dict per update, and CAT062 reads a
    batch of them field by field (``zip(*values)``)."""

    number: int
    time: float
    status: str
    lat: float
    lon: float
    altitude_m: float | None
    flight_level: float | None
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    ground_speed_mps: float
    track_angle_deg: float
    climb_rate_fpm: float | None
    covariance: tuple[float, ...]
    address: str | None
    callsign: str | None
    mode3a: str | None
    mode3a_changed: bool
    first: bool
    duplicate_address: bool
    adsb_inconsistent: bool
    sources: tuple[str, ...]
    ages: tuple[float | None, ...]
    plot_radar: str | None
    plot_range_m: float | None
    plot_azimuth_deg: float | None
    daps: tuple[tuple[str, float, float], ...]

    @classmethod
    def of_doc(cls, d: Mapping[str, Any]) -> SystemValues:
        """From a message's values (``model_dump()``'s shape)."""
        plot, ages = d["last_plot"], d["ages"]
        return cls(
            d["number"],
            d["time"],
            d["status"],
            d["lat"],
            d["lon"],
            d["altitude_m"],
            d["flight_level"],
            d["x_m"],
            d["y_m"],
            d["vx_mps"],
            d["vy_mps"],
            d["ground_speed_mps"],
            d["track_angle_deg"],
            d["climb_rate_fpm"],
            tuple(value for row in d["covariance"] for value in row),
            d["address"],
            d["callsign"],
            d["mode3a"],
            d["mode3a_changed"],
            d["first"],
            d["duplicate_address"],
            d.get("adsb_inconsistent", False),
            tuple(s["radar"] for s in d["sources"]),
            tuple(ages[sensor] for sensor in SENSORS),
            None if plot is None else plot["radar"],
            None if plot is None else plot["range_m"],
            None if plot is None else plot["azimuth_deg"],
            tuple((p["name"], p["value"], p["age_s"]) for p in d.get("daps", ())),
        )

    @classmethod
    def of_message(cls, message: SystemTrackMessage) -> SystemValues:
        return cls.of_doc(message.model_dump())


class LocalUpdate(NamedTuple):
    """One local-track update: its number and its JSON (``LocalTrackMessage``). A tuple:
    one a local track's update, made at a third of a frozen dataclass's cost."""

    number: int
    deleted: bool
    payload: bytes

    def message(self) -> LocalTrackMessage:
        return LocalTrackMessage.model_validate_json(self.payload)


FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

_BATCH_ROWS = (
    "number",
    "time",
    "lat",
    "lon",
    "x",
    "y",
    "vx",
    "vy",
    "covariance",
    "flight_level",
    "altitude_m",
    "climb_rate_fpm",
    "ground_speed",
    "track_angle",
    "status",
    "first",
    "mode3a_changed",
    "duplicate_address",
    "adsb_inconsistent",
    "address",
    "mode3a",
    "callsign",
    "n_sources",
    "source_radar",
    "ages",
    "plot_radar",
    "plot_range",
    "plot_azimuth",
    "has_dap",
    "dap_value",
    "dap_age",
)


@dataclass(frozen=True, eq=False)
class SystemBatch:
    """System-track updates column by column: what CAT062 and the Foxglove map read,
    without an object per update. Each array has one entry (row)
    per update; NaN where the message has null, -1 where it has no code or address;
    ``status`` a code of ``STATUSES``; ``callsign`` an id of ``names`` (-1 none),
    ``source_radar`` (with ``n_sources`` of each row used) and ``plot_radar`` ids of
    ``radar_names``; ``ages`` by ``SENSORS``; the DAPs by ``messages.DAP_NAMES``."""

    number: IntArray
    time: FloatArray
    lat: FloatArray
    lon: FloatArray
    x: FloatArray
    y: FloatArray
    vx: FloatArray
    vy: FloatArray
    covariance: FloatArray
    """(N, 16), row-major."""
    flight_level: FloatArray
    altitude_m: FloatArray
    climb_rate_fpm: FloatArray
    ground_speed: FloatArray
    track_angle: FloatArray
    status: IntArray
    first: BoolArray
    mode3a_changed: BoolArray
    duplicate_address: BoolArray
    adsb_inconsistent: BoolArray
    address: IntArray
    mode3a: IntArray
    callsign: IntArray
    n_sources: IntArray
    source_radar: IntArray
    """(N, sources)."""
    ages: FloatArray
    plot_radar: IntArray
    plot_range: FloatArray
    plot_azimuth: FloatArray
    has_dap: BoolArray
    dap_value: FloatArray
    dap_age: FloatArray
    names: Sequence[str | None]
    """Callsigns by id."""
    radar_names: Sequence[str]

    def __len__(self) -> int:
        return len(self.number)

    def take(self, rows: IntArray | list[int]) -> SystemBatch:
        """The batch of rows ``rows``, in that order."""
        index = np.asarray(rows, dtype=np.int64)
        columns: dict[str, Any] = {name: getattr(self, name)[index] for name in _BATCH_ROWS}
        return replace(self, **columns)

    @staticmethod
    def gather(rows_of: Sequence[tuple[SystemBatch, int]]) -> SystemBatch:
        """Rows (batch, row) in their order: one take per batch when the batches share
        their names (one mapper's), else the rows' values made into a batch."""
        rows: dict[int, tuple[SystemBatch, list[int], list[int]]] = {}
        for position, (batch, row) in enumerate(rows_of):
            group = rows.get(id(batch))
            if group is None:
                group = rows[id(batch)] = (batch, [], [])
            group[1].append(position)
            group[2].append(row)
        if len(rows) == 1:
            ((batch, _, taken),) = rows.values()
            return batch.take(taken)
        first = rows_of[0][0]
        if any(
            b.names is not first.names
            or b.radar_names is not first.radar_names
            or b.source_radar.shape[1] != first.source_radar.shape[1]
            for b, _, _ in rows.values()
        ):
            return SystemBatch.of_values([batch.values(row) for batch, row in rows_of])
        # Each column of the batches whole, then one take of the rows: two numpy calls a
        # column rather than a take of every column a batch (a second's CAT062 gathers
        # from some 100 batches).
        batches = [batch for batch, _, _ in rows.values()]
        index = np.empty(len(rows_of), dtype=np.int64)
        offset = 0
        for batch, positions, taken in rows.values():
            index[positions] = np.asarray(taken, dtype=np.int64) + offset
            offset += len(batch)
        columns: dict[str, Any] = {
            name: np.concatenate([getattr(batch, name) for batch in batches])[index]
            for name in _BATCH_ROWS
        }
        return replace(batches[0], **columns)

    @staticmethod
    def runs(updates: Sequence[SystemUpdate]) -> list[SystemBatch]:
        """``updates`` in order as batches: each run of updates of one batch as that
        batch's rows (the batch itself when the run is the whole batch in order)."""
        out: list[SystemBatch] = []
        start = 0
        for end in range(1, len(updates) + 1):
            if end < len(updates) and updates[end].batch is updates[start].batch:
                continue
            batch = updates[start].batch
            rows = [u.index for u in updates[start:end]]
            whole = len(rows) == len(batch) and rows == list(range(len(batch)))
            out.append(batch if whole else batch.take(rows))
            start = end
        return out

    @classmethod
    def of_values(cls, values: Sequence[SystemValues]) -> SystemBatch:
        """The batch of messages' values (``SystemValues``), names made for them."""
        names: dict[str, int] = {}
        radars: dict[str, int] = {}
        sources = max((len(v.sources) for v in values), default=0)
        source_radar = np.full((len(values), max(sources, 1)), -1, dtype=np.int64)
        for k, v in enumerate(values):
            for i, radar in enumerate(v.sources):
                source_radar[k, i] = radars.setdefault(radar, len(radars))

        def floats(column: Sequence[float | None]) -> FloatArray:
            return np.array([np.nan if x is None else x for x in column], dtype=np.float64)

        def codes(column: Sequence[str | None], base: int) -> IntArray:
            return np.array([-1 if x is None else int(x, base) for x in column], dtype=np.int64)

        daps = [dict((name, (value, age)) for name, value, age in v.daps) for v in values]
        return cls(
            number=np.array([v.number for v in values], dtype=np.int64),
            time=floats([v.time for v in values]),
            lat=floats([v.lat for v in values]),
            lon=floats([v.lon for v in values]),
            x=floats([v.x_m for v in values]),
            y=floats([v.y_m for v in values]),
            vx=floats([v.vx_mps for v in values]),
            vy=floats([v.vy_mps for v in values]),
            covariance=np.array([v.covariance for v in values], dtype=np.float64).reshape(-1, 16),
            flight_level=floats([v.flight_level for v in values]),
            altitude_m=floats([v.altitude_m for v in values]),
            climb_rate_fpm=floats([v.climb_rate_fpm for v in values]),
            ground_speed=floats([v.ground_speed_mps for v in values]),
            track_angle=floats([v.track_angle_deg for v in values]),
            status=np.array([STATUSES.index(v.status) for v in values], dtype=np.int64),
            first=np.array([v.first for v in values], dtype=np.bool_),
            mode3a_changed=np.array([v.mode3a_changed for v in values], dtype=np.bool_),
            duplicate_address=np.array([v.duplicate_address for v in values], dtype=np.bool_),
            adsb_inconsistent=np.array([v.adsb_inconsistent for v in values], dtype=np.bool_),
            address=codes([v.address for v in values], 16),
            mode3a=codes([v.mode3a for v in values], 8),
            callsign=np.array(
                [_id(names, v.callsign) for v in values],
                dtype=np.int64,
            ),
            n_sources=np.array([len(v.sources) for v in values], dtype=np.int64),
            source_radar=source_radar,
            ages=np.array(
                [[np.nan if a is None else a for a in v.ages] for v in values], dtype=np.float64
            ).reshape(-1, len(SENSORS)),
            plot_radar=np.array([_id(radars, v.plot_radar) for v in values], dtype=np.int64),
            plot_range=floats([v.plot_range_m for v in values]),
            plot_azimuth=floats([v.plot_azimuth_deg for v in values]),
            has_dap=np.array(
                [[name in d for name in DAP_NAMES] for d in daps], dtype=np.bool_
            ).reshape(-1, len(DAP_NAMES)),
            dap_value=np.array(
                [[d.get(name, (np.nan, np.nan))[0] for name in DAP_NAMES] for d in daps],
                dtype=np.float64,
            ).reshape(-1, len(DAP_NAMES)),
            dap_age=np.array(
                [[d.get(name, (np.nan, np.nan))[1] for name in DAP_NAMES] for d in daps],
                dtype=np.float64,
            ).reshape(-1, len(DAP_NAMES)),
            names=list(names),
            radar_names=list(radars),
        )

    def values(self, k: int) -> SystemValues:
        """Row ``k`` as plain values."""

        def optional(x: float) -> float | None:
            return None if x != x else x

        n = int(self.n_sources[k])
        callsign = int(self.callsign[k])
        address, mode3a, plot = int(self.address[k]), int(self.mode3a[k]), int(self.plot_radar[k])
        return SystemValues(
            int(self.number[k]),
            float(self.time[k]),
            STATUSES[int(self.status[k])],
            float(self.lat[k]),
            float(self.lon[k]),
            optional(float(self.altitude_m[k])),
            optional(float(self.flight_level[k])),
            float(self.x[k]),
            float(self.y[k]),
            float(self.vx[k]),
            float(self.vy[k]),
            float(self.ground_speed[k]),
            float(self.track_angle[k]),
            optional(float(self.climb_rate_fpm[k])),
            tuple(self.covariance[k].tolist()),
            None if address < 0 else f"{address:06X}",
            None if callsign < 0 else self.names[callsign],
            None if mode3a < 0 else f"{mode3a:04o}",
            bool(self.mode3a_changed[k]),
            bool(self.first[k]),
            bool(self.duplicate_address[k]),
            bool(self.adsb_inconsistent[k]),
            tuple(self.radar_names[r] for r in self.source_radar[k, :n].tolist()),
            tuple(map(optional, self.ages[k].tolist())),
            None if plot < 0 else self.radar_names[plot],
            optional(float(self.plot_range[k])),
            optional(float(self.plot_azimuth[k])),
            tuple(
                (name, value, age)
                for name, there, value, age in zip(
                    DAP_NAMES,
                    self.has_dap[k].tolist(),
                    self.dap_value[k].tolist(),
                    self.dap_age[k].tolist(),
                    strict=True,
                )
                if there
            ),
        )


@dataclass(frozen=True, slots=True)
class SystemUpdate:
    """One system-track update: its row of a ``SystemBatch`` and its JSON
    (``SystemTrackMessage``); its plain values, the message's values as a dict and the
    model only when asked for (the dict read back from the JSON, which holds the values
    exactly)."""

    batch: SystemBatch
    index: int
    number: int
    payload: bytes

    @property
    def ended(self) -> bool:
        return bool(self.batch.status[self.index] == _ENDED)

    @property
    def values(self) -> SystemValues:
        return self.batch.values(self.index)

    @property
    def doc(self) -> dict[str, Any]:
        """The message's values (``model_dump()``'s shape; a non-finite number None, as
        the JSON has it)."""
        doc: dict[str, Any] = json.loads(self.payload)
        return doc

    def message(self) -> SystemTrackMessage:
        """The model, unvalidated, as the pydantic path builds it from the rows."""
        return system_model(self.doc)


_ENDED = STATUSES.index("ended")


def _id(ids: dict[str, int], name: str | None) -> int:
    """``name``'s id in ``ids`` (a new one when new), -1 for None."""
    return -1 if name is None else ids.setdefault(name, len(ids))
