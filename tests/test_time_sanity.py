"""Clock faults of real feeds (issue 10 findings 1-2, issue 11 finding 1), reproduced on a
short three_sites recording that crosses midnight: one corrupt I140 at the start and in
the middle of a stream, times of day above 86,400 s after the wrap, one datagram two
hours ahead, a radar restarting 60 s fast or an hour slow, a whole capture replayed live.
Each run goes through the whole service core (``TrackerService``) and is compared with
the clean run of the same recording."""

from __future__ import annotations

import dataclasses
import datetime
import re
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from asterix.codec import Block, decode_blocks, encode_block
from asterix.containers import Datagram, read_file
from asterix.plots import extract_plots
from tests.conftest import shared_file
from tests.test_service_replay import endpoint, logged
from tests.test_service_replay import simulate as simulate_recording
from tests.test_service_run import DaemonProcess, Feeds
from tracker_service.chain import BatchOutput, PlotUse
from tracker_service.cli import main
from tracker_service.evaluation.real_data import NOMINAL_SITE_068, track_capture
from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.ingest import DAY_S, TimeSource
from tracker_service.outputs.messages import StatusMessage
from tracker_service.service.config import (
    ConfigError,
    ServiceConfig,
    load_service_config,
    parse_service_config,
)
from tracker_service.service.core import Outputs, TrackerService
from tracker_service.service.replay import open_replay
from tracker_service.time_sanity import TimeSanity, TimeSanityConfig
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig
from tracker_service.tracking.clock import DataClock

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "config" / "scenarios" / "three_sites.toml"
START = "2026-06-01T23:59:58Z"
MIDNIGHT = datetime.datetime(2026, 6, 2, tzinfo=datetime.UTC).timestamp()
DURATION_S = 60.0
RADAR = "25_13"  # Koris-hegy, 5 s antenna
KEY = "25/13"

Fault = Callable[[str, Datagram], list[Datagram]]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("time") / "midnight.mcap"
    args = ["simulate", str(SCENARIO), "-o", str(out), "--duration", str(DURATION_S)]
    assert main([*args, "--start", START]) == 0
    return out


class Recorded(Outputs):
    """The outputs, keeping every batch's plots and local-track updates."""

    def __init__(self, config: ServiceConfig) -> None:
        super().__init__(config)
        self.local: list[tuple[str, Any]] = []
        self.plots: list[tuple[str, Any]] = []

    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None:
        super().batch(output, sources, received)
        self.local += [(output.source, u) for u in output.local]
        self.plots += [(output.source, p) for p in output.plots]


@dataclass
class Run:
    service: TrackerService
    local: list[tuple[str, Any]]  # (radar, local-track update row)
    plots: list[tuple[str, Any]]  # (radar, plot row)
    statuses: list[StatusMessage]
    fused: set[str]
    """The radars feeding the system tracks live at the end."""

    @property
    def system_numbers(self) -> int:
        return len(self.service.counts.system_tracks)

    def local_of(self, radar: str, after: float = -np.inf) -> list[Any]:
        return [u for r, u in self.local if r == radar and u["time"] > after]

    def confirmed_tracks(self, radar: str) -> int:
        return len({int(u["track_number"]) for u in self.local_of(radar) if u["status"] == 1})

    def deleted(self, radar: str, start: float, end: float) -> int:
        return sum(1 for u in self.local_of(radar) if u["status"] == 3 and start < u["time"] < end)


def run(
    recording: Path,
    fault: Fault | None = None,
    config_update: Callable[[dict[str, Any]], None] | None = None,
) -> Run:
    """The recording through the service core, each datagram through ``fault`` first."""
    source = open_replay(recording)
    config = source.config
    if config_update is not None:
        doc = config.model_dump(mode="json", exclude_none=True)
        config_update(doc)
        config = parse_service_config(doc)
    outputs = Recorded(config)
    service = TrackerService(config, outputs=outputs)
    statuses = []
    for name, datagram in source.datagrams:
        for faulted in fault(name, datagram) if fault is not None else [datagram]:
            service.process(name, faulted)
        statuses.append(service.status())
    fused = {s.radar for track in service.picture().values() for s in track.sources}
    service.close()
    return Run(service, outputs.local, outputs.plots, statuses, fused)


