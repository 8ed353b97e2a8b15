"""The service: configuration, and later the daemon and replay that run the pipeline."""

from tracker_service.service.config import (
    AdsbFeed,
    ConfigError,
    Input,
    Lan,
    McapConfig,
    Radar,
    ServiceConfig,
    SystemConfig,
    ZenohConfig,
    load_service_config,
    parse_service_config,
)

__all__ = [
    "AdsbFeed",
    "ConfigError",
    "Input",
    "Lan",
    "McapConfig",
    "Radar",
    "ServiceConfig",
    "SystemConfig",
    "ZenohConfig",
    "load_service_config",
    "parse_service_config",
]
