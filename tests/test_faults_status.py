"""Issue 11 findings 2 and 3: no datagram stops the status, and unknown sources cannot grow
memory or the status without bound.

Real datagrams through the service core (the path the daemon and the replay share), a
real capture replayed by ``tracker-service replay``, its MCAP log read back."""

from __future__ import annotations

import resource
from pathlib import Path

import numpy as np

from asterix.codec import encode_block
from asterix.containers import Datagram, write_pcap
from tests.fault_tools import EXAMPLE, NO_I010, hostile_datagrams, plot_block, plot_record
from tests.test_service_replay import endpoint, logged
from tracker_service.cli import main
from tracker_service.outputs.messages import StatusMessage
from tracker_service.service.config import load_service_config
from tracker_service.service.core import ServiceTimings, TrackerService, build_radar_stage

T0 = 1780300800.0  # 2026-06-01T08:00:00Z
SRC, DST = ("10.0.0.1", 40000), ("127.0.0.1", 8600)


def datagram(payload: bytes, number: int, time: float) -> Datagram:
    return Datagram(payload, number, time, SRC, DST)


def service() -> TrackerService:
    return TrackerService(load_service_config(EXAMPLE), timings=ServiceTimings(status_s=1.0))


def radar(status: StatusMessage, key: str) -> dict[str, int]:
    return next(r.errors for r in status.radars if r.radar == key)


def test_radar_batches_alone_move_the_outputs_data_time() -> None:
    """The fusion role's input is radar batches, not datagrams: its outputs' data time (the
    status's time, a radar's plot delay, the periodic CAT062/CAT065) must follow them. It
    stood at the start (or at -inf) while batches kept coming: a status that called every
    radar's clock ahead, and a CAT065 whose time was not a number."""
    core = service()
    stage = build_radar_stage(load_service_config(EXAMPLE))
    for k in range(4):
        t = T0 + 2.0 * k
        for batch in stage.feed(plot_block(25, 12, t % 86400), t, k):
            core.process_batch(batch)
        status = core.outputs.status()
        assert status.time == t
        assert not [r for r in status.reasons if "25/12" in r], status.reasons
    assert core.periodic_failures == 0


def test_a_record_without_i010_is_counted_and_status_goes_on() -> None:
    core = service()
    core.process("25_12", datagram(plot_block(25, 12, T0 % 86400), 0, T0))
    core.process("25_12", datagram(NO_I010, 1, T0 + 0.5))
    for k in range(2, 8):
        core.process("25_12", datagram(plot_block(25, 12, (T0 + k) % 86400), k, T0 + k))
        status = core.status()  # validated: raised for the radar "-1/-1" before
        StatusMessage.model_validate_json(status.model_dump_json())
    assert core.periodic_failures == 0
    assert radar(status, "25/12") == {"no_source": 1}
    assert {r.radar for r in status.radars} == {"25/11", "25/12", "25/13", "25/50"}
    assert core.counts.plots == 7


def test_random_datagrams_never_stop_the_status() -> None:
    core = service()
    rng = np.random.default_rng(5)
    hostile = hostile_datagrams(rng, T0 % 86400)
    kinds = set()
    for k in range(70):
        kind, payload = next(hostile)
        kinds.add(kind)
        core.process("25_13", datagram(payload, k, T0 + 0.2 * k))
        StatusMessage.model_validate_json(core.status().model_dump_json())
    assert core.periodic_failures == 0
    assert {"random", "random_cat048", "no_i010"} <= kinds
    errors = radar(core.status(), "25/13")
    assert errors["not_asterix"] >= 10  # the malformed and most random ones
    assert errors["no_source"] >= 10  # every record without I010, random ones too
    assert errors["unknown_category"] == 10
    assert errors["decode_error"] >= 10  # the truncated records, at least


def test_a_replay_with_hostile_datagrams_runs_to_its_end(tmp_path: Path) -> None:
    """``_periodic`` was outside the error handling: the first status after the record
    without I010 ended the replay with a traceback."""
    rng = np.random.default_rng(9)
    hostile = hostile_datagrams(rng, T0 % 86400)
    datagrams = []
    for k in range(60):
        t = T0 + 0.5 * k
        datagrams.append((t, SRC, DST, plot_block(25, 11, t % 86400, 30.0 + k / 10)))
        datagrams.append((t + 0.01, SRC, DST, next(hostile)[1]))
    capture = tmp_path / "hostile.pcap"
    write_pcap(capture, datagrams)
    out = tmp_path / "log"
    args = ["replay", str(capture), "--config", str(EXAMPLE), "--speed", "max"]
    code = main([*args, "--mcap-dir", str(out), "--zenoh-listen", endpoint()])
    assert code == 0
    statuses = [m.data for m in logged(out) if m.topic == "/status"]
    # A status every 5 s of the 30 s, the first at the start, the last at the end.
    assert len(statuses) >= 6
    assert statuses[-1]["time"] >= T0 + 29.0


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def test_unknown_sources_are_bounded() -> None:
    """65,536 distinct SAC/SICs (a datagram of 256 plots per SAC): a tracker and a
    status line for the first ``max_unknown_sources`` only; the plots of the others
    dropped and counted."""
    core = service()
    limit = core.config.system.max_unknown_sources
    radars = {"25/11", "25/12", "25/13"}  # 25/50 is an ADS-B feed: unknown as a radar
    before = rss_mb()
    for sac in range(256):
        t = T0 + sac
        records = [plot_record(sac, sic, t % 86400) for sic in range(256)]
        core.process("25_12", datagram(encode_block(48, records), sac, t))
    status = core.status()
    text = status.model_dump_json()
    unknown = 65536 - len(radars)
    assert len(core.chain.radars) == len(radars) + limit
    assert len(status.radars) == len({*radars, "25/50", *core.chain.admission.unknown})
    assert len(text) < 20_000, len(text)
    assert status.unattributed["unknown_sources_dropped"] == unknown - limit
    errors = radar(status, "25/12")
    assert errors["unknown_source"] == unknown - limit
    # The peak of this process (the test runner too): a tracker per source was ~15 kB.
    assert rss_mb() - before < 100.0


def test_system_track_numbers_running_short_degrade_the_status_for_a_minute() -> None:
    """The fuser's count of foundings that found no number past its reuse delay
    (``tests/test_fusion_numbers.py`` makes them happen) reaches the status as a reason
    line while it is recent, wherever the outputs run (it travels in ``CoreState``)."""
    core = service()
    assert not core.core_state().reasons  # before any data: both times -inf
    core.process("25_12", datagram(plot_block(25, 12, T0 % 86400), 0, T0))
    fuser = core.chain.fuser
    assert fuser is not None
    assert not [r for r in core.status().reasons if r.startswith("fusion:")]
    fuser.stats.numbers_reused_early = 3
    fuser.stats.last_number_shortage = T0 + 1.0
    for k, t in enumerate((T0 + 2.0, T0 + 60.0, T0 + 62.0), start=1):
        core.process("25_12", datagram(plot_block(25, 12, t % 86400), k, t))
        shown = [r for r in core.status().reasons if r.startswith("fusion:")]
        if t - (T0 + 1.0) <= 60.0:
            assert len(shown) == 1 and "ran short: 3 track(s)" in shown[0], shown
            assert core.status().health == "degraded"
        else:
            assert not shown