def _time(datagram: Datagram) -> float:
    assert datagram.time is not None
    return datagram.time


def retimed(
    payload: bytes, change: Callable[[int, float], float], items: Sequence[str] = ("140", "030")
) -> bytes:
    """The datagram with each record's time of day (CAT048 I140, CAT034 I030, of those in
    ``items``) changed by ``change(index of the record in its category, time of day)``;
    everything else re-encoded as it was."""
    blocks = []
    index: Counter[int] = Counter()
    for event in decode_blocks(payload):
        assert isinstance(event, Block)
        records = []
        for record in event.records:
            item = {48: "140", 34: "030"}.get(event.cat)
            if item is not None and item in items and item in record:
                record = {**record, item: change(index[event.cat], float(record[item]))}
                index[event.cat] += 1
            records.append(record)
        blocks.append(encode_block(event.cat, records))
    return b"".join(blocks)


def has_plots(name: str, datagram: Datagram) -> bool:
    """A datagram of RADAR with Mode S plots (and others beside them)."""
    plots = extract_plots(datagram.payload).plots
    return name == RADAR and len(plots) >= 2 and bool(np.any(plots["address"] >= 0))


@pytest.fixture(scope="module")
def clean(recording: Path) -> Run:
    return run(recording)


def test_the_clean_run_is_sane(clean: Run) -> None:
    final = clean.statuses[-1]
    assert final.health == "ok" and final.reasons == []
    assert not any(s.reasons for s in clean.statuses)
    offsets = [r.time_offset_s for r in final.radars if r.radar != "25/50"]
    assert all(o is not None and -2.0 < o < 0.0 for o in offsets)
    # The simulator's SSR reflections are stamped with their aircraft's time at a
    # mirrored azimuth: a handful fail the azimuth check, nothing else.
    rejected = Counter(p["use"] for _, p in clean.plots)
    assert rejected[PlotUse.TIME_IMPLAUSIBLE] <= 0.002 * len(clean.plots)


def corrupt_once(where: Callable[[float], bool], tod: float = 19711.0) -> Fault:
    """One plot of one datagram of RADAR (the first where ``where(reception)``) gets ``tod``."""
    done = False

    def fault(name: str, datagram: Datagram) -> list[Datagram]:
        nonlocal done
        if done or not has_plots(name, datagram) or not where(_time(datagram)):
            return [datagram]
        done = True
        # A Mode S aircraft's plot: not the field monitor's, not clutter by the radar.
        plots = extract_plots(datagram.payload).plots
        first = int(np.flatnonzero((plots["address"] >= 0) & (plots["rab"] != 1))[0])
        payload = retimed(datagram.payload, lambda i, t: tod if i == first else t, ("140",))
        return [dataclasses.replace(datagram, payload=payload)]

    return fault


def test_one_corrupt_i140_among_the_first_plots_at_midnight(recording: Path, clean: Run) -> None:
    faulty = run(recording, corrupt_once(lambda t: t > MIDNIGHT))
    # Today's main started no track at all from the radar's other plots.
    assert faulty.confirmed_tracks(KEY) >= clean.confirmed_tracks(KEY) - 1
    assert faulty.system_numbers <= clean.system_numbers + 1
    rejected = [p for r, p in faulty.plots if r == KEY and p["use"] == PlotUse.TIME_IMPLAUSIBLE]
    assert any(abs(p["time"] - MIDNIGHT - 19711.0) < 1.0 for p in rejected)
    assert faulty.statuses[-1].radars[2].rejected.get("time_implausible", 0) >= 1


def test_one_corrupt_i140_in_the_middle_of_a_stream(recording: Path, clean: Run) -> None:
    middle = MIDNIGHT + 40.0
    faulty = run(recording, corrupt_once(lambda t: t > middle))
    # Today's main deleted nearly every track of the radar at once and dropped its later
    # plots as late.
    assert (
        faulty.deleted(KEY, middle, middle + 30.0) <= clean.deleted(KEY, middle, middle + 30.0) + 1
    )
    tracker = faulty.service.chain.radars[KEY].tracker
    assert tracker.stats.late_plots_dropped <= (
        clean.service.chain.radars[KEY].tracker.stats.late_plots_dropped + 2
    )
    later = [u for u in faulty.local_of(KEY, middle) if u["plot_id"] >= 0]
    assert len(later) >= 0.95 * len([u for u in clean.local_of(KEY, middle) if u["plot_id"] >= 0])
    assert faulty.system_numbers <= clean.system_numbers + 1


