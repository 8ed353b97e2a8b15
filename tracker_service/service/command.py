"""The service's commands: ``replay``, ``run`` and ``health``; what they share."""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import gc
import logging
import math
import multiprocessing
import os
import pickle
import queue
import signal
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Self

import numpy.typing as npt

from asterix.containers import Datagram
from tracker_service.adsb_status import AdsbCount
from tracker_service.bias import ObservedFrom
from tracker_service.chain import BatchOutput, RadarStageFailed, RadarStages
from tracker_service.distribution import RemoteRadarStages
from tracker_service.inputs.udp import InputCounters
from tracker_service.log_level import configure
from tracker_service.loop_load import LoopLoad
from tracker_service.outputs.foxglove_sink import FoxgloveListenError, check_listen
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.messages import StatusMessage
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_session import (
    TLS_PROTOCOLS,
    PlaintextEndpointError,
    ZenohConfigError,
    ZenohEndpointError,
    check_listen_endpoints,
    endpoint_protocol,
    zenoh_config,
)
from tracker_service.ratelimit import RateLimitedLog
from tracker_service.service.call_pickle import CallPickler
from tracker_service.service.config import (
    ConfigError,
    ServiceConfig,
    load_service_config,
    with_destinations,
)
from tracker_service.service.core import (
    CoreState,
    Outputs,
    OutputsFailed,
    ServiceCounts,
    TrackerService,
)
from tracker_service.service.health import (
    DEFAULT_BEHIND_S,
    DEFAULT_SILENT_FOR_S,
    unhealthy_reasons,
)
from tracker_service.service.replay import (
    CONFIG_METADATA,
    Progress,
    Replay,
    open_replay,
    parse_date,
    parse_speed,
)
from tracker_service.service.signals import StopSignal, stop_on_signals
from tracker_service.service.warm_up import OutputCalls, warm_outputs, warmed

__all__ = [
    "OutputProcess",
    "OutputProcessFailed",
    "OutputSummary",
    "add_health_arguments",
    "add_replay_arguments",
    "add_run_arguments",
    "health",
    "open_outputs",
    "open_service",
    "replay",
    "stop_on_signals",
]

log = logging.getLogger(__name__)

PIPE_BYTES = 1024 * 1024
"""Room in the pipe to the output process (Linux caps it at /proc/sys/fs/pipe-max-size)."""


def _add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tls/0.0.0.0:7447 (repeatable); added to "
        "[zenoh] listen and to --zenoh-config's",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint (router or peer) to connect to (repeatable); added to "
        "[zenoh] connect and to --zenoh-config's",
    )
    parser.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh JSON5 configuration: TLS, access control, routers (docs/security.md)",
    )
    parser.add_argument(
        "--zenoh-scouting",
        action="store_true",
        help="find and answer peers by multicast and gossip scouting (off by default)",
    )
    parser.add_argument(
        "--zenoh-allow-plaintext",
        action="store_true",
        help="allow a plaintext endpoint (tcp/, udp/...) beside a --zenoh-config that "
        "configures TLS (refused by default)",
    )


def _add_asterix_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--asterix-udp",
        action="append",
        default=[],
        metavar="HOST:PORT",
        help="send CAT062 system tracks on update, CAT065 SDPS status and CAT063 sensor "
        "status to this multicast group or unicast address (repeatable); added to "
        "[[asterix_udp]]",
    )


def _add_foxglove_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--foxglove-listen",
        metavar="HOST:PORT",
        help="serve a live view to the Foxglove app on ws://HOST:PORT, e.g. 127.0.0.1:8765 "
        "(needs pip install 'tracker-service[foxglove]'); sets [foxglove] listen",
    )


