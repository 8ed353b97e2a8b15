"""The SDPS identity the ASTERIX outputs write (I010 SAC/SIC, I015 service) and the plane
their positions are in: what the outputs read of the configuration, as a protocol, so that
they depend on no configuration module."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from tracker_service.geodesy.plane import PlaneKind


class SdpsIdentity(Protocol):
    """``service.config.SystemConfig`` is one. Hashable: the encoders cache per identity."""

    def __hash__(self) -> int: ...

    @property
    def sac(self) -> int: ...

    @property
    def sic(self) -> int: ...

    @property
    def service_id(self) -> int: ...

    @property
    def centre_lat(self) -> float: ...

    @property
    def centre_lon(self) -> float: ...

    @property
    def projection(self) -> PlaneKind: ...


@dataclass(frozen=True)
class Sdps:
    """An ``SdpsIdentity`` as plain values."""

    sac: int
    sic: int
    service_id: int
    centre_lat: float
    centre_lon: float
    projection: PlaneKind

    @classmethod
    def of(cls, identity: SdpsIdentity, service_id: int | None = None) -> Sdps:
        """``identity``, with another service (I015) when ``service_id`` is given."""
        return cls(
            identity.sac,
            identity.sic,
            identity.service_id if service_id is None else service_id,
            identity.centre_lat,
            identity.centre_lon,
            identity.projection,
        )
