"""The JSON of a batch's track messages, written from its columns (``json_rows``): one
template per message type, filled for every update of the batch at once, byte for byte
what the models' ``model_dump_json`` writes (``LocalTrackMessage``,
``SystemTrackMessage``: ``tests/test_outputs_updates.py``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from tracker_service.outputs.json_rows import (
    HEX6,
    INTEGER,
    INTEGER_OR_NULL,
    JOIN,
    LITERAL,
    NUMBER,
    OCTAL4,
    PART_OR_NULL,
    Literals,
    Numbers,
    Rendered,
    Template,
    render,
)
from tracker_service.outputs.messages import DAP_NAMES
from tracker_service.outputs.updates import STATUSES, SystemBatch

__all__ = ["MessageWriter", "iso_times"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

_COVARIANCE = "[[%s,%s,%s,%s],[%s,%s,%s,%s],[%s,%s,%s,%s],[%s,%s,%s,%s]]"
_LOCAL = (
    '{"radar":%s,"number":%s,"time":%s,"x_m":%s,"y_m":%s,"vx_mps":%s,"vy_mps":%s,'
    f'"covariance":{_COVARIANCE},"flight_level":%s,"climb_rate_fpm":%s,"status":%s,'
    '"plot_id":%s,"mode3a":%s,"address":%s,"model_probabilities":[%s]}'
)
_LOCAL_NUMBERS = 23
"""time, x, y, vx, vy, the 16 of the covariance, flight level, climb rate (ft/min)."""
_SYSTEM = (
    '{"number":%s,"time":%s,"time_iso":%s,"lat":%s,"lon":%s,"altitude_m":%s,'
    '"flight_level":%s,"x_m":%s,"y_m":%s,"vx_mps":%s,"vy_mps":%s,"ground_speed_mps":%s,'
    f'"track_angle_deg":%s,"climb_rate_fpm":%s,"covariance":{_COVARIANCE},'
    '"position_sigma_m":%s,"address":%s,"callsign":%s,"mode3a":%s,"mode3a_changed":%s,'
    '"first":%s,"sources":[%s],"status":%s,"last_plot":%s,'
    '"ages":{"psr":%s,"ssr":%s,"mode_s":%s,"adsb":%s},"duplicate_address":%s,'
    '"adsb_inconsistent":%s,"daps":[%s]}'
)
_SYSTEM_NUMBERS = 29
"""time, lat, lon, altitude, flight level, x, y, vx, vy, ground speed, track angle, climb
rate, the 16 of the covariance, position sigma: the state's numbers, in the template's
order."""
_SOURCE = '{"radar":%s,"local_track":%s,"age_s":%s,"plot_id":%s}'
_DAP = '{"name":%s,"value":%s,"age_s":%s}'
_LAST_PLOT = '{"radar":%s,"time":%s,"lat":%s,"lon":%s,"range_m":%s,"azimuth_deg":%s}'


def iso_times(posix: FloatArray) -> list[str]:
    """``messages.iso_time`` of each time, at once: microseconds rounded half to even as
    ``datetime.fromtimestamp`` rounds them (held to it by a test)."""
    whole = np.floor(posix)
    micro = whole.astype(np.int64) * 1_000_000 + np.rint((posix - whole) * 1e6).astype(np.int64)
    text = np.datetime_as_string(micro.astype("datetime64[us]"), unit="us")
    return [t + "Z" for t in text.tolist()]


class MessageWriter:
    """Writes the messages of batches; keeps the texts they share (``Literals``)."""

    def __init__(self) -> None:
        literals = self.literals = Literals()
        self._local = Template.of(
            _LOCAL,
            [
                LITERAL,
                INTEGER,
                *([NUMBER] * _LOCAL_NUMBERS),
                LITERAL,
                INTEGER_OR_NULL,
                OCTAL4,
                HEX6,
                JOIN,
            ],
            literals,
        )
        self._probability = Template.of("%s", [NUMBER], literals)
        self._system = Template.of(
            _SYSTEM,
            [INTEGER, NUMBER, PART_OR_NULL, *[NUMBER] * (_SYSTEM_NUMBERS - 1)]
            + [HEX6, LITERAL, OCTAL4, LITERAL, LITERAL, JOIN, LITERAL, PART_OR_NULL]
            + [NUMBER] * 4
            + [LITERAL, LITERAL, JOIN],
            literals,
        )
        self._source = Template.of(_SOURCE, [LITERAL, INTEGER, NUMBER, INTEGER_OR_NULL], literals)
        self._dap = Template.of(_DAP, [LITERAL, NUMBER, NUMBER], literals)
        self._last_plot = Template.of(_LAST_PLOT, [LITERAL, *[NUMBER] * 5], literals)
        self._null = literals.add(b"null")
        self._booleans = np.array([literals.add(b"false"), literals.add(b"true")])
        self._local_statuses = np.array(
            [literals.string(s) for s in ("tentative", "confirmed", "coasting", "deleted")]
        )
        self._statuses = np.array([literals.string(s) for s in STATUSES])
        self._dap_names = np.array([literals.string(name) for name in DAP_NAMES])

    def local(
        self,
        radar: int,
        number: IntArray,
        numbers: FloatArray,
        status: IntArray,
        plot_id: IntArray,
        mode3a: IntArray,
        address: IntArray,
        probabilities: FloatArray,
    ) -> list[bytes]:
        """Local-track messages: ``radar`` the literal id of the radar's JSON string,
        ``numbers`` (N, 23) as ``_LOCAL`` takes them, ``probabilities`` (N, models)."""
        n, models = probabilities.shape
        texts = Numbers.of(np.concatenate((numbers.ravel(), probabilities.ravel())))
        values = np.empty((n, self._local.slots), dtype=np.int64)
        values[:, 0] = radar
        values[:, 1] = number
        values[:, 2 : 2 + _LOCAL_NUMBERS] = np.arange(n * _LOCAL_NUMBERS).reshape(n, -1)
        values[:, 25] = self._local_statuses[status]
        values[:, 26] = plot_id
        values[:, 27] = mode3a
        values[:, 28] = address
        values[:, 29] = np.arange(n) * models
        counts = np.zeros_like(values)
        counts[:, 29] = models
        probability = np.arange(n * _LOCAL_NUMBERS, n * (_LOCAL_NUMBERS + models))
        parts = render(self._probability, probability[:, None], self.literals, texts)
        return render(self._local, values, self.literals, texts, counts, parts).rows()

    def system(
        self,
        batch: SystemBatch,
        radar_ids: IntArray,
        sigma: FloatArray,
        local_numbers: IntArray,
        local_plot_ids: IntArray,
        source_ages: FloatArray,
        plot_position: FloatArray,
    ) -> list[bytes]:
        """System-track messages: ``batch`` the updates' values, ``radar_ids`` the literal
        id of each of its ``radar_names``' JSON string, ``sigma`` the position sigmas,
        ``local_numbers``, ``local_plot_ids`` and ``source_ages`` of the sources (the
        first ``n_sources`` of each row), ``plot_position`` the last plots' time, lat,
        lon, range and azimuth (NaN where none)."""
        n = len(batch)
        state = np.column_stack(
            (
                batch.time,
                batch.lat,
                batch.lon,
                batch.altitude_m,
                batch.flight_level,
                batch.x,
                batch.y,
                batch.vx,
                batch.vy,
                batch.ground_speed,
                batch.track_angle,
                batch.climb_rate_fpm,
                batch.covariance,
                sigma,
            )
        )
        used = np.arange(source_ages.shape[1]) < batch.n_sources[:, None]
        source_rows = used.nonzero()
        sources = int(used.sum())
        dap_rows, dap_columns = batch.has_dap.nonzero()
        daps = dap_rows.size
        has_plot = batch.plot_radar >= 0
        plots = int(has_plot.sum())
        # Every number of the batch in one list: the states, the sources' ages, the sensor
        # ages, the DAPs' values and ages, the last plots.
        blocks = (
            state.ravel(),
            source_ages[source_rows],
            batch.ages.ravel(),
            np.column_stack(
                (batch.dap_value[dap_rows, dap_columns], batch.dap_age[dap_rows, dap_columns])
            ).ravel(),
            plot_position[has_plot].ravel(),
        )
        starts = np.cumsum([0, *(block.size for block in blocks)])
        texts = Numbers.of(np.concatenate(blocks))
        first_source = np.cumsum(used.sum(axis=1)) - used.sum(axis=1)
        first_dap = np.cumsum(batch.has_dap.sum(axis=1)) - batch.has_dap.sum(axis=1)
        iso = iso_times(batch.time)
        parts = _joined(
            render(
                self._source,
                np.column_stack(
                    (
                        radar_ids[batch.source_radar[source_rows]],
                        local_numbers[source_rows],
                        starts[1] + np.arange(sources),
                        local_plot_ids[source_rows],
                    )
                ),
                self.literals,
                texts,
            ),
            render(
                self._dap,
                np.column_stack(
                    (
                        self._dap_names[dap_columns],
                        starts[3] + 2 * np.arange(daps),
                        starts[3] + 2 * np.arange(daps) + 1,
                    )
                ),
                self.literals,
                texts,
            ),
            render(
                self._last_plot,
                np.column_stack(
                    (
                        radar_ids[batch.plot_radar[has_plot]],
                        starts[4] + 5 * np.arange(plots)[:, None] + np.arange(5),
                    )
                ),
                self.literals,
                texts,
            ),
            _quoted(iso),
        )
        last_plot = np.full(n, -1, dtype=np.int64)
        last_plot[has_plot] = sources + daps + np.arange(plots)
        values = np.empty((n, self._system.slots), dtype=np.int64)
        counts = np.zeros_like(values)
        values[:, 0] = batch.number
        values[:, 1] = _SYSTEM_NUMBERS * np.arange(n)
        values[:, 2] = sources + daps + plots + np.arange(n)
        values[:, 3 : 2 + _SYSTEM_NUMBERS] = values[:, 1:2] + np.arange(1, _SYSTEM_NUMBERS)
        column = 2 + _SYSTEM_NUMBERS
        values[:, column] = batch.address
        # The mapper's callsign ids are the literal ids of their JSON strings.
        values[:, column + 1] = np.where(batch.callsign >= 0, batch.callsign, self._null)
        values[:, column + 2] = batch.mode3a
        values[:, column + 3] = self._booleans[batch.mode3a_changed.view(np.int8)]
        values[:, column + 4] = self._booleans[batch.first.view(np.int8)]
        values[:, column + 5] = first_source
        counts[:, column + 5] = batch.n_sources
        values[:, column + 6] = self._statuses[batch.status]
        values[:, column + 7] = last_plot
        values[:, column + 8 : column + 12] = starts[2] + 4 * np.arange(n)[:, None] + np.arange(4)
        values[:, column + 12] = self._booleans[batch.duplicate_address.view(np.int8)]
        values[:, column + 13] = self._booleans[batch.adsb_inconsistent.view(np.int8)]
        values[:, column + 14] = sources + first_dap
        counts[:, column + 14] = batch.has_dap.sum(axis=1)
        return render(self._system, values, self.literals, texts, counts, parts).rows()


def _quoted(texts: Sequence[str]) -> Rendered:
    """Strings that need no escaping (ISO times) as JSON strings, rows of a rendering."""
    data = ('"' + '""'.join(texts) + '"').encode() if texts else b"\0"
    lengths = np.fromiter(map(len, texts), dtype=np.int64, count=len(texts)) + 2
    ends = np.cumsum(lengths)
    return Rendered(np.frombuffer(data, dtype=np.uint8), ends - lengths, ends)


def _joined(*parts: Rendered) -> Rendered:
    """Renderings one after another: their rows renumbered in that order."""
    offsets = np.cumsum([0, *(part.data.size for part in parts)])
    return Rendered(
        np.concatenate([part.data for part in parts]),
        np.concatenate([part.starts + o for part, o in zip(parts, offsets, strict=False)]),
        np.concatenate([part.ends + o for part, o in zip(parts, offsets, strict=False)]),
    )
