"""The chain's rows as the service's messages, in one place for every output.

``MessageMapper`` turns local-track rows, system-track rows (with the plots that made
them) and bias estimates into the pydantic messages of ``messages.py``, and remembers
what a system track's next message needs from its previous ones (last plot, sensor ages,
callsign, duplicate addresses). The sinks (``sink.py``) only carry the messages: Zenoh and
the MCAP log publish the same ones.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np
import numpy.typing as npt

from tracker_service.adsb import ADSB_TYP
from tracker_service.bias import ObservedFrom
from tracker_service.fusion import COASTING, ENDED
from tracker_service.geodesy import SystemPlane
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
    iso_time,
    position_sigma_m,
    track_angle_deg,
    wrap_degrees,
)
from tracker_service.outputs.updates import (
    LocalUpdate,
    LocationFix,
    SystemUpdate,
    local_json,
    location_of,
    system_json,
)

__all__ = ["LOCAL_STATUS", "LocationFix", "MessageMapper", "location_fix"]

LocalStatus = Literal["tentative", "confirmed", "coasting", "deleted"]
LOCAL_STATUS: tuple[LocalStatus, ...] = ("tentative", "confirmed", "coasting", "deleted")
# I048/020 TYP: which sensor types a plot of each type is (PSR, SSR, Mode S).
_PSR_TYPES = frozenset((1, 3, 6, 7))
_SSR_TYPES = frozenset((2, 3))
_MODE_S_TYPES = frozenset((4, 5, 6, 7))
_ADSB_TYPES = frozenset((ADSB_TYP,))


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


@dataclass
class _SystemTrack:
    """What the mapper remembers of a live system track between its updates: its last
    message (the batch path keeps the update, whose model is built only when asked for)."""

    last: SystemTrackMessage | SystemUpdate
    last_plot: LastPlot | dict[str, Any] | None = None
    sensor_times: dict[str, float] = field(default_factory=dict)
    daps: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Each DAP's last value and the time of the plot that carried it."""

    @property
    def message(self) -> SystemTrackMessage:
        last = self.last
        return last if isinstance(last, SystemTrackMessage) else last.message()

    @property
    def mode3a(self) -> str | None:
        last = self.last
        return last.mode3a if isinstance(last, SystemTrackMessage) else last.doc["mode3a"]

    @property
    def address(self) -> str | None:
        last = self.last
        return last.address if isinstance(last, SystemTrackMessage) else last.doc["address"]

    @property
    def callsign(self) -> str | None:
        last = self.last
        return last.callsign if isinstance(last, SystemTrackMessage) else last.doc["callsign"]


def location_fix(message: SystemTrackMessage) -> LocationFix:
    return location_of(
        message.time, message.lat, message.lon, message.flight_level, message.covariance
    )


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


