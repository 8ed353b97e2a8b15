"""Sensor status as ASTERIX CAT063 (1.7): per radar or ADS-B feed, as the SDPS sees it.

One record per feed of a ``StatusMessage``: I050 the sensor, I060 its connection status
(CON: operational while it is received, tracked and its clock sane; degraded while it is
received but its tracker stalls or its clock is not sane; not connected while it is
silent), TSV from its time sanity and NPW ("no plot warning", here derived by the SDPS)
while nothing arrives; and, from its latest ``BiasMessage``, the systematic errors as
estimated: I080 range gain and offset, I081 azimuth, I070 time stamping bias, each only
when the estimator can observe it (an unobservable component is its prior: absent
rather than sent as a measurement). The service estimates one set of biases per radar
and corrects PSR and SSR/Mode S plots with it, so I090/I091 (PSR) repeat I080/I081.

The conventions are the spec's and the estimator's alike: rho_measured = (1 + gain) rho
+ offset, theta_measured = theta + azimuth bias (I080/I081 notes), times measured minus
true. The sensor-technology GO/NOGO bits (PSR, SSR, MDS, ADS, MLT) come from the sensors'
own service messages, which the service does not decode: sent 0 (GO, the spec's default).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from tracker_service.outputs.messages import BiasMessage, RadarStatus
from tracker_service.outputs.time_of_day import time_of_day

__all__ = ["CAT063", "CON_DEGRADED", "CON_NOT_CONNECTED", "CON_OPERATIONAL", "sensor_records"]

CAT063 = 63
CON_OPERATIONAL = 0
CON_DEGRADED = 1
CON_NOT_CONNECTED = 3
NM = 1852.0
_GAIN_MAX = 32767e-5
_RANGE_MAX_NM = 32767 / 128
_AZIMUTH_MAX_DEG = 32767 * 360 / 65536
_TIME_MAX_MS = 32767.0


def _capped(value: float, limit: float) -> float:
    return max(-limit, min(value, limit))


def connection(radar: RadarStatus) -> int:
    """I063/060 CON of a feed's status."""
    if not radar.receiving:
        return CON_NOT_CONNECTED
    if not (radar.tracking and radar.time_sane):
        return CON_DEGRADED
    return CON_OPERATIONAL


def sensor_record(
    radar: RadarStatus,
    time: float,
    sac: int,
    sic: int,
    service_id: int,
    bias: BiasMessage | None = None,
) -> dict[str, Any]:
    """The CAT063 item dict of one feed (decoded shape)."""
    sensor_sac, sensor_sic = (int(part) for part in radar.radar.split("/"))
    status: dict[str, int] = {
        "CON": connection(radar),
        "PSR": 0,
        "SSR": 0,
        "MDS": 0,
        "ADS": 0,
        "MLT": 0,
    }
    if not radar.time_sane or not radar.receiving:
        status |= {"OPS": 0, "ODP": 0, "OXT": 0, "MSC": 0}
        status |= {"TSV": int(not radar.time_sane), "NPW": int(not radar.receiving)}
    record: dict[str, Any] = {
        "010": {"SAC": sac, "SIC": sic},
        "015": service_id,
        "030": time_of_day(time),
        "050": {"SAC": sensor_sac, "SIC": sensor_sic},
        "060": status,
    }
    if bias is not None:
        if bias.time_s.observable:
            record["070"] = _capped(bias.time_s.estimate * 1000.0, _TIME_MAX_MS)
        if bias.range_gain.observable or bias.range_offset_m.observable:
            gain = _capped(bias.range_gain.estimate, _GAIN_MAX)
            offset = _capped(bias.range_offset_m.estimate / NM, _RANGE_MAX_NM)
            record["080"] = {"SRG": gain, "SRB": offset}
            record["090"] = {"PRG": gain, "PRB": offset}
        if bias.azimuth_deg.observable:
            azimuth = _capped(bias.azimuth_deg.estimate, _AZIMUTH_MAX_DEG)
            record["081"] = azimuth
            record["091"] = azimuth
    return record


def sensor_records(
    radars: Iterable[RadarStatus],
    time: float,
    sac: int,
    sic: int,
    service_id: int,
    biases: Mapping[str, BiasMessage],
) -> list[dict[str, Any]]:
    return [
        sensor_record(radar, time, sac, sic, service_id, biases.get(radar.radar))
        for radar in radars
    ]
