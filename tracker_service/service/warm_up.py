"""The kernels a service process calls, compiled (or loaded from numba's cache) before it
takes its first live data.

numba compiles a kernel at its first call in a process, or loads it from its cache
(``__pycache__`` beside the module) when an earlier process compiled it. After an
installation the cache is empty, and a daemon that compiled on its first live data fell
36 s behind and shed a third of its first two minutes' datagrams (docs/reliability.md,
finding 13); on a filled cache each process still loads some hundred kernels in its
first batches, about a second in which the data waits. So every service process, once
its inputs are bound (a UDP port in use is reported at once, as a Zenoh endpoint in use
and a log directory that cannot be written are by the command's checks before it; what
arrives meanwhile waits in their bounded queues), first takes a generated scenario
(``warm_up_scenario``: 120 s of 30 aircraft entering and leaving, seen by a CAT048 radar
on two LANs, a second one, a CAT001 radar and an ADS-B station, with clutter, splits, a
field monitor and a test target) through throwaway copies of its own stages, with the
service's own settings ([tracker], [fusion], [bias] ...: they choose which kernels run),
and only then runs:

- ``warm_radar_stage``: a radar process (``run --role radar``);
- ``warm_core``: the core's process (``run``, ``run --role fusion``: its radar stages
  in other processes, ``remote_radars``); it hands back the calls its throwaway core made
  on its outputs (``OutputCalls``), for
- ``warm_outputs``: the output process, which makes them on throwaway ``Outputs``.

None of it touches the service's own state, sessions or log. What the scenario does not
reach (a fault seen only on some real feed) compiles at its first call, as before; the
per-radar options (``time_base``, ``reference``, fixed transponders) call no kernel of
their own on three_sites (checked by hand, docs/reliability.md finding 13). ``[system]
warm_up = false`` turns it off; ``tracker-service warm-up`` (``run``) fills the cache
without a service.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from asterix.containers import Datagram
from tracker_service.fusion.state import PairEvidence
from tracker_service.radar_stage import RadarStage
from tracker_service.service.config import FoxgloveConfig, ServiceConfig
from tracker_service.service.core import (
    Outputs,
    TrackerService,
    build_radar_stage,
    input_name,
)
from tracker_service.service.signals import Stop
from tracker_service.simulator.scenario import Scenario
from tracker_service.stage_messages import DatagramResult, decode_message, encode_message
from tracker_service.tracking.association.gate import scipy_trees_only

__all__ = [
    "KernelCounts",
    "OutputCalls",
    "WarmUpInput",
    "WarmUpStopped",
    "add_arguments",
    "core_warm_up",
    "feed_core",
    "kernel_counts",
    "radar_warm_up",
    "run",
    "signatures",
    "warm_core",
    "warm_outputs",
    "warm_radar_stage",
    "warm_up_input",
    "warm_up_scenario",
    "warmed",
]

log = logging.getLogger(__name__)

WARM_UP_S = 120.0
"""Long enough for tracks to be confirmed by every radar, fused, corrected for bias, sent
as CAT062 (every 5 s) and ended (aircraft that leave): every periodic duty falls due."""

_SCENARIO: dict[str, Any] = {
    "name": "warm_up",
    "seed": 7,
    "start": "2026-01-01T12:00:00Z",
    "duration_s": WARM_UP_S,
    "system_centre": {"lat": 50.0, "lon": 10.0},
    "radars": [
        {
            "name": "warm-up A",
            "sac": 1,
            "sic": 1,
            "lat": 50.0,
            "lon": 9.3,
            "alt_m": 400.0,
            "antenna_period_s": 4.0,
            "max_range_nm": 120.0,
            "dual_lan": True,
            "bias": {"range_offset_m": 80.0, "azimuth_offset_deg": 0.05},
            "clutter": {"persistent_per_scan": 2, "random_per_scan": 2.0},
            "pathologies": {"split": 0.02, "missing_mode_c": 0.02, "missing_time": 0.02},
            "field_monitor": {"lat": 50.05, "lon": 9.4, "alt_m": 300.0, "address": "FFFFF1"},
            "test_targets": [{"range_nm": 100.0, "azimuth_deg": 45.0}],
        },
        {
            "name": "warm-up B",
            "sac": 1,
            "sic": 2,
            "lat": 50.2,
            "lon": 10.6,
            "alt_m": 500.0,
            "antenna_period_s": 5.0,
            "max_range_nm": 120.0,
            "bias": {"range_offset_m": -60.0, "azimuth_offset_deg": -0.04},
            "ehs_registers": "every_scan",
        },
        {
            "name": "warm-up C",
            "sac": 1,
            "sic": 3,
            "lat": 49.7,
            "lon": 10.1,
            "alt_m": 450.0,
            "antenna_period_s": 6.0,
            "max_range_nm": 120.0,
            "mode_s": False,
            "asterix": "cat001",
        },
    ],
    "adsb_stations": [
        {"name": "warm-up ADS-B", "sac": 1, "sic": 50, "lat": 50.0, "lon": 10.0, "alt_m": 200.0}
    ],
    "traffic": {
        "count": 30,
        "area": {"lat_min": 49.6, "lat_max": 50.4, "lon_min": 9.2, "lon_max": 10.8},
        "turning_fraction": 0.3,
        "climbing_fraction": 0.3,
        "mode_s_fraction": 0.8,
        "psr_only_fraction": 0.1,
        "adsb_fraction": 0.6,
        "mean_flight_s": 60.0,
    },
}


def warm_up_scenario() -> Scenario:
    """The generated traffic every service process warms up on (see the module doc)."""
    return Scenario.model_validate(_SCENARIO)


@dataclass
class WarmUpInput:
    """The warm-up scenario as a service takes it: the service's configuration over the
    scenario's radars, and the datagrams with their input's name, in reception order."""

    config: ServiceConfig
    datagrams: list[tuple[str, Datagram]]


def warm_up_input(config: ServiceConfig | None = None) -> WarmUpInput:
    """``config``'s settings over the warm-up scenario's sources: its radars, ADS-B feeds
    and system plane replaced by the scenario's, its outputs off (no Zenoh, log, ASTERIX
    over UDP or live map: the throwaway stages send nothing anywhere). Without ``config``,
    the scenario's own (the default settings)."""
    # Imported here: the simulator's traffic and radar models are not otherwise loaded
    # by a service process.
    from tracker_service.service.replay import open_replay
    from tracker_service.simulator.run import simulate

    with tempfile.TemporaryDirectory(prefix="tracker-warm-up-") as directory:
        path = Path(directory) / "warm_up.mcap"
        simulate(warm_up_scenario(), path)
        replay = open_replay(path)
        datagrams = list(replay.datagrams)
    scenario = replay.config
    if config is None:
        return WarmUpInput(scenario, datagrams)
    system = config.system.model_copy(
        update={
            "centre_lat": scenario.system.centre_lat,
            "centre_lon": scenario.system.centre_lon,
            "sac": scenario.system.sac,
            "sic": scenario.system.sic,
        }
    )
    warm = config.model_copy(
        update={
            "radars": scenario.radars,
            "adsb": scenario.adsb,
            "system": system,
            "atmosphere": scenario.atmosphere,
            "asterix_udp": [],
            "foxglove": FoxgloveConfig(),
        }
    )
    return WarmUpInput(warm, datagrams)