def add_replay_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        help="a simulator recording or a log of the service (.mcap, or a directory of "
        "logs), or a pcap/pcapng/GPS/final/raw/hex capture",
    )
    parser.add_argument(
        "--speed",
        type=parse_speed,
        default=1.0,
        metavar="1|N|max",
        help="pace: reception times divided by N, or 'max' for as fast as possible "
        "(default 1, real time)",
    )
    parser.add_argument(
        "--config",
        help="service configuration (radars, system plane, settings); "
        "default: the recording's metadata",
    )
    parser.add_argument(
        "--date",
        type=parse_date,
        metavar="YYYY-MM-DD",
        help="the UTC day of a capture that holds times of day only (GPS, final, raw, hex)",
    )
    parser.add_argument("--mcap-dir", help="write the service's MCAP log into this directory")
    parser.add_argument(
        "--workers",
        type=int,
        default=0,
        metavar="N",
        help="run the radar stages in N worker processes and the central stage (bias, "
        "fusion) in this one, over Zenoh on 127.0.0.1, the outputs in a process of their own "
        "(default 0: everything in this process); the messages are the same either way",
    )
    parser.add_argument(
        "--output-process",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the outputs (messages, CAT062, MCAP log, Foxglove map, Zenoh) in a process of "
        "their own, as the daemon runs them (default: with --workers only); the messages "
        "are the same either way; the process dying ends the replay with status 1",
    )
    _add_zenoh_arguments(parser)
    _add_asterix_arguments(parser)
    _add_foxglove_arguments(parser)


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="service configuration (TOML)")
    parser.add_argument(
        "--health-file",
        help="a file the daemon writes each status message into, as JSON (for a "
        "container's health check: `tracker-service health --file FILE`)",
    )
    parser.add_argument(
        "--role",
        choices=("radar", "fusion"),
        help="run one stage (docs/deployment.md): 'radar' the radar stages of --radars, "
        "published over Zenoh; 'fusion' fusion and the outputs, fed by the radar "
        "processes; default: everything in this process",
    )
    parser.add_argument(
        "--radars",
        type=lambda text: [part.strip() for part in text.split(",") if part.strip()],
        default=[],
        metavar="SAC/SIC,...",
        help="with --role radar: the configured radars whose inputs this process takes",
    )
    parser.add_argument(
        "--stage-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="with --role: Zenoh endpoint of the stage session to listen on, e.g. "
        "tls/0.0.0.0:7450 (repeatable; the [zenoh] config_file and mode apply)",
    )
    parser.add_argument(
        "--stage-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="with --role: Zenoh endpoint of the stage session to connect to (repeatable)",
    )
    _add_zenoh_arguments(parser)
    _add_asterix_arguments(parser)
    _add_foxglove_arguments(parser)


def add_health_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--file", required=True, help="the daemon's --health-file")
    parser.add_argument(
        "--max-age",
        type=float,
        default=30.0,
        help="seconds since the last status beyond which the daemon is unhealthy",
    )
    parser.add_argument(
        "--live",
        action="store_true",
        help="only whether the daemon runs (a fresh status), whatever its health: for a "
        "liveness probe that restarts the container, which a silent radar must not do",
    )
    parser.add_argument(
        "--container",
        action="store_true",
        help="a container's health check (exit 0 healthy, 1 unhealthy, never 2): unhealthy "
        "when the status is stale, every radar silent for --silent-for seconds or the chain "
        "--behind seconds behind; a degraded status is printed but healthy",
    )
    parser.add_argument(
        "--silent-for",
        type=float,
        default=DEFAULT_SILENT_FOR_S,
        metavar="S",
        help=f"with --container: every radar silent this long is unhealthy (default "
        f"{DEFAULT_SILENT_FOR_S:g})",
    )
    parser.add_argument(
        "--behind",
        type=float,
        default=DEFAULT_BEHIND_S,
        metavar="S",
        help=f"with --container: the chain this far behind the wall clock is unhealthy "
        f"(default {DEFAULT_BEHIND_S:g})",
    )


def _with_cli(config: ServiceConfig, args: argparse.Namespace) -> ServiceConfig:
    """The configuration with the command line's Zenoh settings on top: endpoints
    added, scouting and plaintext when either asks. Checked here, so that a Zenoh file
    or endpoint that cannot work (a listen port in use), or TLS turned plaintext, is
    one line at start-up, not after the warm-up."""
    zenoh = config.zenoh
    updates: dict[str, object] = {
        "listen": list(dict.fromkeys([*zenoh.listen, *args.zenoh_listen])),
        "connect": list(dict.fromkeys([*zenoh.connect, *args.zenoh_connect])),
        "scouting": zenoh.scouting or args.zenoh_scouting,
        "allow_plaintext": zenoh.allow_plaintext or args.zenoh_allow_plaintext,
    }
    if args.zenoh_config:
        updates["config_file"] = Path(args.zenoh_config)
    zenoh = zenoh.model_copy(update=updates)
    try:
        check_listen_endpoints(
            zenoh_config(
                zenoh.mode,
                zenoh.listen,
                zenoh.connect,
                zenoh.config_file,
                scouting=zenoh.scouting,
                allow_plaintext=zenoh.allow_plaintext,
            )
        )
    except ZenohEndpointError as exc:
        raise ConfigError(str(exc)) from None
    except PlaintextEndpointError as exc:
        cli = {"listen": args.zenoh_listen, "connect": args.zenoh_connect}[exc.direction]
        if exc.endpoint in cli:
            raise ConfigError(
                exc.describe(f"--zenoh-{exc.direction}", "give --zenoh-allow-plaintext")
            ) from None
        raise ConfigError(
            exc.describe(f"[zenoh] {exc.direction}", "set [zenoh] allow_plaintext = true")
        ) from None
    except ZenohConfigError as exc:
        raise ConfigError(f"zenoh: {exc}") from None
    try:
        config = with_destinations(config, getattr(args, "asterix_udp", []))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return _with_foxglove(config.model_copy(update={"zenoh": zenoh}), args)