def test_times_of_day_above_86400_after_the_wrap_in_a_capture_replayed_hours_later(
    recording: Path, clean: Run
) -> None:
    """The capture sent live 13 hours later, ten of its plots still stamped above
    86,400 s after the CAT034 wrapped: both kinds of time of day stay on the radar's
    timeline (a day on from the capture's: the day nearest the reception), tracked."""
    shift = 13 * 3600.0
    unwrapped = 0

    def fault(name: str, datagram: Datagram) -> list[Datagram]:
        nonlocal unwrapped
        payload = datagram.payload
        if has_plots(name, datagram) and unwrapped < 10 and _time(datagram) > MIDNIGHT + 5:

            def keep_unwrapped(i: int, tod: float) -> float:
                nonlocal unwrapped
                if i == 0 and tod < 100.0:
                    unwrapped += 1
                    return tod + DAY_S
                return tod

            payload = retimed(payload, keep_unwrapped, ("140",))
        return [dataclasses.replace(datagram, payload=payload, time=_time(datagram) + shift)]

    faulty = run(recording, fault)
    assert unwrapped == 10
    after = MIDNIGHT + 15.0 + DAY_S  # the radar's time lands a day on: nearest its offset
    tracked = [u for u in faulty.local_of(KEY, after) if u["plot_id"] >= 0]
    expected = [u for u in clean.local_of(KEY, MIDNIGHT + 15.0) if u["plot_id"] >= 0]
    assert len(tracked) >= 0.95 * len(expected)
    times = np.array([p["time"] for r, p in faulty.plots if r == KEY])
    assert np.all(np.diff(times) > -10.0), "the radar's time jumped back at the wrap"
    final = faulty.statuses[-1]
    assert any("25/13" in line and "ahead of its reception" in line for line in final.reasons)


def test_one_datagram_two_hours_ahead_ends_nothing(recording: Path, clean: Run) -> None:
    """One extra datagram of a known radar with I140 two hours ahead: today's main ended
    every system track after each update (1,394 numbers for 45 aircraft)."""
    inserted = False

    def fault(name: str, datagram: Datagram) -> list[Datagram]:
        nonlocal inserted
        if inserted or not has_plots(name, datagram) or _time(datagram) < MIDNIGHT + 30:
            return [datagram]
        inserted = True
        future = retimed(datagram.payload, lambda _i, t: (t + 7200.0) % DAY_S)
        return [datagram, dataclasses.replace(datagram, payload=future)]

    faulty = run(recording, fault)
    assert inserted
    assert faulty.system_numbers <= clean.system_numbers + 1
    ended = [u for u in faulty.local if u[1]["status"] == 3]
    assert len(ended) <= len([u for u in clean.local if u[1]["status"] == 3]) + 2


def test_the_fuser_and_the_local_tracker_survive_an_update_two_hours_ahead(
    recording: Path, clean: Run
) -> None:
    """Straight to the stages, past time sanity: a batch two hours ahead moves neither
    clock, ends no track and blocks no later data."""
    chain = TrackerService(open_replay(recording).config).chain
    fuser = chain.fuser
    assert fuser is not None
    injected = False
    for _name, datagram in open_replay(recording).datagrams:
        outputs = chain.feed(datagram.payload, _time(datagram))
        if injected or _time(datagram) < MIDNIGHT + 40 or not outputs:
            continue
        output = outputs[0]
        tracked = output.plots[output.plots["use"] == PlotUse.TRACKED]
        if not len(output.local) or not len(tracked):
            continue
        injected = True
        tracker = chain.radars[output.source].tracker
        now, live_local = tracker.clock.now, len(tracker.tracks)
        plots = np.zeros(len(tracked), dtype=PLOT_DTYPE)
        for name in ("time", "x", "y", "R", "flight_level", "address", "typ", "plot_id"):
            plots[name] = tracked[name]
        plots["time"] += 7200.0
        rows = tracker.process(plots)
        assert not np.any(rows["status"] == 3) and tracker.clock.now == now
        assert len(tracker.tracks) == live_local
        ahead = output.local.copy()
        ahead["time"] += 7200.0
        live, ended = len(fuser.system_tracks), fuser.stats.system_tracks_ended
        fuser.process(chain.sources.index(output.source), ahead, plots)
        assert fuser.stats.system_tracks_ended == ended and len(fuser.system_tracks) == live
        assert fuser.stats.out_of_line_updates == len(ahead)
    assert injected
    reference = clean.service.chain.fuser
    assert reference is not None
    assert len(fuser.system_tracks) >= len(reference.system_tracks) - 1
    assert fuser.stats.system_tracks_created <= reference.stats.system_tracks_created + 1
    for source, radar in chain.radars.items():
        baseline = clean.service.chain.radars[source].tracker.stats
        assert radar.tracker.stats.tracks_deleted <= baseline.tracks_deleted + 1