@dataclass
class KernelCounts:
    """numba's compilations and cache loads in this process so far, over every kernel of
    the service's modules."""

    compiled: int = 0
    loaded: int = 0

    def since(self, before: KernelCounts) -> KernelCounts:
        return KernelCounts(self.compiled - before.compiled, self.loaded - before.loaded)

    def __str__(self) -> str:
        return f"{self.compiled} compiled, {self.loaded} from numba's cache"


def _kernels() -> Iterator[Any]:
    for name, module in list(sys.modules.items()):
        if not (name.startswith("tracker_service.") or name.startswith("asterix.")):
            continue
        for value in list(vars(module).values()):
            # numba's dispatchers, known by what is read of them (numba itself is
            # imported by the kernels' modules, through tracker_service.numba_symbols).
            if all(hasattr(value, a) for a in ("py_func", "signatures", "stats")):
                yield value


def kernel_counts() -> KernelCounts:
    counts = KernelCounts()
    for kernel in {id(k): k for k in _kernels()}.values():
        stats = kernel.stats
        counts.compiled += sum(stats.cache_misses.values())
        counts.loaded += sum(stats.cache_hits.values())
    return counts


def signatures() -> dict[str, set[str]]:
    """Every kernel of the service's modules with the argument types it is compiled for
    in this process (a test compares them before and after real data)."""
    out: dict[str, set[str]] = {}
    for kernel in _kernels():
        key = f"{kernel.py_func.__module__}.{kernel.py_func.__qualname__}"
        out.setdefault(key, set()).update(str(s) for s in kernel.signatures)
    return out


T = TypeVar("T")


def warmed(part: str, warm: Callable[[], T]) -> T | None:
    """``warm()``, or None when it fails: a warm-up that fails (a bug, a full disk for
    its scenario) costs the service its head start, not its start; logged."""
    log.info(
        "warming up the %s: kernels compiled or loaded from numba's cache (seconds; up to "
        "two minutes at the first start after an installation)",
        part,
    )
    try:
        with _quiet():
            return warm()
    except WarmUpStopped:
        raise
    except Exception:
        log.exception("warm-up of the %s failed: its kernels compile at their first call", part)
        return None