def _with_foxglove(config: ServiceConfig, args: argparse.Namespace) -> ServiceConfig:
    """``--foxglove-listen`` on top of ``[foxglove] listen``, checked now (the SDK there,
    the port free) so that a live view that cannot start is one line at start-up."""
    listen = getattr(args, "foxglove_listen", None) or config.foxglove.listen
    if listen is None:
        return config
    try:
        check_listen(listen)
    except FoxgloveListenError as exc:
        raise ConfigError(str(exc)) from None
    foxglove = config.foxglove.model_copy(update={"listen": listen})
    return config.model_copy(update={"foxglove": foxglove})


@contextmanager
def open_outputs(
    config: ServiceConfig, mcap_dir: Path | None, *, zenoh: bool = True
) -> Iterator[tuple[ZenohPublisher | None, McapLog | None]]:
    """The Zenoh session and the MCAP log of a configuration, closed on the way out."""
    publisher = None
    mcap = None
    try:
        if zenoh:
            z = config.zenoh
            publisher = ZenohPublisher(
                z.prefix,
                mode=z.mode,
                listen=z.listen,
                connect=z.connect,
                config_file=z.config_file,
                scouting=z.scouting,
                allow_plaintext=z.allow_plaintext,
            )
        if mcap_dir is not None:
            m = config.mcap
            mcap = McapLog(
                mcap_dir,
                m.rotate_size_mb,
                m.rotate_duration_s,
                m.chunk_size,
                metadata={CONFIG_METADATA: {"config": config.model_dump_json()}},
            )
        yield publisher, mcap
    finally:
        if publisher is not None:
            publisher.close()
        if mcap is not None:
            mcap.close()


def freeze_start_up() -> None:
    """What start-up built (modules, configuration, kernels' dispatchers: some 150,000
    objects) lives as long as the process: out of the cyclic collector's sight
    (``gc.freeze``), so that its full collections scan only what the chain made since.
    The chain makes almost no cycles (a 120 s ``artas`` replay: 2,200 objects
    collected in all), but each full collection scanned everything: 100-190 ms pauses
    of the chain every 20-50 CPU-s on ``artas`` (docs/benchmarks.md, "Session 12")."""
    gc.collect()
    gc.freeze()


def freeze_survivors() -> None:
    """From now on, what survives each full collection of the cyclic collector goes out
    of its sight too (``gc.freeze`` at the collection's end), so that each full
    collection scans only what became long-lived since the last one. The output
    process holds some 70,000 objects with 400,000 references for its picture of 4,000
    tracks (the messages' state, the map's trails, CAT062's pending updates, the log's
    chunk index), each one replaced within minutes: a full collection of all of them
    paused its calls 44-57 ms (docs/benchmarks.md, "Session 15"). A frozen object is
    still freed when its last reference goes; only a reference cycle made of objects
    that had survived a full collection would never be collected, and the outputs make
    next to none (``benchmarks/bench_output_calls.py calls`` counts them at its end).
    At the collection's end the younger generations are empty: no garbage is frozen.
    The core's process (the daemon, the fusion role) has it too: its full collections
    scanned the fusion state's ~54,000 objects 12 s into ``artas``, 11-20 ms, more as the
    picture grows, and the central stage makes as few cycles (20 objects in 40 s of
    ``artas``: docs/benchmarks.md, "Session 16")."""
    if _freeze_after_full_collection not in gc.callbacks:
        gc.callbacks.append(_freeze_after_full_collection)


@contextmanager
def survivors_frozen() -> Iterator[None]:
    """``freeze_survivors`` while the block runs (the service's life in the core's
    process), no longer after it (a test's process goes on)."""
    installed = _freeze_after_full_collection not in gc.callbacks
    freeze_survivors()
    try:
        yield
    finally:
        if installed:
            gc.callbacks.remove(_freeze_after_full_collection)