def restart(offset_s: float, at: float = MIDNIGHT + 25.0) -> Fault:
    """RADAR restarts at ``at`` with its clock ``offset_s`` off (plots and north markers)."""

    def fault(name: str, datagram: Datagram) -> list[Datagram]:
        if name != RADAR or _time(datagram) < at:
            return [datagram]
        payload = retimed(datagram.payload, lambda _i, t: (t + offset_s) % DAY_S)
        return [dataclasses.replace(datagram, payload=payload)]

    return fault


@pytest.mark.parametrize("offset_s", [60.0, -3600.0], ids=["60s-fast", "1h-slow"])
def test_a_radar_restarting_with_a_wrong_clock(
    recording: Path, clean: Run, offset_s: float
) -> None:
    """Today's main: 518 system tracks with the radar 60 s fast; an hour slow, nothing more
    from it. Now its tracker follows its new time after a few datagrams, it is kept out of
    fusion while out of step with the other radars, and status says why."""
    at = MIDNIGHT + 25.0
    faulty = run(recording, restart(offset_s, at))
    assert faulty.system_numbers <= clean.system_numbers + 2
    # Its local tracks go on, on its own (wrong) time.
    later = [u for u in faulty.local_of(KEY, at + offset_s + 20.0) if u["plot_id"] >= 0]
    assert later and faulty.confirmed_tracks(KEY) > clean.confirmed_tracks(KEY)
    tracker = faulty.service.chain.radars[KEY].tracker
    assert tracker.stats.clock_resyncs == 1
    # Plus the time its plots were held as implausible, then out of line.
    assert tracker.stats.last_clock_jump_s == pytest.approx(offset_s, abs=20.0)
    final = faulty.statuses[-1]
    assert final.health == "degraded"
    assert any(KEY in line and "kept out of fusion" in line for line in final.reasons)
    assert any(KEY in line and "tracker followed" in line for line in final.reasons)
    counted = final.radars[2].rejected
    assert counted["time_implausible"] > 0 and counted["out_of_line"] > 0
    # While its plots did not fit its timeline, that was a reason too.
    assert any(
        any(line.startswith(f"radar {KEY}: ") and "implausible times" in line for line in s.reasons)
        for s in faulty.statuses
    )
    assert not any("25/11" in line or "25/12" in line for line in final.reasons)


def test_a_radar_with_a_wrong_clock_re_based_on_reception_is_fused(
    recording: Path, clean: Run
) -> None:
    def rebase(doc: dict[str, Any]) -> None:
        for radar in doc["radars"]:
            if radar["sic"] == 13:
                radar["time_base"] = "reception"

    faulty = run(recording, restart(60.0, at=MIDNIGHT + 25.0), rebase)
    assert faulty.system_numbers <= clean.system_numbers + 3
    final = faulty.statuses[-1]
    assert not any("kept out of fusion" in line for line in final.reasons)
    assert KEY in faulty.fused
    tracked = [p for r, p in faulty.plots if r == KEY and p["use"] == PlotUse.TRACKED]
    times = np.array([p["time"] for p in tracked])
    assert times.max() < MIDNIGHT + DURATION_S  # re-based: not 60 s ahead