class _OthersAndErrors(logging.Filter):
    """Every record but those below ERROR that the thread ``thread`` logs outside this
    module: the throwaway stages' own reports."""

    def __init__(self, thread: int) -> None:
        super().__init__()
        self.thread = thread

    def filter(self, record: logging.LogRecord) -> bool:
        return (
            record.thread != self.thread
            or record.levelno >= logging.ERROR
            or (record.name == log.name)
        )


@contextmanager
def _quiet() -> Iterator[None]:
    """The throwaway stages' own reports kept to errors while they run (their summary at
    their end, the faults the scenario plants, would read as the service's); the rest of
    the process, its inputs' threads already receiving, logs as before."""
    handlers = list(logging.getLogger().handlers)
    only = _OthersAndErrors(threading.get_ident())
    for handler in handlers:
        handler.addFilter(only)
    try:
        yield
    finally:
        for handler in handlers:
            handler.removeFilter(only)


class WarmUpStopped(Exception):
    """The service was told to stop while it warmed up."""


def _check(stop: Stop | None) -> None:
    if stop is not None and stop.is_set():
        raise WarmUpStopped


def warm_radar_stage(warm: WarmUpInput, stop: Stop | None = None) -> None:
    """A radar process's warm-up: a throwaway radar stage through the scenario (its
    batches encoded as the process publishes them), then ``_warm_rare_radar_paths``.
    ``stop`` set: ``WarmUpStopped`` at the next datagram."""
    started, before = time.perf_counter(), kernel_counts()
    _feed_radar_stage(build_radar_stage(warm.config), warm, stop)
    _warm_rare_radar_paths(warm, stop)
    _done("radar stage", started, before)


RARE_PATHS_S = 30.0
"""Of the scenario, what a throwaway stage of the rare paths takes: tracks on every
radar, and batches for them."""


def _feed_radar_stage(
    stage: RadarStage, warm: WarmUpInput, stop: Stop | None, until_s: float = math.inf
) -> None:
    """The scenario's radar datagrams (their first ``until_s`` seconds) through
    ``stage``, published as a radar process publishes them."""
    radar_inputs = {input_name(r.key) for r in warm.config.radars}
    times = [datagram.time or 0.0 for _, datagram in warm.datagrams]  # simulated: all set
    for (name, datagram), t in zip(warm.datagrams, times, strict=True):
        _check(stop)
        if t - times[0] > until_s:
            break
        if name in radar_inputs:
            _published(stage, datagram)


def _warm_rare_radar_paths(warm: WarmUpInput, stop: Stop | None) -> None:
    """Kernels of a radar stage's paths that data takes too rarely for any scenario of
    minutes: the gate's fallback to scipy's trees (``gate.scipy_trees_only``; two
    batches in 60 s of ``scale``, none in the scenario), through a throwaway stage whose
    gates all take it."""
    with scipy_trees_only():
        _feed_radar_stage(build_radar_stage(warm.config), warm, stop, RARE_PATHS_S)


def _warm_rare_core_paths() -> None:
    """Kernels of the core's duties that the scenario's 30 aircraft never call: the
    exchange evidence's sweep (due once 4,096 pairs are held; ``artas`` and ``scale``
    get there within a minute)."""
    PairEvidence(compiled=True).sweep()


def _published(stage: RadarStage, datagram: Datagram) -> bytes | None:
    """A radar datagram through a radar stage, its result encoded as a radar process
    publishes it (``roles.RadarRole``); None when it made no batch."""
    from tracker_service.service.roles import reception_order

    assert datagram.time is not None
    order = reception_order(datagram.time)
    batches = stage.feed(datagram.payload, datagram.time, order)
    return encode_message(DatagramResult(order, datagram.time, batches)) if batches else None


@dataclass
class OutputCalls:
    """What a throwaway core called on its outputs, in order, with the configuration to
    build throwaway ``Outputs`` that take them (``warm_outputs``)."""

    config: ServiceConfig
    calls: list[tuple[str, tuple[Any, ...]]] = field(default_factory=list)


class _CallRecorder:
    """An ``OutputSink`` that keeps each call (the chain hands over nothing it reuses)."""

    pid = None

    def __init__(self, calls: OutputCalls) -> None:
        self._calls = calls.calls

    def __getattr__(self, method: str) -> Any:
        def record(*args: Any) -> None:
            self._calls.append((method, args))

        return record


def warm_core(
    warm: WarmUpInput, remote_radars: bool = False, stop: Stop | None = None
) -> OutputCalls:
    """The core's warm-up: a throwaway chain through the scenario (``feed_core``), the
    calls it made on its outputs kept, then the rare paths (``_warm_rare_radar_paths``
    where the core runs the radar stages, ``_warm_rare_core_paths``). ``stop`` set:
    ``WarmUpStopped`` at the next datagram."""
    started, before = time.perf_counter(), kernel_counts()
    calls = OutputCalls(warm.config)
    feed_core(warm.config, warm.datagrams, _CallRecorder(calls), remote_radars, stop)
    if not remote_radars:  # the fusion process runs no radar stage but its warm-up's
        _warm_rare_radar_paths(warm, stop)
    _warm_rare_core_paths()
    _done("core", started, before)
    return calls