def _freeze_after_full_collection(phase: str, info: dict[str, int]) -> None:
    if phase == "stop" and info["generation"] == 2:
        gc.freeze()


SWITCH_INTERVAL_S = 0.001
"""How long a thread of a service process may keep the GIL while another waits for it
(Python's default: 5 ms). A plot's way through the service is a chain of threads that
wake and need the GIL from one that computes: a radar process's UDP reader, the fusion
process's Zenoh callback, the output process's reader of the core's calls, its Zenoh
sink's thread; each of them waits for the computing thread to let go, at worst the whole
interval. At 1 ms a woken thread's wait went from 5.1 to 1.1 ms (p50) for 1.6 % of the
computing thread's work (``benchmarks/bench_switch_interval.py``); what it gives the
service end to end was within the host's noise in four live runs of ``artas``
(docs/benchmarks.md, "Session 20")."""


@contextmanager
def short_switch_interval() -> Iterator[None]:
    """``SWITCH_INTERVAL_S`` while the block runs (a service's life), the interval before
    it after (a test's process goes on)."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield
    finally:
        sys.setswitchinterval(previous)


@contextmanager
def open_service(
    config: ServiceConfig,
    mcap_dir: Path | None,
    *,
    zenoh: bool = True,
    output_process: bool = False,
    supervised: bool = True,
    health_file: Path | None = None,
    radar_stage: RadarStages | None = None,
    warm_up: OutputCalls | None = None,
) -> Iterator[TrackerService]:
    """The core with its Zenoh session and MCAP log, in this process or, with
    ``output_process``, in a process of their own (which writes each status into
    ``health_file``, and is restarted when it dies if ``supervised``: ``OutputProcess``;
    it first makes the calls of a throwaway core's warm-up, ``warm_up``, on throwaway
    outputs); on the way out every live track is ended, then the session and the log are
    closed, whatever happened."""
    if output_process:
        with OutputProcess(
            config,
            mcap_dir,
            zenoh=zenoh,
            health_file=health_file,
            supervised=supervised,
            warm_up=warm_up,
        ) as outputs:
            service = TrackerService(config, outputs=outputs, radar_stage=radar_stage)
            freeze_start_up()
            with survivors_frozen(), short_switch_interval():
                try:
                    yield service
                finally:
                    service.close()
        return
    with open_outputs(config, mcap_dir, zenoh=zenoh) as (publisher, mcap):
        service = TrackerService(config, publisher, mcap, radar_stage=radar_stage)
        freeze_start_up()
        with survivors_frozen(), short_switch_interval():
            try:
                yield service
            finally:
                service.close()


class OutputStartFailed(RuntimeError):
    """The output process could not open its session or its log (a Zenoh port in use, a
    log directory not writable); the message says which, in one line."""


class OutputProcessFailed(OutputsFailed):
    """The output process died more often than ``[system] max_output_restarts`` within
    ``RESTART_WINDOW_S``: the daemon gives up, with a non-zero exit status."""


RESTART_WINDOW_S = 600.0
"""A daemon restarts a dead output process itself (the chain keeps its tracks, the outputs
resume within seconds), but not without end: more than ``[system] max_output_restarts``
deaths within this window is a fault a restart does not cure, so the daemon exits with
status 1 and a one-line error, and the service manager (systemd ``Restart=on-failure``,
Docker ``restart: on-failure``) takes over."""


@dataclass
class OutputSummary:
    """What an output process that ended normally hands back: the totals a replay
    prints, its log's files, and its CPU seconds (``time.process_time``)."""

    counts: ServiceCounts
    log_files: list[Path]
    cpu_s: float