class MessageMapper:
    """Rows to messages; its state follows only from the rows it is given, in order."""

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
        return {number: self._tracks[number].message for number in sorted(self._tracks)}

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
            ended.append(track.message.model_copy(update={"status": "ended", "first": False}))
        self._by_address.clear()
        return ended

    # --- the batch path: plain updates with their JSON, no model per update -----------

    def local_updates(self, source: str, rows: npt.NDArray[Any]) -> list[LocalUpdate]:
        """As :meth:`local`, each update as its JSON (``LocalTrackMessage``'s)."""
        n = len(rows)
        if not n:
            return []
        columns = zip(
            rows["track_number"].tolist(),
            rows["time"].tolist(),
            rows["x"].tolist(),
            rows["y"].tolist(),
            rows["vx"].tolist(),
            rows["vy"].tolist(),
            rows["P"].reshape(n, 4, 4).tolist(),
            rows["flight_level"].tolist(),
            (rows["climb_rate_fl_per_s"] * 6000.0).tolist(),
            rows["status"].tolist(),
            rows["plot_id"].tolist(),
            rows["mode3a"].tolist(),
            rows["address"].tolist(),
            rows["model_probabilities"].tolist(),
            strict=True,
        )
        updates = []
        times = self._local_times
        for (
            number,
            time,
            x,
            y,
            vx,
            vy,
            p,
            level,
            rate,
            status_code,
            plot_id,
            code,
            address,
            mu,
        ) in columns:
            status = LOCAL_STATUS[status_code]
            doc = {
                "radar": source,
                "number": number,
                "time": time,
                "x_m": x,
                "y_m": y,
                "vx_mps": vx,
                "vy_mps": vy,
                "covariance": p,
                "flight_level": _none_if_nan(level),
                "climb_rate_fpm": _none_if_nan(rate),
                "status": status,
                "plot_id": plot_id if plot_id >= 0 else None,
                "mode3a": _octal_code(code),
                "address": _hex_address(address),
                "model_probabilities": mu,
            }
            deleted = status == "deleted"
            if deleted:
                times.pop((source, number), None)
            else:
                times[(source, number)] = time
            updates.append(LocalUpdate(number, deleted, local_json(doc)))
        return updates

    def system_updates(
        self, rows: npt.NDArray[Any], plots: npt.NDArray[Any], sources: Sequence[str]
    ) -> list[SystemUpdate]:
        """As :meth:`system`, each update as plain values and its JSON
        (``SystemTrackMessage``'s)."""
        n = len(rows)
        if not n:
            return []
        lat, lon = self.plane.to_geodetic(rows["x"], rows["y"])
        plot_index = {p: i for i, p in enumerate(plots["plot_id"].tolist())}
        plot_lat, plot_lon = self.plane.to_geodetic(plots["x"], plots["y"])
        plot_callsigns = plots["callsign"].tolist()
        plot_columns = (
            plots["time"].tolist(),
            plots["typ"].tolist(),
            plots["rho_m"].tolist(),
            [wrap_degrees(theta) for theta in plots["theta_deg"].tolist()],
            plot_lat.tolist(),
            plot_lon.tolist(),
        )
        covariance = rows["P"].reshape(n, 4, 4).tolist()
        columns = zip(
            rows["system_number"].tolist(),
            rows["time"].tolist(),
            rows["x"].tolist(),
            rows["y"].tolist(),
            rows["vx"].tolist(),
            rows["vy"].tolist(),
            rows["flight_level"].tolist(),
            rows["climb_rate_fl_per_s"].tolist(),
            rows["status"].tolist(),
            rows["fresh"].tolist(),
            rows["radar"].tolist(),
            rows["plot_id"].tolist(),
            rows["address"].tolist(),
            rows["mode3a"].tolist(),
            rows["n_sources"].tolist(),
            rows["local_radars"].tolist(),
            rows["local_numbers"].tolist(),
            rows["local_plot_ids"].tolist(),
            rows["adsb_inconsistent"].tolist(),
            lat.tolist(),
            ((lon + 180.0) % 360.0 - 180.0).tolist(),
            strict=True,
        )
        updates = []
        for k, row in enumerate(columns):
            (number, time, x, y, vx, vy, level, climb, status, fresh, radar, plot_id) = row[:12]
            (address_raw, code_raw, n_sources, radars, numbers, plot_ids, adsb_flag) = row[12:19]
            lat_k, lon_k = row[19:]
            previous = self._tracks.get(number)
            sensor_times = {} if previous is None else previous.sensor_times
            daps = {} if previous is None else previous.daps
            last_plot = None if previous is None else previous.last_plot
            if isinstance(last_plot, LastPlot):
                last_plot = last_plot.model_dump()
            plot = plot_index.get(plot_id)
            plot_callsign = None
            if plot is not None and fresh:
                plot_callsign = str(plot_callsigns[plot])
                plot_time, typ, rho, theta, p_lat, p_lon = (c[plot] for c in plot_columns)
                daps = _remember_daps(daps, plots[plot], plot_time)
                for sensor, types in (
                    ("psr", _PSR_TYPES),
                    ("ssr", _SSR_TYPES),
                    ("mode_s", _MODE_S_TYPES),
                    ("adsb", _ADSB_TYPES),
                ):
                    if typ in types:
                        sensor_times[sensor] = plot_time
                last_plot = {
                    "radar": sources[radar],
                    "time": plot_time,
                    "lat": p_lat,
                    "lon": p_lon,
                    # An ADS-B report has no range and azimuth (NaN).
                    "range_m": _none_if_nan(rho),
                    "azimuth_deg": _none_if_nan(theta),
                }
            track_sources = []
            for slot in range(n_sources):
                local_radar, local = sources[radars[slot]], numbers[slot]
                local_time = self._local_times.get((local_radar, local), time)
                track_sources.append(
                    {
                        "radar": local_radar,
                        "local_track": local,
                        "age_s": max(time - local_time, 0.0),
                        "plot_id": plot_ids[slot] if plot_ids[slot] >= 0 else None,
                    }
                )
            address = _hex_address(address_raw)
            mode3a = _octal_code(code_raw)
            if previous is not None and previous.address is not None:
                self._by_address[previous.address].discard(number)
            ages: dict[str, float | None] = {"psr": None, "ssr": None, "mode_s": None}
            ages |= {"adsb": None} | {s: max(time - t, 0.0) for s, t in sensor_times.items()}
            rate = _none_if_nan(climb)
            doc = {
                "number": number,
                "time": time,
                "time_iso": iso_time(time),
                "lat": lat_k,
                "lon": lon_k,
                "altitude_m": None,
                "flight_level": _none_if_nan(level),
                "x_m": x,
                "y_m": y,
                "vx_mps": vx,
                "vy_mps": vy,
                "ground_speed_mps": math.hypot(vx, vy),
                "track_angle_deg": track_angle_deg(vx, vy),
                "climb_rate_fpm": None if rate is None else rate * 6000.0,
                "covariance": covariance[k],
                "position_sigma_m": position_sigma_m(covariance[k]),
                "address": address,
                "callsign": _track_callsign(plot_callsign, previous, address),
                "mode3a": mode3a,
                "mode3a_changed": previous is not None and previous.mode3a not in (None, mode3a),
                "first": previous is None,
                "sources": track_sources,
                "status": "ended"
                if status == ENDED
                else "coasting"
                if status == COASTING
                else "confirmed",
                "last_plot": last_plot,
                "ages": ages,
                "duplicate_address": address is not None and bool(self._by_address.get(address)),
                "adsb_inconsistent": bool(adsb_flag),
                "daps": _dap_docs(daps, time),
            }
            update = SystemUpdate(number, doc, system_json(doc))
            if status == ENDED:
                self._tracks.pop(number, None)
            else:
                self._tracks[number] = _SystemTrack(update, last_plot, sensor_times, daps)
                if address is not None:
                    self._by_address[address].add(number)
            updates.append(update)
        return updates

    def end_all_updates(self) -> list[SystemUpdate]:
        """As :meth:`end_all`, as updates."""
        ended = []
        for number in sorted(self._tracks):
            track = self._tracks.pop(number)
            last = track.last
            doc = last.model_dump() if isinstance(last, SystemTrackMessage) else dict(last.doc)
            doc |= {"status": "ended", "first": False}
            ended.append(SystemUpdate(number, doc, system_json(doc)))
        self._by_address.clear()
        return ended

    def bias(
        self,
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
        if isinstance(last_plot, dict):
            last_plot = LastPlot.model_construct(**last_plot)
        if plot is not None and plot_position is not None:
            daps = _remember_daps(daps, plot, float(plot["time"]))
            radar = chain_sources[int(row["radar"])]
            typ = int(plot["typ"])
            for sensor, types in (
                ("psr", _PSR_TYPES),
                ("ssr", _SSR_TYPES),
                ("mode_s", _MODE_S_TYPES),
                ("adsb", _ADSB_TYPES),
            ):
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
