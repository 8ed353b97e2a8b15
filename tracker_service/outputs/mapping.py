"""The chain's rows as the service's messages, in one place for every output.

``MessageMapper`` turns a batch's local-track and system-track rows (with the plots that
made them) into updates (``updates.py``): each message's JSON, written for the whole batch
at once from its columns (``message_json``), and, for system tracks, the batch's values
column by column (``SystemBatch``) for CAT062 and the map; and bias estimates into
``BiasMessage``. What a system track's next message needs from its previous ones (last
plot, sensor and DAP ages, callsign, duplicate addresses) it keeps per track in arrays
(``system_state``). The sinks (``sink.py``) only carry the updates: Zenoh and the MCAP log
publish the same JSON.

``ModelMapper`` is the same mapping message by message, as pydantic models: the
reference the batch path is held to, byte for byte (``tests/test_outputs_updates.py``).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from itertools import repeat
from typing import Any, Literal, cast

import numpy as np
import numpy.typing as npt

from tracker_service.adsb import ADSB_TYP
from tracker_service.bias import ObservedFrom
from tracker_service.fusion import COASTING, ENDED
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.message_json import MessageWriter
from tracker_service.outputs.messages import (
    DAP_NAMES,
    BiasMessage,
    BiasSource,
    DownlinkedParameter,
    Estimate,
    LastPlot,
    LocalTrackMessage,
    SensorAges,
    SystemTrackMessage,
    TrackSource,
    ellipse_sigma_m,
    track_angle_deg,
    wrap_degrees,
)
from tracker_service.outputs.system_state import StepInput, SystemState
from tracker_service.outputs.updates import (
    STATUSES,
    LocalUpdate,
    SystemBatch,
    SystemUpdate,
    system_json,
)

__all__ = ["LOCAL_STATUS", "MessageMapper", "ModelMapper"]

LocalStatus = Literal["tentative", "confirmed", "coasting", "deleted"]
LOCAL_STATUS: tuple[LocalStatus, ...] = ("tentative", "confirmed", "coasting", "deleted")
_DELETED = LOCAL_STATUS.index("deleted")
# I048/020 TYP: which sensor types a plot of each type is (PSR, SSR, Mode S).
_PSR_TYPES = frozenset((1, 3, 6, 7))
_SSR_TYPES = frozenset((2, 3))
_MODE_S_TYPES = frozenset((4, 5, 6, 7))
_ADSB_TYPES = frozenset((ADSB_TYP,))
_SENSOR_TYPES = (
    ("psr", _PSR_TYPES),
    ("ssr", _SSR_TYPES),
    ("mode_s", _MODE_S_TYPES),
    ("adsb", _ADSB_TYPES),
)
"""Each ``SensorAges`` key with the plot types (TYP) that update it."""
_SENSOR_BITS = np.array(
    [
        sum(1 << bit for bit, (_, types) in enumerate(_SENSOR_TYPES) if typ in types)
        for typ in range(max(ADSB_TYP, 7) + 1)
    ],
    dtype=np.int64,
)
"""Per plot type (TYP), bit i set when it updates ``_SENSOR_TYPES[i]``."""
_STATUS_CODES = np.zeros(256, dtype=np.int64)
"""The fuser's status codes as ``SystemBatch.status`` codes (``STATUSES``)."""
_STATUS_CODES[COASTING] = STATUSES.index("coasting")
_STATUS_CODES[ENDED] = STATUSES.index("ended")