class OutputProcess:
    """``Outputs`` (messages, Zenoh, CAT062, MCAP) in a process of its own, so that the
    chain keeps a core to itself: each call of the core goes, pickled at once (the chain
    reuses nothing it hands over, but a later pickle would race with it), through a pipe
    to the process, which makes the same calls in the same order, so the messages are the
    ones ``Outputs`` makes in the core's process. ``close`` (the core's) ends the tracks
    there; leaving the context waits for the process to drain the pipe and exit.

    Supervised (the daemon): when the process dies (killed, out of memory), the next call
    finds it gone, logs it, and starts a new one (see ``RESTART_WINDOW_S``); the calls in the
    pipe at that moment are lost, and the new process starts without the old one's picture
    (every live track's next update is a "first" again). The status reports each restart.
    Not supervised (the replay, whose log must be the one-process log or none): its death
    is an ``OutputProcessFailed`` at the next call.

    A process that ends normally (the context left after ``close``) sends back its
    ``OutputSummary``: ``summary``, None until then."""

    def __init__(
        self,
        config: ServiceConfig,
        mcap_dir: Path | None,
        *,
        zenoh: bool = True,
        health_file: Path | None = None,
        supervised: bool = True,
        warm_up: OutputCalls | None = None,
    ) -> None:
        # A live (supervised) output process measures its loop for the status's busy; a
        # replay's status stays a function of its recording.
        self._args = (config, mcap_dir, zenoh, health_file, supervised)
        self._warm_up = warm_up
        """For the first process only (a restarted one finds its kernels in the cache its
        predecessor filled, and the core should not wait for it any longer); its calls are
        dropped once that process has them, so that nothing keeps them."""
        self._supervised = supervised
        self.summary: OutputSummary | None = None
        self.restarts = 0
        self.last_restart: str | None = None
        self._deaths: list[float] = []
        self._data_time: float | None = None
        self._failed: str | None = None
        """Why the process is given up on, once it is."""
        self._start()

    def _start(self) -> None:
        # Spawned, not forked: the parent may hold threads (inputs, Zenoh) by now.
        context = multiprocessing.get_context("spawn")
        # A pipe written by the core's own thread: a multiprocessing queue's feeder thread
        # would wait for the GIL (up to the 5 ms switch interval) at each call while the
        # chain computes, and fall behind. Enlarged so that a slow moment of the outputs
        # does not stall the chain (a full pipe does: back pressure, nothing lost).
        reader, self._calls = context.Pipe(duplex=False)
        self._pickler = CallPickler()  # its dtype numbers are the new process's
        with contextlib.suppress(OSError):
            fcntl.fcntl(self._calls.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        replies: multiprocessing.Queue[str | OutputSummary | None] = context.Queue()
        self._replies = replies
        self._process = context.Process(
            target=_serve_outputs,
            args=(*self._args, self._warm_up, os.getpid(), reader, replies),
            name="tracker-outputs",
        )
        self._process.start()  # spawned: its arguments are pickled by now
        if self._warm_up is not None:
            self._warm_up.calls.clear()
            self._warm_up = None
        reader.close()  # the child's end: with it closed here, the child sees the core go
        self._next_check = 0.0
        # Started when its session and log are open: a bad endpoint fails here, as in
        # one process.
        while True:
            try:
                failure = replies.get(timeout=1.0)
                break
            except queue.Empty:
                if not self._process.is_alive():
                    failure = f"exited with code {self._process.exitcode}"
                    break
        if failure is not None:
            self._process.join()
            raise OutputStartFailed(f"the output process did not start: {failure}")

    def _restart(self) -> None:
        self._process.join(timeout=5.0)
        code = self._process.exitcode
        self._calls.close()
        if not self._supervised:
            self._failed = f"the output process exited with code {code}"
            raise OutputProcessFailed(self._failed)
        now = time.monotonic()
        self._deaths = [t for t in self._deaths if now - t <= RESTART_WINDOW_S] + [now]
        if len(self._deaths) > self._args[0].system.max_output_restarts:
            self._failed = (
                f"the output process died {len(self._deaths)} times within "
                f"{RESTART_WINDOW_S:g} s (last exit code {code}): giving up"
            )
            raise OutputProcessFailed(self._failed)
        log.error("the output process died (exit code %s): restarting it", code)
        self._start()
        self.restarts += 1
        self.last_restart = f"exit code {code}"
        # The new one starts at the data time the old one had reached.
        if self._data_time is not None:
            self._calls.send_bytes(pickle.dumps(("advance", (self._data_time,))))

    def _call(self, method: str, *args: object) -> None:
        if self._failed:
            raise OutputProcessFailed(self._failed)
        # Whether the process still runs costs a system call: asked once a second of
        # wall clock, not at each of the thousands of calls a second.
        now = time.monotonic()
        if now >= self._next_check:
            self._next_check = now + 1.0
            if not self._process.is_alive():
                self._restart()
        call = (method, args)
        try:
            self._calls.send_bytes(self._pickler.dumps(call))
        except OSError:  # BrokenPipeError: it died since the last check
            self._restart()
            self._calls.send_bytes(self._pickler.dumps(call))

    def advance(self, time: float) -> None:
        self._data_time = time
        self._call("advance", time)

    def set_input_counters(self, counters: dict[str, InputCounters]) -> None:
        self._call("set_input_counters", counters)

    def set_core_state(self, state: CoreState) -> None:
        # The restarts are this proxy's to know; the core tells the rest.
        self._call(
            "set_core_state",
            replace(state, restarts=self.restarts, last_restart=self.last_restart),
        )

    def received(self, name: str, datagram: Datagram, adsb: AdsbCount | None = None) -> None:
        self._data_time = datagram.time
        self._call("received", name, datagram, adsb)

    def error(self, name: str, kind: str, detail: str = "") -> None:
        self._call("error", name, kind, detail)

    def count(self, name: str, kind: str, n: int) -> None:
        self._call("count", name, kind, n)

    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None:
        # One call where an ``advance`` and a ``batch`` were two: a pipe write less.
        if received is not None:
            self._data_time = received
        self._call("batch", output, sources, received)

    def publish_cat062(self) -> None:
        self._call("publish_cat062")

    def publish_bias(
        self,
        estimates: dict[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
        observed_from: dict[str, ObservedFrom],
    ) -> None:
        self._call("publish_bias", estimates, observed_from)

    def publish_status(self) -> None:
        self._call("publish_status")

    def close(self) -> None:
        self._call("close")

    @property
    def pid(self) -> int | None:
        return self._process.pid

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._failed:
            return
        if self._process.is_alive():
            with contextlib.suppress(OSError):
                self._calls.send_bytes(b"")
        # Read before the join: the process ends once its queue is flushed to here.
        while self.summary is None and (self._process.is_alive() or not self._replies.empty()):
            with contextlib.suppress(queue.Empty):
                reply = self._replies.get(timeout=1.0)
                if isinstance(reply, OutputSummary):
                    self.summary = reply
        self._process.join()
        self._calls.close()


def _serve_outputs(
    config: ServiceConfig,
    mcap_dir: Path | None,
    zenoh: bool,
    health_file: Path | None,
    live: bool,
    warm_up: OutputCalls | None,
    parent: int,
    calls: Connection,
    replies: multiprocessing.Queue[str | OutputSummary | None],
) -> None:
    """The output process: ``Outputs`` making the calls that arrive, until told to stop
    (then its ``OutputSummary`` into ``replies``) or until its parent is gone; first the
    calls of ``warm_up`` on throwaway outputs."""
    configure()
    # A signal to the process group is the parent's to handle: this process ends the
    # tracks when the parent says so, after the calls queued before.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if warm_up is not None:
        warmed("outputs", lambda: warm_outputs(warm_up))
        warm_up.calls.clear()  # the process's own arguments hold it for its life
    failed = RateLimitedLog(log)
    try:
        with open_outputs(config, mcap_dir, zenoh=zenoh) as (publisher, mcap):
            outputs = Outputs(config, publisher, mcap)
            outputs.health_file = health_file
            freeze_start_up()
            freeze_survivors()
            sys.setswitchinterval(SWITCH_INTERVAL_S)  # a process of its own: for its life
            replies.put(None)
            try:
                told_to_stop = _make_calls(outputs, parent, calls, failed, live)
            finally:
                # The outputs' threads finish before the session and the log close.
                outputs.stop()
        if told_to_stop:
            files = [] if mcap is None else list(mcap.files)
            replies.put(OutputSummary(outputs.counts, files, time.process_time()))
    except ZenohConfigError as exc:
        # Said by the parent, in one line (the endpoint and the fix).
        replies.put(str(exc))
    except Exception as exc:
        replies.put(f"{type(exc).__name__}: {exc}")
        raise


def _make_calls(
    outputs: Outputs, parent: int, calls: Connection, failed: RateLimitedLog, live: bool
) -> bool:
    """The calls that arrive, until told to stop (True) or until the parent is gone;
    ``live``: the loop's waits counted for the status's ``busy["outputs"]``."""
    loop = outputs.loop = LoopLoad() if live else None
    while True:
        began = time.monotonic()
        arrived = calls.poll(1.0)
        if loop is not None:
            loop.waited(time.monotonic() - began)
        if not arrived:
            if os.getppid() != parent:
                log.error("the core's process is gone: stopping")
                return False
            continue
        try:
            item = calls.recv_bytes()
        except EOFError:
            log.error("the core's process is gone: stopping")
            return False
        if not item:
            return True
        method, args = pickle.loads(item)
        try:
            getattr(outputs, method)(*args)
        except Exception as exc:
            # As in one process: a failed output is logged, counted, and the others go on.
            outputs.sink_failed("outputs", f"{method}: {type(exc).__name__}: {exc}")
            failed.exception(method, "output %s failed", method)


def _watch_hint(config: ServiceConfig) -> str:
    z = config.zenoh
    endpoints = [e.replace("0.0.0.0", "127.0.0.1") for e in z.listen]
    connect = " ".join(f"--connect {e}" for e in endpoints[:1])
    # A subscriber of a TLS endpoint needs its own certificate (config/zenoh/).
    if any(endpoint_protocol(e) in TLS_PROTOCOLS for e in endpoints[:1]):
        connect = f"--zenoh-config SUBSCRIBER.json5 {connect}"
    prefix = "" if z.prefix == "tracker" else f" --prefix {z.prefix}"
    return f"tracker-service subscribe {connect}{prefix}".replace("  ", " ").strip()


def _live_tracks(service: TrackerService) -> int | None:
    """The live system tracks, when the outputs that know them run in this process."""
    return len(service.live_tracks) if isinstance(service.outputs, Outputs) else None


def _replay_datagrams(
    service: TrackerService, source: Replay, speed: float, stop: StopSignal
) -> None:
    progress = Progress(source.span)
    first: float | None = None
    wall0 = time.monotonic()
    datagrams = 0
    for name, datagram in source.datagrams:
        if stop.is_set():
            break
        assert datagram.time is not None
        if first is None:
            first = datagram.time
        if math.isfinite(speed):
            delay = wall0 + (datagram.time - first) / speed - time.monotonic()
            if delay > 0 and stop.wait(delay):
                break
        service.process(name, datagram)
        datagrams += 1
        if progress.enabled:
            progress.update(service.now, datagrams, _live_tracks(service))
    progress.update(service.now, datagrams, _live_tracks(service), True)
    progress.finish()


def replay(args: argparse.Namespace) -> int:
    if args.workers < 0:
        print(f"tracker-service replay: --workers {args.workers}: give 0 or more", file=sys.stderr)
        return 2
    try:
        config = None if args.config is None else load_service_config(args.config)
        source = open_replay(args.recording, config, args.date)
        config = _with_cli(source.config, args)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"tracker-service replay: {exc}", file=sys.stderr)
        return 2
    mcap_dir = None if args.mcap_dir is None else Path(args.mcap_dir)
    speed: float = args.speed
    output_process: bool = args.workers > 0 if args.output_process is None else args.output_process
    print(f"{args.recording}: {source.kind}; watch with: {_watch_hint(config)}", file=sys.stderr)
    if config.foxglove.listen is not None:
        print(f"foxglove: open ws://{config.foxglove.listen} in the Foxglove app", file=sys.stderr)
    try:
        with contextlib.ExitStack() as stack:
            stop = stack.enter_context(stop_on_signals())
            workers = None
            if args.workers > 0:
                workers = stack.enter_context(
                    RemoteRadarStages(
                        args.recording, config, args.date, args.workers, config.zenoh.prefix
                    )
                )
            service = stack.enter_context(
                open_service(
                    config,
                    mcap_dir,
                    output_process=output_process,
                    supervised=False,
                    radar_stage=workers,
                )
            )
            service.set_input_counters(source.counters)
            _replay_datagrams(service, source, speed, stop)
    except (RadarStageFailed, OutputProcessFailed) as exc:
        print(f"tracker-service replay: {exc}", file=sys.stderr)
        return 1
    except (ZenohConfigError, OutputStartFailed, OSError) as exc:
        print(f"tracker-service replay: {exc}", file=sys.stderr)
        return 2
    if isinstance(service.outputs, OutputProcess):
        if service.outputs.summary is None:
            print(
                "tracker-service replay: the output process ended without its totals",
                file=sys.stderr,
            )
            return 1
        summary = service.outputs.summary
        cpu = [f"outputs {summary.cpu_s:.1f}"]
    else:
        files = [] if service.log is None else list(service.log.files)
        summary = OutputSummary(service.counts, files, 0.0)
        cpu = []
    if workers is not None:
        cpu.append("radar workers " + " + ".join(f"{s:.1f}" for s in workers.cpu_s))
    counts = summary.counts
    duplicates = sum(c.duplicates for c in source.counters.values())
    print(
        f"replayed {counts.datagrams} datagrams ({duplicates} duplicates dropped): "
        f"{counts.plots} plots, {len(counts.system_tracks)} system tracks "
        f"({counts.system_updates} updates), {counts.errors} errors",
        file=sys.stderr,
    )
    for path in summary.log_files:
        print(f"log: {path}", file=sys.stderr)
    if cpu:
        # Where the CPU went: the balance of the processes (docs/deployment.md).
        cpu.insert(0, f"this process {time.process_time():.1f}")
        print(f"cpu seconds: {', '.join(cpu)}", file=sys.stderr)
    return 0


HEALTH_STALE = 1
"""``health`` exit status: no fresh status (the daemon is not running, or stuck)."""
HEALTH_DEGRADED = 2
"""``health`` exit status: the daemon runs, but a radar, an output or the chain is not ok
(each reason printed on a line of its own)."""


def health(args: argparse.Namespace) -> int:
    """0 when the daemon wrote a status within ``--max-age`` seconds and its health is
    "ok"; ``HEALTH_STALE`` or ``HEALTH_DEGRADED`` otherwise, saying why."""
    path = Path(args.file)
    try:
        age = time.time() - path.stat().st_mtime
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        print(f"unhealthy: {exc}", file=sys.stderr)
        return HEALTH_STALE
    if age > args.max_age:
        print(f"unhealthy: last status {age:.0f} s ago (is the daemon running?)", file=sys.stderr)
        return HEALTH_STALE
    try:
        status = StatusMessage.model_validate_json(text)
    except ValueError as exc:
        print(f"unhealthy: {path} holds no status ({exc.__class__.__name__})", file=sys.stderr)
        return HEALTH_STALE
    if getattr(args, "container", False):
        return _container_health(status, age, args.silent_for, args.behind)
    if status.health != "ok" and not args.live:
        print(f"degraded: status of {age:.1f} s ago says:", file=sys.stderr)
        for reason in status.reasons:
            print(f"  {reason}", file=sys.stderr)
        return HEALTH_DEGRADED
    print(f"{'running' if args.live else 'healthy'}: last status {age:.1f} s ago")
    return 0


def _container_health(status: StatusMessage, age: float, silent_for: float, behind: float) -> int:
    """0 or 1, as a container engine reads a health check (2 is reserved there)."""
    reasons = unhealthy_reasons(status, silent_for, behind)
    for reason in reasons:
        print(f"unhealthy: {reason}", file=sys.stderr)
    if reasons:
        return HEALTH_STALE
    state = "healthy" if status.health == "ok" else "healthy but degraded"
    print(f"{state}: last status {age:.1f} s ago")
    for reason in status.reasons:
        print(f"  {reason}")
    return 0


def _check_log_directory(directory: Path | None) -> None:
    """Whether the log can be written in ``directory`` (made if missing), said at
    start-up rather than by the output process after the warm-up."""
    if directory is None:
        return
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise ConfigError(
            f"[mcap] directory {directory}: {exc.strerror or exc}: give a directory the "
            "service's user can write, or none for no log"
        ) from None


def run(args: argparse.Namespace) -> int:
    from tracker_service.service.daemon import Daemon, InputError
    from tracker_service.service.roles import (
        STAGE_LISTEN_FIX,
        FusionRole,
        RadarRole,
        stage_session_config,
    )

    try:
        config = _with_cli(load_service_config(args.config), args)
        if args.role is not None:
            stage = stage_session_config(config, args.stage_listen, args.stage_connect)
            check_listen_endpoints(stage, STAGE_LISTEN_FIX)
        if args.role != "radar":
            _check_log_directory(config.mcap.directory)
    except (ConfigError, ZenohConfigError) as exc:
        print(f"tracker-service run: {exc}", file=sys.stderr)
        return 2
    if args.radars and args.role != "radar":
        print("tracker-service run: --radars goes with --role radar", file=sys.stderr)
        return 2
    configure()
    health_file = None if args.health_file is None else Path(args.health_file)
    with stop_on_signals() as stop:
        try:
            if args.role == "radar":
                radar_role = RadarRole(config, args.radars, args.stage_listen, args.stage_connect)
                return radar_role.run(stop)
            if args.role == "fusion":
                fusion_role = FusionRole(config, args.stage_listen, args.stage_connect, health_file)
                return fusion_role.run(stop)
            return Daemon(config, health_file).run(stop)
        except InputError as exc:
            print(f"tracker-service run: {args.config}: {exc}", file=sys.stderr)
            return 2
        except OutputProcessFailed as exc:
            print(f"tracker-service run: {exc}", file=sys.stderr)
            return 1
        except (OutputStartFailed, ZenohEndpointError) as exc:
            # ZenohEndpointError: a stage endpoint taken since the check at start-up.
            print(f"tracker-service run: {exc}", file=sys.stderr)
            return 2
