"""The ``tracker-service`` command: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import datetime
import faulthandler
import importlib.metadata
import signal
import sys
from collections.abc import Sequence

from tracker_service.log_level import LOG_LEVELS, configure


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tracker-service",
        description="ASTERIX-fed multiradar tracker service.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument(
        "--log-level",
        type=str.upper,
        choices=LOG_LEVELS,
        default=None,
        help="what the log shows: debug, info (the daemon's default), warning, error",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    decode = commands.add_parser(
        "decode",
        help="decode a capture (pcap, pcapng, GPS, final format, raw, hex) to JSON lines",
        description="Print one JSON object per ASTERIX record, in file order; decode errors "
        "go to stderr as JSON lines. The container format is detected from the content.",
    )
    decode.add_argument("path", help="the capture file")
    decode.add_argument(
        "--summary",
        action="store_true",
        help="decode everything but print only counts, duplicates, time span and errors",
    )
    decode.add_argument(
        "--bds",
        action="store_true",
        help='add the named fields of Mode S BDS 4,0/5,0/6,0 registers to I048/250 ("BDS")',
    )
    simulate = commands.add_parser(
        "simulate",
        help="simulate radars and aircraft from a scenario: ASTERIX datagrams and the truth",
        description="Run a scenario (TOML) and write what its radars send, and the truth. "
        "The output format follows OUT's suffix: .mcap (datagrams, truth, metadata), "
        ".pcap (UDP to each radar's multicast group), .raw/.ast (data blocks), .hex.",
    )
    simulate.add_argument(
        "scenario", help="the scenario file, e.g. config/scenarios/three_sites.toml"
    )
    simulate.add_argument("-o", "--output", help="output file (default: <scenario name>.mcap)")
    simulate.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    simulate.add_argument(
        "--duration", type=float, help="seconds to simulate (default: the scenario's)"
    )
    simulate.add_argument(
        "--no-bias", action="store_true", help="zero every systematic error of every radar"
    )
    simulate.add_argument(
        "--start",
        type=_start_time,
        help="when the scenario starts: 'now' (so that its pcap can feed `run` live) or an "
        "ISO 8601 UTC time, e.g. 2026-06-01T23:59:30Z (default: the scenario's)",
    )
    evaluate = commands.add_parser(
        "evaluate",
        help="run the local trackers on a recording with truth and measure them against it",
        description="Track every radar of a simulated MCAP recording and measure plots and "
        "local tracks against the truth: position, along/across-track and velocity RMS, "
        "probability of update, tracks per aircraft, identity changes, false tracks, NEES.",
    )
    from tracker_service.evaluation.command import add_arguments

    add_arguments(evaluate)
    assess = commands.add_parser(
        "assess",
        help="judge the tracker on a recording without truth (opportunity traffic)",
        description="Run a recording through the chain and measure what needs no truth: "
        "tracks per Mode S address and Mode 3/A code, breaks while plots continue, speeds, "
        "accelerations, position jumps, NIS, test and fixed targets, time faults, ADS-B as "
        "reference; then the pass/fail checks of real-data tracking. Exit 1 when one fails.",
    )
    from tracker_service.evaluation.assess import add_arguments as add_assess_arguments

    add_assess_arguments(assess)
    subscribe = commands.add_parser(
        "subscribe",
        help="print the system tracks a running service publishes over Zenoh",
        description="Ask the service for the current air picture, then follow its updates: "
        "a live table, or JSON lines (--json). Ends on Ctrl-C or SIGTERM.",
    )
    from tracker_service.subscribe import add_arguments as add_subscribe_arguments

    add_subscribe_arguments(subscribe)
    from tracker_service.service.command import (
        add_health_arguments,
        add_replay_arguments,
        add_run_arguments,
    )

    replay = commands.add_parser(
        "replay",
        help="replay a recording or capture through the whole service (Zenoh, MCAP log)",
        description="Feed a recording (simulator MCAP, the service's own MCAP log, or a "
        "pcap/pcapng/GPS/final/raw/hex capture) through the service, paced by its reception "
        "times, publishing over Zenoh as the daemon does.",
    )
    add_replay_arguments(replay)
    run = commands.add_parser(
        "run",
        help="run the service on the live UDP feeds of a configuration",
        description="The daemon: every configured radar's UDP input (and its second LAN), "
        "tracks published over Zenoh and logged to MCAP. Ends cleanly on SIGTERM or Ctrl-C.",
    )
    add_run_arguments(run)
    play = commands.add_parser(
        "play",
        help="send a capture's datagrams to the configured radar inputs, as the radars do",
        description="Send each datagram of a capture (any format replay reads) to the UDP "
        "input (multicast or unicast, every LAN) of the feed its I010 names, paced by its "
        "reception times; --now re-bases the times, inside the datagrams too, on the present.",
    )
    from tracker_service.play import add_arguments as add_play_arguments

    add_play_arguments(play)
    init = commands.add_parser(
        "init",
        help="write the example configuration, the scenarios and the Zenoh examples into DIR",
        description="Copy the example configuration (as tracker.toml), the simulator's "
        "scenarios and the Zenoh TLS examples into DIR, to start from.",
    )
    from tracker_service.init import add_arguments as add_init_arguments

    add_init_arguments(init)
    health = commands.add_parser(
        "health",
        help="exit 0 when a running daemon is healthy (for container health checks)",
        description="Checks the daemon's --health-file: healthy when it was touched "
        "within --max-age seconds.",
    )
    add_health_arguments(health)
    warm_up = commands.add_parser(
        "warm-up",
        help="compile the service's kernels into numba's cache (after an install, in an "
        "image build)",
        description="Take generated traffic through every stage of the service, so that "
        "numba's cache holds their compiled kernels and the first start of the service is "
        "not a two-minute compilation. Run it as the user the service runs as.",
    )
    from tracker_service.service.warm_up import add_arguments as add_warm_up_arguments

    add_warm_up_arguments(warm_up)
    export = commands.add_parser(
        "export",
        help="write the tracks of a service log as GeoJSON, KML, CSV or Parquet",
        description="One feature, placemark or set of rows per track (time, position, level, "
        "speed, identity); CSV and Parquet columns as the traffic library reads them.",
    )
    from tracker_service.export import add_arguments as add_export_arguments

    add_export_arguments(export)
    return parser


def _version() -> str:
    try:
        return importlib.metadata.version("tracker-service")
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def _start_time(text: str) -> datetime.datetime:
    """``--start``: 'now' or an ISO 8601 time (UTC unless it names its zone)."""
    if text == "now":
        return datetime.datetime.now(datetime.UTC)
    try:
        when = datetime.datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither 'now' nor an ISO 8601 time such as 2026-06-01T10:00:00Z"
        ) from None
    return (
        when.replace(tzinfo=datetime.UTC) if when.tzinfo is None else when.astimezone(datetime.UTC)
    )


def _simulate(args: argparse.Namespace) -> int:
    from tracker_service.simulator.run import simulate
    from tracker_service.simulator.scenario import ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"tracker-service simulate: {exc}", file=sys.stderr)
        return 2
    if args.duration is not None and args.duration <= 0:
        print("tracker-service simulate: --duration must be positive", file=sys.stderr)
        return 2
    if args.start is not None:
        scenario = scenario.model_copy(update={"start": args.start})
    output = args.output or f"{scenario.name}.mcap"
    try:
        summary = simulate(scenario, output, args.seed, args.duration, args.no_bias)
    except ValueError as exc:
        print(f"tracker-service simulate: {exc}", file=sys.stderr)
        return 2
    plots = ", ".join(f"{key}: {count}" for key, count in summary.plots.items())
    print(
        f"{output}: {summary.aircraft} aircraft, {summary.datagrams} datagrams, "
        f"reports per source {{{plots}}}, {summary.seconds:.1f} s",
        file=sys.stderr,
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    # `kill -USR1 PID` prints every thread's stack on stderr (file descriptor 2, whatever
    # sys.stderr is): what a stuck process is doing, without stopping it.
    faulthandler.register(signal.SIGUSR1, file=2, all_threads=True)
    args = build_parser().parse_args(argv)
    if args.log_level is not None:
        configure(args.log_level)
    if args.command == "decode":
        from tracker_service.decode import main as decode_main

        try:
            return decode_main(args.path, args.summary, args.bds)
        except BrokenPipeError:
            # `decode ... | head` closes the pipe early; that is not an error.
            sys.stderr.close()
            return 0
    if args.command == "simulate":
        return _simulate(args)
    if args.command == "evaluate":
        from tracker_service.evaluation.command import run

        return run(args)
    if args.command == "assess":
        from tracker_service.evaluation.assess import run as assess_run

        return assess_run(args)
    if args.command == "subscribe":
        from tracker_service.subscribe import run as subscribe_run

        return subscribe_run(args)
    if args.command == "init":
        from tracker_service.init import run as init_run

        return init_run(args)
    if args.command == "play":
        from tracker_service.play import run as play_run

        return play_run(args)
    if args.command == "export":
        from tracker_service.export import run as export_run

        return export_run(args)
    if args.command == "warm-up":
        from tracker_service.service.warm_up import run as warm_up_run

        return warm_up_run(args)
    if args.command in ("replay", "run", "health"):
        from tracker_service.service import command

        handler = {"replay": command.replay, "run": command.run, "health": command.health}
        return handler[args.command](args)
    return 2


if __name__ == "__main__":
    sys.exit(main())