def _none_if_nan(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _hex_address(value: int) -> str | None:
    return f"{value:06X}" if value >= 0 else None


def _octal_code(value: int) -> str | None:
    return f"{value:04o}" if value >= 0 else None


def _track_callsign(
    plot_callsign: str | None, previous: _SystemTrack | None, address: str | None
) -> str | None:
    """The callsign (I048/240) of the plot that updated the track; without one (coasting,
    or a plot without I240), the track's own from its earlier plots while its address
    stays the same. Never the latest callsign seen for the address: two aircraft that
    share an address would trade callsigns."""
    if plot_callsign:
        return plot_callsign
    if previous is not None and previous.address == address:
        return previous.callsign
    return None


def _remember_daps(
    daps: dict[str, tuple[float, float]], plot: Any, time: float
) -> dict[str, tuple[float, float]]:
    """``daps`` (copied) with the DAPs of ``plot`` (a plot-table row) taken in."""
    if "has_daps" not in (plot.dtype.names or ()) or not plot["has_daps"]:
        return daps
    daps = dict(daps)
    for name in DAP_NAMES:
        value = float(plot[name])
        if math.isfinite(value):
            daps[name] = (value, time)
    return daps


def _dap_docs(daps: dict[str, tuple[float, float]], time: float) -> list[dict[str, Any]]:
    return [
        {"name": name, "value": daps[name][0], "age_s": max(time - daps[name][1], 0.0)}
        for name in DAP_NAMES
        if name in daps
    ]


def bias_messages(
    estimates: Mapping[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
    observed_from: Mapping[str, ObservedFrom],
    time: float,
) -> list[BiasMessage]:
    """Each radar's estimate; a component is observable when something observes it
    (``observed_from``: other radars' traffic, a reference radar, a field monitor,
    ADS-B), whatever its sigma says. A state beyond the 4 biases is the clock's drift
    (s/s) and then its rate (s/s^2), observable with the time offset."""
    messages = []
    for source, (bias, covariance) in estimates.items():
        sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0))
        sources = observed_from.get(source, ((),) * 4)
        scale = (1.0, 1.0, math.degrees(1.0), 1.0, 3600.0, 3600.0**2)
        values = [
            Estimate(
                estimate=float(bias[i]) * scale[i],
                sigma=float(sigma[i]) * scale[i],
                observable=bool(sources[min(i, 3)]),
                observed_from=[cast(BiasSource, name) for name in sources[min(i, 3)]],
            )
            for i in range(len(bias))
        ]
        clock: list[Estimate | None] = [*values[4:], None, None]
        messages.append(
            BiasMessage(
                radar=source,
                time=time,
                range_offset_m=values[0],
                range_gain=values[1],
                azimuth_deg=values[2],
                time_s=values[3],
                time_drift_s_per_h=clock[0],
                time_drift_rate_s_per_h2=clock[1],
            )
        )
    return messages


@dataclass
class _SystemTrack:
    """What the per-message path remembers of a live system track between its updates."""

    last: SystemTrackMessage
    last_plot: LastPlot | None = None
    sensor_times: dict[str, float] = field(default_factory=dict)
    daps: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Each DAP's last value and the time of the plot that carried it."""

    @property
    def mode3a(self) -> str | None:
        return self.last.mode3a

    @property
    def address(self) -> str | None:
        return self.last.address

    @property
    def callsign(self) -> str | None:
        return self.last.callsign


def _ended(update: SystemUpdate) -> bytes:
    """The JSON of a track's last message with status "ended", not first: its last
    update's JSON with those two values written again. Each of their keys occurs once, at
    the top level (a string value cannot hold the unescaped quotes of ``"status":"``);
    should a replacement not be made exactly once, the JSON is written from its values."""
    payload = update.payload
    for old, new in (
        (b'"first":true,', b'"first":false,'),
        (b'"status":"confirmed",', b'"status":"ended",'),
        (b'"status":"coasting",', b'"status":"ended",'),
    ):
        payload = payload.replace(old, new)
    if payload.count(b'"first":false,') == 1 and payload.count(b'"status":"ended",') == 1:
        return payload
    return system_json(update.doc | {"status": "ended", "first": False})


