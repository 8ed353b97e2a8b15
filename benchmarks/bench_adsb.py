"""CPU time of the ADS-B ingest alone: every datagram of a recording's first seconds that
holds CAT021 blocks, through ``TrackerService.process`` as the replay runs it (the
decoding, the status's count of the feed, the central stage's ADS-B reference or fusion),
without the radars' datagrams and without an output sink. Prints CPU microseconds per
datagram and per report, the median of ``--repeats`` passes (the first pass untimed),
and the ADS-B feeds' status counts, which two versions must agree on.

    tracker-service simulate config/scenarios/artas.toml -o artas30.mcap --duration 30
    python benchmarks/bench_adsb.py artas30.mcap [--seconds 30] [--repeats 5]
        [--profile FILE]

Run it on two trees (a ``git archive`` copy on ``PYTHONPATH`` for the base) alternately
for a side-by-side ratio.
"""

from __future__ import annotations

import argparse
import cProfile
import statistics
import time

import tracker_service
from asterix.codec import Block, decode_blocks
from tracker_service.outputs.messages import RadarStatus
from tracker_service.radar_stage import CAT021, blocks_of
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="a recording with ADS-B stations (e.g. of artas)")
    parser.add_argument("--seconds", type=float, default=30.0, help="slice of the recording")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--profile", help="a cProfile of one more pass into this file")
    args = parser.parse_args()
    replay = open_replay(args.recording)
    datagrams = []
    first = None
    for name, datagram in replay.datagrams:
        assert datagram.time is not None
        first = datagram.time if first is None else first
        if datagram.time - first > args.seconds:
            break
        if any(True for _ in blocks_of(datagram.payload, CAT021)):
            datagrams.append((name, datagram))
    reports = sum(
        len(event.records)
        for _, datagram in datagrams
        for block in blocks_of(datagram.payload, CAT021)
        for event in decode_blocks(block)
        if isinstance(event, Block)
    )

    adsb = {a.key for a in replay.config.adsb}

    def one_pass() -> tuple[float, list[RadarStatus]]:
        service = TrackerService(replay.config)
        started = time.process_time()
        for name, datagram in datagrams:
            service.process(name, datagram)
        seconds = time.process_time() - started
        status = [r for r in service.status().radars if r.radar in adsb]
        service.close()
        return seconds, status

    _, status = one_pass()
    seconds = statistics.median(one_pass()[0] for _ in range(args.repeats))
    if args.profile:
        profile = cProfile.Profile()
        profile.runcall(one_pass)
        profile.dump_stats(args.profile)
    print(f"code: {tracker_service.__file__}")
    print(f"{len(datagrams)} CAT021 datagrams, {reports} reports, {args.seconds:.0f} s")
    print(
        f"ADS-B ingest: {seconds:.3f} CPU s (median of {args.repeats}), "
        f"{seconds / len(datagrams) * 1e6:.0f} us/datagram, {seconds / reports * 1e6:.1f} us/report"
    )
    for r in status:
        print(f"  {r.radar}: {r.plots_per_second:.3f}/s, last {r.last_plot_time!r}")


if __name__ == "__main__":
    main()