def test_a_capture_replayed_live_is_reported_and_can_be_re_based(
    recording: Path, clean: Run
) -> None:
    """``simulate -o x.pcap`` sent to ``run`` hours later: the data time is far from the
    reception. Today's main mixed the two times (80 system tracks for 45 aircraft) and said
    "degraded" without a reason."""
    shift = 6 * 3600.0 + 40 * 60.0

    def replayed(name: str, datagram: Datagram) -> list[Datagram]:
        return [dataclasses.replace(datagram, time=_time(datagram) + shift)]

    faulty = run(recording, replayed)
    final = faulty.statuses[-1]
    assert final.health == "degraded"
    for key in ("25/11", "25/12", "25/13"):
        assert any(
            line.startswith(f"radar {key}: data time 2400") and "behind its reception" in line
            for line in final.reasons
        ), final.reasons
    assert faulty.system_numbers <= clean.system_numbers + 1
    assert not any("kept out of fusion" in line for line in final.reasons)

    def on_reception(doc: dict[str, Any]) -> None:
        for radar in doc["radars"]:
            radar["time_base"] = "reception"

    rebased = run(recording, replayed, on_reception)
    final = rebased.statuses[-1]
    assert final.reasons == [] or all("25/50" in line for line in final.reasons)
    assert rebased.system_numbers <= clean.system_numbers + 1
    times = np.array([p["time"] for _, p in rebased.plots])
    assert times.min() > MIDNIGHT + shift - 10.0


def test_time_base_errors_name_the_field(recording: Path) -> None:
    doc = open_replay(recording).config.model_dump(mode="json", exclude_none=True)
    doc["radars"][0]["time_base"] = "gps"
    with pytest.raises(ConfigError, match=r"radars\.0\.time_base|radars\[0\]\.time_base"):
        parse_service_config(doc)
    doc["radars"][0]["time_base"] = "data"
    doc["time_sanity"] = {"max_offset": 3.0}
    with pytest.raises(ValueError, match="max_offset"):
        TrackerService(parse_service_config(doc))


def test_data_clock_follows_only_sustained_jumps() -> None:
    clock = DataClock(10.0, 10.0, resync_batches=3, resync_span_s=5.0)
    for t in range(0, 50, 5):
        assert clock.step(np.array([float(t)])).accepted.all()
    # One stamp two hours ahead, inside a batch or alone: refused, the clock stays.
    assert not clock.step(np.array([46.0, 7245.0, 47.0])).accepted[1]
    assert not clock.step(np.array([7248.0])).accepted.any()
    assert clock.now == 47.0
    # A radar an hour slow for good: held, then followed.
    steps = [clock.step(np.array([47.0 - 3600.0 + 2.0 * k])) for k in range(5)]
    assert [s.resynchronised for s in steps] == [False, False, False, True, False]
    assert steps[3].jump_s == pytest.approx(-3600.0 + 6.0 - 0.0, abs=0.1)
    assert clock.resyncs == 1


def test_the_local_tracker_follows_its_radar_back_after_an_outage() -> None:
    """Ten minutes without data: the first plots after it are held (out of line) until
    the stream has shown, over a period, that its time really moved on."""
    tracker = LocalTracker(TrackerConfig(scan_period_s=5.0))
    rng = np.random.default_rng(3)
    out = []
    for k in range(24):
        batch = np.zeros(1, dtype=PLOT_DTYPE)
        t = 1000.0 + 5.0 * k + (600.0 if k >= 8 else 0.0)
        batch["time"] = t
        batch["x"], batch["y"] = 20e3 + 200.0 * (t - 1000.0) + rng.normal(0, 30), 10e3
        batch["R"] = np.eye(2) * 900.0
        batch["plot_id"] = k
        batch["address"] = 0x3C0001
        batch["typ"] = 5
        out.append(tracker.process(batch))
    rows = np.concatenate(out)
    assert tracker.stats.clock_resyncs == 1
    assert tracker.stats.out_of_line_plots == 2  # held, then dropped when followed
    assert tracker.clock.now == pytest.approx(1000.0 + 5.0 * 23 + 600.0)
    after = rows[(rows["plot_id"] >= 10) & (rows["status"] == 1)]
    assert len(after) >= 10  # a new confirmed track from the plots after the outage
    assert DELETED_STATUS in rows["status"]  # the old one aged out