class MessageMapper:
    """Rows to updates, a batch at a time; its state follows only from the rows it is
    given, in order."""

    def __init__(self, plane: SystemPlane) -> None:
        self.plane = plane
        self._writer = MessageWriter()
        self._state = SystemState()
        self._last: dict[int, SystemUpdate] = {}
        """The latest update of every live system track."""
        self._local_times: dict[int, float] = {}
        """Each local track's latest update by ``_local_key`` (its radar's id, its number)."""
        self._names: list[str | None] = []
        """Callsigns by the literal id of their JSON string (None: another literal)."""
        self._callsigns: dict[str, int] = {"": -1}
        self._sources: tuple[tuple[str, ...], npt.NDArray[np.int64]] | None = None
        self._radars: dict[str, int] = {}
        """Radar names by id (``SystemBatch.radar_names``)."""
        self._radar_names: list[str] = []
        self._radar_literals: list[int] = []

    @property
    def live_tracks(self) -> list[int]:
        return sorted(self._last)

    def picture(self) -> dict[int, SystemTrackMessage]:
        """The latest message of every live system track."""
        return {number: self._last[number].message() for number in sorted(self._last)}

    def local_updates(self, source: str, rows: npt.NDArray[Any]) -> list[LocalUpdate]:
        """A radar's local-track rows as updates, each with its JSON
        (``LocalTrackMessage``'s)."""
        n = len(rows)
        if not n:
            return []
        numbers = rows["track_number"]
        status = rows["status"].astype(np.int64)
        radar = self._radar_id(source)
        payloads = self._writer.local(
            self._radar_literals[radar],
            numbers,
            np.column_stack(
                (
                    rows["time"],
                    rows["x"],
                    rows["y"],
                    rows["vx"],
                    rows["vy"],
                    rows["P"].reshape(n, 16),
                    rows["flight_level"],
                    rows["climb_rate_fl_per_s"] * 6000.0,
                )
            ),
            status,
            rows["plot_id"],
            rows["mode3a"],
            rows["address"],
            rows["model_probabilities"].reshape(n, -1),
        )
        number_list = numbers.tolist()
        deleted = (status == _DELETED).tolist()
        times = self._local_times
        keys = _local_key(radar, numbers.astype(np.int64)).tolist()
        if any(deleted):
            for key, time, gone in zip(keys, rows["time"].tolist(), deleted, strict=True):
                if gone:
                    times.pop(key, None)
                else:
                    times[key] = time
        else:
            times.update(zip(keys, rows["time"].tolist(), strict=True))
        return list(map(LocalUpdate, number_list, deleted, payloads))

    def system_updates(
        self, rows: npt.NDArray[Any], plots: npt.NDArray[Any], sources: Sequence[str]
    ) -> list[SystemUpdate]:
        """A batch's system rows as updates: its values (``SystemBatch``) and each
        message's JSON (``SystemTrackMessage``'s); ``plots`` is the batch's plot table,
        ``sources`` names the chain's radars by index."""
        n, m = len(rows), len(plots)
        if not n:
            return []
        radar_ids = self._radar_ids(sources)
        # The rows' and the plots' positions in one call of the projection.
        lat, lon = self.plane.to_geodetic(
            np.concatenate((rows["x"], plots["x"])), np.concatenate((rows["y"], plots["y"]))
        )
        vx, vy, p = rows["vx"].tolist(), rows["vy"].tolist(), np.ascontiguousarray(rows["P"])
        # The derived numbers by the per-message path's own functions, to the bit.
        speed = np.array(list(map(math.hypot, vx, vy)), dtype=np.float64)
        angle = np.array(list(map(track_angle_deg, vx, vy)), dtype=np.float64)
        sigma = np.array(
            list(map(ellipse_sigma_m, p[:, 0].tolist(), p[:, 1].tolist(), p[:, 5].tolist())),
            dtype=np.float64,
        )
        climb = rows["climb_rate_fl_per_s"]
        level = rows["flight_level"]
        n_sources = rows["n_sources"].astype(np.int64)
        local_radars = rows["local_radars"].astype(np.int64)
        number = rows["system_number"].astype(np.int64)
        time = rows["time"].astype(np.float64)
        status = rows["status"]
        address = rows["address"].astype(np.int64)
        mode3a = rows["mode3a"].astype(np.int64)
        rho = plots["rho_m"]
        # ``wrap_degrees`` over the column: numpy's remainder is Python's float %, to the bit.
        with np.errstate(invalid="ignore"):
            theta = np.remainder(plots["theta_deg"].astype(np.float64), 360.0)
        theta = np.where(theta >= 360.0, 0.0, theta)
        if "has_daps" in (plots.dtype.names or ()):
            daps = np.column_stack([plots[name] for name in DAP_NAMES])
            daps[~plots["has_daps"]] = np.nan
        else:
            daps = np.full((m, len(DAP_NAMES)), np.nan)
        step = self._state.step(
            StepInput(
                number=number,
                time=time,
                ended=status == ENDED,
                address=address,
                mode3a=mode3a,
                plot_id=rows["plot_id"].astype(np.int64),
                fresh=rows["fresh"].astype(np.bool_),
                radar=radar_ids[rows["radar"].astype(np.int64)],
                n_sources=n_sources,
                local_time=self._local_times_of(rows, radar_ids, n_sources, local_radars),
                plot_ids=plots["plot_id"].astype(np.int64),
                plot_time=plots["time"].astype(np.float64),
                plot_callsign=self._callsign_ids(plots["callsign"].tolist()),
                plot_type=plots["typ"].astype(np.int64),
                sensors=_SENSOR_BITS,
                plot_daps=daps,
                plot_position=np.column_stack(
                    (
                        plots["time"],
                        lat[n:],
                        lon[n:],
                        np.where(np.isfinite(rho), rho, np.nan),
                        np.where(np.isfinite(theta), theta, np.nan),
                    )
                ),
            )
        )
        batch = SystemBatch(
            number=number,
            time=time,
            lat=lat[:n],
            lon=(lon[:n] + 180.0) % 360.0 - 180.0,
            x=rows["x"].astype(np.float64),
            y=rows["y"].astype(np.float64),
            vx=rows["vx"].astype(np.float64),
            vy=rows["vy"].astype(np.float64),
            covariance=p,
            flight_level=np.where(np.isfinite(level), level, np.nan),
            altitude_m=np.full(n, np.nan),
            climb_rate_fpm=np.where(np.isfinite(climb), climb * 6000.0, np.nan),
            ground_speed=speed,
            track_angle=angle,
            status=_STATUS_CODES[status],
            first=step.first,
            mode3a_changed=step.mode3a_changed,
            duplicate_address=step.duplicate_address,
            adsb_inconsistent=rows["adsb_inconsistent"].astype(np.bool_),
            address=address,
            mode3a=mode3a,
            callsign=step.callsign,
            n_sources=n_sources,
            source_radar=radar_ids[local_radars],
            ages=step.ages,
            plot_radar=step.plot_radar,
            plot_range=step.plot_position[:, 3],
            plot_azimuth=step.plot_position[:, 4],
            has_dap=step.has_dap,
            dap_value=step.dap_value,
            dap_age=step.dap_age,
            names=self._names,
            radar_names=self._radar_names,
        )
        payloads = self._writer.system(
            batch,
            np.array(self._radar_literals, dtype=np.int64),
            sigma,
            rows["local_numbers"].astype(np.int64),
            rows["local_plot_ids"].astype(np.int64),
            step.source_ages,
            step.plot_position,
        )
        numbers = number.tolist()
        updates = list(map(SystemUpdate, repeat(batch), range(n), numbers, payloads))
        last = self._last
        last.update(zip(numbers, updates, strict=True))
        # A track whose last row in the batch ends it is gone (a number may end and start
        # again within a batch).
        for ended in number[status == ENDED].tolist():
            if ended in last and last[ended].ended:
                del last[ended]
        return updates

    def _local_times_of(
        self,
        rows: npt.NDArray[Any],
        radar_ids: npt.NDArray[np.int64],
        n_sources: npt.NDArray[np.int64],
        local_radars: npt.NDArray[np.int64],
    ) -> npt.NDArray[np.float64]:
        """Each source's local track's latest update (NaN: unknown); ``radar_ids``: the
        mapper's ids of the chain's radars."""
        used = np.arange(local_radars.shape[1]) < n_sources[:, None]
        keys = _local_key(
            radar_ids[local_radars[used]], rows["local_numbers"][used].astype(np.int64)
        )
        local_time = np.full(local_radars.shape, np.nan)
        local_time[used] = list(map(self._local_times.get, keys.tolist(), repeat(math.nan)))
        return local_time

    def end_all_updates(self) -> list[SystemUpdate]:
        """An "ended" update for every live track (its last message, status "ended", not
        first), which are then forgotten."""
        if not self._last:
            return []
        last = [self._last[number] for number in sorted(self._last)]
        batch = SystemBatch.gather([(u.batch, u.index) for u in last])
        batch = replace(
            batch,
            status=np.full(len(batch), STATUSES.index("ended"), dtype=np.int64),
            first=np.zeros(len(batch), dtype=np.bool_),
        )
        ended = [SystemUpdate(batch, k, u.number, _ended(u)) for k, u in enumerate(last)]
        self._last.clear()
        self._state.end_all()
        return ended

    def bias(
        self,
        estimates: Mapping[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
        observed_from: Mapping[str, ObservedFrom],
        time: float,
    ) -> list[BiasMessage]:
        """``bias_messages``."""
        return bias_messages(estimates, observed_from, time)

    def _radar_id(self, name: str) -> int:
        known = self._radars.get(name)
        if known is None:
            known = self._radars[name] = len(self._radar_names)
            self._radar_names.append(name)
            self._radar_literals.append(self._writer.literals.string(name))
        return known

    def _radar_ids(self, sources: Sequence[str]) -> npt.NDArray[np.int64]:
        """The ids of the chain's radars (``sources``: the same names batch after batch,
        the last ones' ids kept)."""
        names = tuple(sources)
        known = self._sources
        if known is None or known[0] != names:
            ids = np.array([self._radar_id(name) for name in names], dtype=np.int64)
            known = self._sources = (names, ids)
        return known[1]

    def _callsign_ids(self, callsigns: list[str]) -> npt.NDArray[np.int64]:
        """The literal id of each plot callsign's JSON string, -1 for none ("")."""
        known = self._callsigns
        ids = [known.get(c, -2) for c in callsigns]
        if -2 in ids:
            ids = [-1 if not c else self._callsign_id(c) for c in callsigns]
        return np.array(ids, dtype=np.int64)

    def _callsign_id(self, callsign: str) -> int:
        """The literal id of a callsign's JSON string."""
        known = self._callsigns.get(callsign)
        if known is not None:
            return known
        text_id = self._callsigns[callsign] = self._writer.literals.string(callsign)
        names = self._names
        if text_id >= len(names):
            names.extend([None] * (text_id + 1 - len(names)))
        names[text_id] = callsign
        return text_id


def _local_key(radar: int | npt.NDArray[np.int64], number: npt.NDArray[np.int64]) -> Any:
    """A local track's key in ``MessageMapper``'s times: its radar's id and its number
    (within +-2**31) as one integer, computed over a column."""
    return (np.int64(radar) << 32) + number


class ModelMapper:
    """Rows to pydantic messages, one at a time: the reference of ``MessageMapper``."""

    def __init__(self, plane: SystemPlane) -> None:
        self.plane = plane
        self._tracks: dict[int, _SystemTrack] = {}
        self._by_address: dict[str, set[int]] = defaultdict(set)
        """Live system tracks per Mode S address: the duplicate-address flag without a
        scan of every track at each update."""
        self._local_times: dict[tuple[str, int], float] = {}

    @property
    def live_tracks(self) -> list[int]:
        return sorted(self._tracks)

    def picture(self) -> dict[int, SystemTrackMessage]:
        """The latest message of every live system track."""
        return {number: self._tracks[number].last for number in sorted(self._tracks)}

    def local(self, source: str, rows: npt.NDArray[Any]) -> list[LocalTrackMessage]:
        messages = []
        for row in rows:
            number, time = int(row["track_number"]), float(row["time"])
            # Built from the chain's own rows, whose types and ranges hold by construction:
            # no validation on the path every track update takes.
            message = LocalTrackMessage.model_construct(
                radar=source,
                number=number,
                time=time,
                x_m=float(row["x"]),
                y_m=float(row["y"]),
                vx_mps=float(row["vx"]),
                vy_mps=float(row["vy"]),
                covariance=row["P"].reshape(4, 4).tolist(),
                flight_level=_none_if_nan(float(row["flight_level"])),
                climb_rate_fpm=_none_if_nan(float(row["climb_rate_fl_per_s"]) * 6000.0),
                status=LOCAL_STATUS[int(row["status"])],
                plot_id=int(row["plot_id"]) if row["plot_id"] >= 0 else None,
                mode3a=_octal_code(int(row["mode3a"])),
                address=_hex_address(int(row["address"])),
                model_probabilities=row["model_probabilities"].tolist(),
            )
            if message.status == "deleted":
                self._local_times.pop((source, number), None)
            else:
                self._local_times[(source, number)] = time
            messages.append(message)
        return messages

    def system(
        self, rows: npt.NDArray[Any], plots: npt.NDArray[Any], sources: Sequence[str]
    ) -> list[SystemTrackMessage]:
        """The messages of a batch's system rows; ``plots`` is the batch's plot table,
        ``sources`` names the chain's radars by index."""
        lat, lon = self.plane.to_geodetic(rows["x"], rows["y"])
        plot_index = {int(p): i for i, p in enumerate(plots["plot_id"].tolist())}
        plot_lat, plot_lon = self.plane.to_geodetic(plots["x"], plots["y"])
        messages = []
        for k, row in enumerate(rows):
            plot = plot_index.get(int(row["plot_id"]))
            if plot is not None and bool(row["fresh"]):
                plot_position = (float(plot_lat[plot]), float(plot_lon[plot]))
                message = self._system_message(
                    row, float(lat[k]), float(lon[k]), plots[plot], plot_position, sources
                )
            else:
                message = self._system_message(
                    row, float(lat[k]), float(lon[k]), None, None, sources
                )
            messages.append(message)
        return messages

    def end_all(self) -> list[SystemTrackMessage]:
        """An "ended" message for every live track, which are then forgotten."""
        ended = []
        for number in sorted(self._tracks):
            track = self._tracks.pop(number)
            ended.append(track.last.model_copy(update={"status": "ended", "first": False}))
        self._by_address.clear()
        return ended

    def _system_message(
        self,
        row: Any,
        lat: float,
        lon: float,
        plot: Any,
        plot_position: tuple[float, float] | None,
        chain_sources: Sequence[str],
    ) -> SystemTrackMessage:
        number, time = int(row["system_number"]), float(row["time"])
        previous = self._tracks.get(number)
        sensor_times = {} if previous is None else previous.sensor_times
        daps = {} if previous is None else previous.daps
        last_plot = None if previous is None else previous.last_plot
        if plot is not None and plot_position is not None:
            daps = _remember_daps(daps, plot, float(plot["time"]))
            radar = chain_sources[int(row["radar"])]
            typ = int(plot["typ"])
            for sensor, types in _SENSOR_TYPES:
                if typ in types:
                    sensor_times[sensor] = float(plot["time"])
            last_plot = LastPlot.model_construct(
                radar=radar,
                time=float(plot["time"]),
                lat=plot_position[0],
                lon=plot_position[1],
                range_m=_none_if_nan(float(plot["rho_m"])),
                azimuth_deg=_none_if_nan(wrap_degrees(float(plot["theta_deg"]))),
            )
        sources = []
        for slot in range(int(row["n_sources"])):
            radar = chain_sources[int(row["local_radars"][slot])]
            local = int(row["local_numbers"][slot])
            local_time = self._local_times.get((radar, local), time)
            plot_id = int(row["local_plot_ids"][slot])
            sources.append(
                TrackSource.model_construct(
                    radar=radar,
                    local_track=local,
                    age_s=max(time - local_time, 0.0),
                    plot_id=plot_id if plot_id >= 0 else None,
                )
            )
        address = _hex_address(int(row["address"]))
        mode3a = _octal_code(int(row["mode3a"]))
        status = int(row["status"])
        if previous is not None and previous.address is not None:
            self._by_address[previous.address].discard(number)
        message = SystemTrackMessage.from_state(
            time=time,
            x_m=float(row["x"]),
            y_m=float(row["y"]),
            vx_mps=float(row["vx"]),
            vy_mps=float(row["vy"]),
            covariance=row["P"].reshape(4, 4).tolist(),
            climb_rate_fl_per_s=_none_if_nan(float(row["climb_rate_fl_per_s"])),
            validate=False,
            number=number,
            lat=lat,
            lon=(lon + 180.0) % 360.0 - 180.0,
            flight_level=_none_if_nan(float(row["flight_level"])),
            address=address,
            callsign=_track_callsign(
                None if plot is None else str(plot["callsign"]), previous, address
            ),
            mode3a=mode3a,
            mode3a_changed=previous is not None and previous.mode3a not in (None, mode3a),
            first=previous is None,
            sources=sources,
            status="ended"
            if status == ENDED
            else "coasting"
            if status == COASTING
            else "confirmed",
            last_plot=last_plot,
            ages=SensorAges.model_construct(
                None, **{k: max(time - t, 0.0) for k, t in sensor_times.items()}
            ),
            duplicate_address=address is not None and bool(self._by_address.get(address)),
            adsb_inconsistent=bool(row["adsb_inconsistent"]),
            daps=[DownlinkedParameter.model_construct(**d) for d in _dap_docs(daps, time)],
        )
        if status == ENDED:
            self._tracks.pop(number, None)
        else:
            self._tracks[number] = _SystemTrack(message, last_plot, sensor_times, daps)
            if address is not None:
                self._by_address[address].add(number)
        return message