def feed_core(
    config: ServiceConfig,
    datagrams: Iterable[tuple[str, Datagram]],
    outputs: Any,
    remote_radars: bool = False,
    stop: Stop | None = None,
) -> None:
    """``datagrams`` through a core of ``config`` whose outputs are ``outputs`` (an
    ``OutputSink``), closed after. ``remote_radars`` (the fusion process): the radar
    datagrams go through a radar stage here and their batches, encoded and decoded as
    they travel, into the central stage, as the radar processes' batches do; ADS-B
    through the chain, as the fusion process's own inputs."""
    if not remote_radars:
        service = TrackerService(config, outputs=outputs)
        for name, datagram in datagrams:
            _check(stop)
            service.process(name, datagram)
    else:
        from tracker_service.service.roles import NoRadarStages

        service = TrackerService(config, outputs=outputs, radar_stage=NoRadarStages())
        stage = build_radar_stage(config)
        radar_inputs = {input_name(r.key) for r in config.radars}
        for name, datagram in datagrams:
            _check(stop)
            if name not in radar_inputs:
                service.process(name, datagram)
                continue
            published = _published(stage, datagram)
            for batch in [] if published is None else decode_message(published).batches:
                service.process_batch(batch)
    service.close()


def core_warm_up(
    config: ServiceConfig, stop: Stop, remote_radars: bool = False
) -> OutputCalls | None:
    """A core's process (``run``, ``run --role fusion``) before it runs, with ``[system]
    warm_up``: ``warm_core``, and ``warm_outputs`` too, so that the kernels of the output
    process, started next, are in numba's cache by then (it loads them, in a fraction of
    a second, rather than compile them while data waits; a restarted one too).
    The calls for the output process's own warm-up; None when off or failed.
    ``WarmUpStopped`` when ``stop`` is set meanwhile."""
    if not config.system.warm_up:
        return None

    def warm() -> OutputCalls:
        calls = warm_core(warm_up_input(config), remote_radars, stop)
        _check(stop)  # after it, the caller looks
        warm_outputs(calls)
        return calls

    return warmed("core", warm)


def radar_warm_up(config: ServiceConfig, stop: Stop) -> None:
    """A radar process (``run --role radar``) before it runs, with ``[system] warm_up``:
    ``warm_radar_stage``. ``WarmUpStopped`` when ``stop`` is set meanwhile."""
    if config.system.warm_up:
        warmed("radar stage", lambda: warm_radar_stage(warm_up_input(config), stop))


def warm_outputs(calls: OutputCalls) -> None:
    """The output process's warm-up: throwaway ``Outputs`` make a throwaway core's
    calls."""
    started, before = time.perf_counter(), kernel_counts()
    outputs = Outputs(calls.config)
    for method, args in calls.calls:
        getattr(outputs, method)(*args)
    outputs.stop()
    _done("outputs", started, before)


def _done(part: str, started: float, before: KernelCounts) -> None:
    log.info(
        "warm-up of the %s: %.1f s, kernels %s",
        part,
        time.perf_counter() - started,
        kernel_counts().since(before),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        help="the service's configuration: its settings ([tracker], [fusion], [bias] ...) "
        "choose which kernels run (default: the default settings)",
    )


def run(args: argparse.Namespace) -> int:
    """``tracker-service warm-up``: every stage through the warm-up scenario in this
    process, so that numba's cache holds their kernels (as the user the service runs as:
    an installation's own directory may not be writable to it, and numba then caches
    per user)."""
    from tracker_service.log_level import configure
    from tracker_service.service.config import ConfigError, load_service_config

    configure()
    try:
        config = None if args.config is None else load_service_config(args.config)
    except ConfigError as exc:
        print(f"tracker-service warm-up: {exc}", file=sys.stderr)
        return 2
    started, before = time.perf_counter(), kernel_counts()

    def warm() -> bool:
        scenario = warm_up_input(config)  # simulated once for both of the core's paths
        warm_outputs(warm_core(scenario))
        warm_outputs(warm_core(scenario, remote_radars=True))
        return True

    if warmed("service", warm) is None:
        return 1
    caches = sorted({k.stats.cache_path for k in _kernels() if k.signatures})
    print(
        f"kernels {kernel_counts().since(before)} in {time.perf_counter() - started:.1f} s; "
        f"numba's cache: {', '.join(caches[:2])}{' ...' if len(caches) > 2 else ''}"
    )
    return 0