DELETED_STATUS = 3


def _updates(number: int, times: list[float], status: int = 1) -> Any:
    """Local-track updates of one straight track at ``times``."""
    rows = np.zeros(len(times), dtype=LocalTracker().output_dtype)
    rows["track_number"] = number
    rows["time"] = times
    rows["x"] = 200.0 * np.asarray(times)
    rows["vx"] = 200.0
    rows["P"] = np.diag([900.0, 900.0, 25.0, 25.0]).reshape(-1)
    rows["status"] = status
    rows["plot_id"] = np.asarray(times, dtype=np.int64) + 100_000
    rows["address"] = rows["mode3a"] = -1
    return rows


def test_numbers_freed_under_a_jumped_clock_are_not_blocked() -> None:
    """A track ended while the data stood two hours ahead; the radar's time comes back for
    good: the clock follows, and the freed number waits its delay from the new present,
    not two hours more."""
    config = FusionConfig(method="tracks", number_reuse_delay_s=300.0, longest_period_s=5.0)
    fuser = SystemTracker(1, config)
    empty = np.zeros(0, dtype=PLOT_DTYPE)
    for t in range(7200, 7240, 5):
        fuser.process(0, _updates(1, [float(t)]), empty)
    assert len(fuser.system_tracks) == 1
    fuser.process(0, _updates(1, [7240.0], status=3), empty)
    assert len(fuser.system_tracks) == 0
    for t in range(0, 40, 5):  # the stream is back at its true time
        fuser.process(0, _updates(2, [float(t)]), empty)
    assert fuser.stats.clock_resyncs == 1 and fuser.clock.now < 100.0
    assert fuser.stats.out_of_line_updates > 0
    assert len(fuser.system_tracks) == 1
    freed = fuser._sys["freed_at"]
    assert np.all(freed <= fuser.clock.now)


def test_simulate_start_now_puts_the_scenario_at_the_current_time(tmp_path: Path) -> None:
    out = tmp_path / "now.pcap"
    before = datetime.datetime.now(datetime.UTC).timestamp()
    args = ["simulate", str(SCENARIO), "-o", str(out), "--duration", "12", "--start", "now"]
    assert main(args) == 0
    source = open_replay(out, load_service_config(REPO / "config" / "example.toml"))
    service = TrackerService(source.config)
    for name, datagram in source.datagrams:
        assert datagram.time is not None and before - 1.0 <= datagram.time <= before + 60.0
        service.process(name, datagram)
    status = service.status()
    assert not any("reception" in line for line in status.reasons)
    offsets = [r.time_offset_s for r in status.radars if r.time_offset_s is not None]
    assert offsets and all(abs(o) < 2.0 for o in offsets)


def test_north_markers_alone_give_the_offset() -> None:
    sanity = TimeSanity()
    for k in range(6):
        items = {"010": {"SAC": 1, "SIC": 2}, "000": 1, "030": 36000.0 + 5.0 * k, "041": 5.0}
        sanity.service_message(items, 1_780_000_000.0 + 5.0 * k)
    report = sanity.report("1/2")
    assert report.offset_s is not None
    day = np.floor(1_780_000_000.0 / DAY_S) * DAY_S
    assert report.offset_s == pytest.approx(day + 36000.0 - 1_780_000_000.0)
    assert report.offset_reported


def test_the_log_says_whether_a_time_or_an_azimuth_is_implausible(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A plot far from the radar's time is logged with its distance in seconds; one on
    time whose azimuth the antenna did not point at then (the simulator's reflections)
    with the azimuth the antenna had, not as "+0.0 s from the expected time"."""
    received0 = 1_780_000_000.0
    day = np.floor(received0 / DAY_S) * DAY_S
    north_tod = received0 - day - 0.5
    sanity = TimeSanity(TimeSanityConfig(log_interval_s=1.0), periods={"1/2": 4.0})
    i140 = np.full(3, TimeSource.I140.value, dtype=np.int8)
    for turn in range(4):
        received = received0 + 4.0 * turn
        north = north_tod + 4.0 * turn
        items = {"010": {"SAC": 1, "SIC": 2}, "000": 1, "030": north, "041": 4.0}
        sanity.service_message(items, received)
        # Three plots a quarter turn on: at 90 degrees, the third on time at 180 (in the
        # last turn) or a minute late (in the third).
        times = np.full(3, day + north + 1.0)
        theta = np.array([90.0, 90.5, 90.0])
        if turn == 2:
            times[2] += 60.0
        if turn == 3:
            theta[2] = 180.0
        with caplog.at_level("WARNING", logger="tracker_service.time_sanity"):
            caplog.clear()
            _, implausible = sanity.check("1/2", times, i140, theta, received + 1.1)
        assert implausible.tolist() == [False, False, turn >= 2]
        warned = [r.getMessage() for r in caplog.records if "implausible" in r.getMessage()]
        if turn == 2:
            assert len(warned) == 1
            late = r"e\.g\. \+(59\.[5-9]|60\.[0-4]) s from the radar's expected time"
            assert re.search(late, warned[0])
        if turn == 3:
            assert len(warned) == 1
            assert "THETA 180.0 deg where the antenna pointed -90 deg from it" in warned[0]


def test_a_real_capture_loses_its_odd_plot_only() -> None:
    """The multi-radar capture (seven radars): no plot kept out but the one SIC 13 record
    stamped 18 s before its neighbours (both LAN copies), a TYP 0 record without a
    position (kept out for that: ``PlotUse.NO_POSITION`` comes first); 25/201's site
    monitor on 7777 is kept out for what it is. (test_real_data.py checks that the 79
    minutes of 068test_bds30.gps keep every plot.)"""
    pcap = track_capture(shared_file("croatiacontrol/cat_034_048.pcap"), NOMINAL_SITE_068)
    kept = [PlotUse.TRACKED, PlotUse.FIXED_TRANSPONDER]
    odd = {source: r.plots["time"][~np.isin(r.plots["use"], kept)] for source, r in pcap.items()}
    assert {s for s, t in odd.items() if len(t)} == {"25/13"}
    assert len(odd["25/13"]) == 2
    assert np.all(np.abs(odd["25/13"] % DAY_S - 27336.26) < 0.01)


def test_a_corrupt_i140_at_a_real_radars_midnight(tmp_path: Path) -> None:
    """parsegps.gps: a Spanish radar just after midnight; one plot's I140 made 19,711 s,
    as in the capture of issue 10: that plot alone is kept out."""
    original = shared_file("croatiacontrol/parsegps.gps").read_bytes()
    clean_run = track_capture(shared_file("croatiacontrol/parsegps.gps"), NOMINAL_SITE_068)
    data = bytearray(original)
    units = [d for d in read_file(shared_file("croatiacontrol/parsegps.gps"))]
    datagrams = [d for d in units if isinstance(d, Datagram) and d.payload[0] == 48]
    # An aircraft's plot (not the capture's test target or its 7777 site monitor).
    target, index = next(
        (d, int(aircraft[0]))
        for d in datagrams[1:]  # not the first plot: a radar's timeline needs one
        if len(plots := extract_plots(d.payload).plots)
        and len(aircraft := np.flatnonzero((plots["tst"] != 1) & (plots["mode3a"] != 0o7777)))
    )
    changed = retimed(target.payload, lambda i, t: 19711.0 if i == index else t, ("140",))
    assert len(changed) == len(target.payload)
    data[target.offset : target.offset + len(changed)] = changed
    faulty_file = tmp_path / "parsegps.gps"
    faulty_file.write_bytes(bytes(data))
    faulty = track_capture(faulty_file, NOMINAL_SITE_068)
    (run_clean,) = clean_run.values()
    (run_faulty,) = faulty.values()
    # Its test target and its site monitor (7777) are kept out too, for their own reasons.
    assert not np.any(run_clean.plots["use"] == PlotUse.TIME_IMPLAUSIBLE)
    rejected = run_faulty.plots["use"] == PlotUse.TIME_IMPLAUSIBLE
    assert int(np.count_nonzero(rejected)) == 1
    kept = run_faulty.plots[~rejected]
    assert np.all(np.abs(np.diff(np.sort(kept["time"]))) < 5.0)
    assert len(run_faulty.updates) >= len(run_clean.updates) - 1


def test_the_daemon_says_why_a_capture_sent_hours_late_is_degraded(tmp_path: Path) -> None:
    """``simulate`` without ``--start now`` sent to ``run`` over UDP on 127.0.0.1: the last
    status the daemon logs (built in its output process from plain rows) names each radar,
    its offset and the fix."""
    # Six hours before now, whatever the hour: a fixed time of day would be more than 12 h
    # off for half the day, and then the nearest day makes it ahead of its reception.
    six_hours_ago = datetime.datetime.now(datetime.UTC) - datetime.timedelta(hours=6)
    start = six_hours_ago.strftime("%Y-%m-%dT%H:%M:%SZ")
    recording = simulate_recording(tmp_path / "old.mcap", 12.0, start=start)
    feeds = Feeds(tmp_path)
    daemon = DaemonProcess(feeds, endpoint(), tmp_path / "health")
    try:
        feeds.send(recording, threading.Event())
        time.sleep(0.5)
        assert daemon.stop(signal.SIGTERM) == 0, "\n".join(daemon.lines)
    finally:
        if daemon.process.poll() is None:
            daemon.process.kill()
            daemon.process.wait()
    status = [m.data for m in logged(feeds.log_dir) if m.topic == "/status"][-1]
    assert status["health"] == "degraded"
    for key in ("25/11", "25/12", "25/13"):
        assert any(
            line.startswith(f"radar {key}: data time")
            and "behind its reception" in line
            and 'time_base = "reception"' in line
            for line in status["reasons"]
        ), status["reasons"]
    offsets = {r["radar"]: r["time_offset_s"] for r in status["radars"]}
    assert offsets["25/13"] is not None and offsets["25/13"] < -3600.0
    assert any("data time" in line and "behind its reception" in line for line in daemon.lines)


@pytest.mark.parametrize("base", ["data", "reception"])
def test_the_compiled_check_is_the_numpy_check(base: str) -> None:
    """A radar's batches through ``TimeSanity.check`` compiled and in numpy: the same
    times, implausible plots and evidence, batch by batch, through a stream with north
    markers, plots timed by I140, by azimuth and by reception, stray stamps, a jump of its
    clock an hour ahead and the midnight wrap."""
    rng = np.random.default_rng(7)
    sanities = [
        TimeSanity(bases={KEY: base}, periods={KEY: 5.0}, compiled=compiled)  # type: ignore[dict-item]
        for compiled in (False, True)
    ]
    received = MIDNIGHT - 300.0
    implausible = 0
    for batch in range(400):
        received += 0.625
        jump = 3600.0 if 150 <= batch < 260 else 0.0
        data_time = received - 0.8 + jump
        if batch % 8 == 0:
            north = {"000": 1, "010": {"SAC": 25, "SIC": 13}, "030": data_time % DAY_S, "041": 5.0}
            for sanity in sanities:
                sanity.service_message(north, received)
        n = int(rng.integers(1, 30))
        theta = (data_time % 5.0) / 5.0 * 360.0 + rng.uniform(-20.0, 0.0, n)
        theta[rng.random(n) < 0.05] = np.nan
        times = data_time - rng.uniform(0.0, 0.3, n)
        times[rng.random(n) < 0.03] += rng.choice([-7200.0, 40.0, 2.4])
        times = np.where(rng.random(n) < 0.3, times % DAY_S + MIDNIGHT - DAY_S, times)
        sources = rng.choice(np.array([0, 0, 0, 1, 2], np.int8), n)
        got = [s.check(KEY, times, sources, theta % 360.0, received) for s in sanities]
        (want_times, want_off), (times_c, off_c) = got
        assert want_times.tobytes() == times_c.tobytes()
        assert want_off.tobytes() == off_c.tobytes()
        a, b = (s._timelines[KEY] for s in sanities)
        assert list(a.offsets) == list(b.offsets) and list(a.phases) == list(b.phases)
        assert (a.rebase_s, a.implausible) == (b.rebase_s, b.implausible)
        implausible += int(off_c.sum())
    assert implausible > 20
