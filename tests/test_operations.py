"""What an operator meets first: a port in use (a radar's UDP input, the Zenoh endpoint)
as one line naming it, with real occupied ports on 127.0.0.1; Zenoh listening only where
told; ``subscribe`` saying when it is not connected; ``--version``, ``--log-level``;
``init`` writing the example configuration and scenarios."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.test_service_replay import free_port, simulate
from tracker_service.cli import main
from tracker_service.log_level import LOG_LEVEL_VARIABLE
from tracker_service.outputs.messages import StatusMessage
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_session import (
    ZenohEndpointError,
    check_listen_endpoints,
    zenoh_config,
)
from tracker_service.service.command import OutputProcess
from tracker_service.service.config import load_service_config
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay
from tracker_service.simulator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "tracker_service.cli"]


@pytest.fixture
def occupied_tcp() -> Iterator[int]:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        yield sock.getsockname()[1]


def _config(tmp_path: Path, radar_port: int) -> Path:
    text = (REPO / "config" / "example.toml").read_text(encoding="utf-8")
    # The first radar's input on the given port; the other feeds' on free ones.
    ports = iter([radar_port, *(free_port(socket.SOCK_DGRAM) for _ in range(3))])
    text = re.sub(
        r"(?m)^input = .*$",
        lambda _: f'input = {{ address = "127.0.0.1", port = {next(ports)} }}',
        text,
    )
    text = re.sub(r"(?m)^directory = .*$", "", text)
    path = tmp_path / "tracker.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _listening_sockets() -> list[str]:
    """This process's listening TCP and bound UDP sockets, from /proc."""
    inodes = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            link = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    found = []
    for table in ("tcp", "tcp6", "udp", "udp6"):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes and (fields[3] == "0A" or table.startswith("udp")):
                found.append(f"{table} {fields[1]}")
    return found


def _in_time_wait(port: int) -> bool:
    """Whether a TCP socket of 127.0.0.1:``port`` is in TIME_WAIT (state 06), from /proc."""
    lines = Path("/proc/net/tcp").read_text().splitlines()[1:]
    return any(f[1] == f"0100007F:{port:04X}" and f[3] == "06" for f in map(str.split, lines))


def test_a_radar_port_in_use_is_one_line(tmp_path: Path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        config = _config(tmp_path, port)
        done = subprocess.run(
            [*CLI, "run", "--config", str(config)], capture_output=True, text=True, timeout=60
        )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "radars[0].input.port (25/11" in lines[0] and f"127.0.0.1:{port}" in lines[0]
    assert "already bound" in lines[0]


@pytest.mark.parametrize(
    ("options", "fix"),
    [
        (["--zenoh-listen"], "(--zenoh-listen, [zenoh] listen)"),
        (["--role", "fusion", "--stage-listen"], "(--stage-listen)"),
        (["--role", "radar", "--radars", "25/11", "--stage-listen"], "(--stage-listen)"),
    ],
    ids=["daemon", "fusion role", "radar role"],
)
def test_a_zenoh_port_in_use_is_one_line_for_run_before_the_warm_up(
    tmp_path: Path, occupied_tcp: int, options: list[str], fix: str
) -> None:
    config = _config(tmp_path, free_port(socket.SOCK_DGRAM))
    endpoint = f"tcp/127.0.0.1:{occupied_tcp}"
    done = subprocess.run(
        [*CLI, "run", "--config", str(config), *options, endpoint],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2, done.stderr
    # The only line: said at start-up, before the minutes an empty numba cache's warm-up
    # can take (nothing logged, no input bound).
    assert done.stderr.strip().splitlines() == [
        f"tracker-service run: zenoh listen endpoint {endpoint}: the port is already in use "
        f"(a second tracker-service?): stop it (`ss -tlpn 'sport = :{occupied_tcp}'` names "
        f"it) or listen on another port {fix}"
    ]


def test_a_log_directory_that_cannot_be_written_is_one_line_before_the_warm_up(
    tmp_path: Path,
) -> None:
    config = _config(tmp_path, free_port(socket.SOCK_DGRAM))
    blocked = tmp_path / "a-file"
    blocked.write_text("not a directory")
    text = config.read_text(encoding="utf-8")
    config.write_text(
        text.replace("[mcap]\n", f'[mcap]\ndirectory = "{blocked}/logs"\n'), encoding="utf-8"
    )
    done = subprocess.run(
        [*CLI, "run", "--config", str(config)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"tracker-service run: [mcap] directory {blocked}/logs: Not a directory: give a "
        "directory the service's user can write, or none for no log"
    ]


def test_listen_endpoints_are_checked_as_zenoh_would_bind_them(occupied_tcp: int) -> None:
    taken = f"tcp/127.0.0.1:{occupied_tcp}"
    with pytest.raises(ZenohEndpointError, match="the port is already in use"):
        check_listen_endpoints(zenoh_config(listen=[f"{taken}#iface=lo"]))
    with pytest.raises(ZenohEndpointError, match=f"{taken}: the port is already in use"):
        check_listen_endpoints(zenoh_config(listen=[f"tcp/127.0.0.1:{free_port()}", taken]))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as datagrams:
        datagrams.bind(("127.0.0.1", 0))
        port = datagrams.getsockname()[1]
        with pytest.raises(ZenohEndpointError, match="already in use"):
            check_listen_endpoints(zenoh_config(listen=[f"udp/127.0.0.1:{port}"]))
    # TEST-NET-1 (RFC 5737): an address no host here has.
    with pytest.raises(ZenohEndpointError, match="not one of this host's"):
        check_listen_endpoints(zenoh_config(listen=["tcp/192.0.2.1:7447"]))
    # A port left in TIME_WAIT by a server just stopped (it closed first) is free; the
    # server's socket ``SO_REUSEADDR`` as Zenoh's listener (tokio's) has it.
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        stopped = server.getsockname()[1]
        with socket.create_connection(("127.0.0.1", stopped)) as client:
            accepted, _ = server.accept()
            accepted.close()
            client.recv(1)
    assert _in_time_wait(stopped)
    check_listen_endpoints(zenoh_config(listen=[f"tcp/127.0.0.1:{stopped}"]))
    # Free, ephemeral, what it cannot read (left to Zenoh): no error.
    check_listen_endpoints(
        zenoh_config(
            listen=[
                f"tcp/127.0.0.1:{free_port()}",
                "tcp/127.0.0.1:0",
                f"udp/127.0.0.1:{free_port(socket.SOCK_DGRAM)}",
                f"unixsock-stream/{tempfile.gettempdir()}/tracker-zenoh.sock",
            ]
        )
    )
    # The probe holds nothing: the port it checked is the session's.
    port = free_port()
    check_listen_endpoints(zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]))
    with ZenohPublisher(listen=[f"tcp/127.0.0.1:{port}"]):
        pass


def test_a_zenoh_port_in_use_is_one_line_for_replay(
    tmp_path: Path, occupied_tcp: int, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = simulate(tmp_path / "short.mcap", 5.0)
    endpoint = f"tcp/127.0.0.1:{occupied_tcp}"
    code = main(["replay", str(recording), "--speed", "max", "--zenoh-listen", endpoint])
    assert code == 2
    err = capsys.readouterr().err
    assert f"tracker-service replay: zenoh listen endpoint {endpoint}: the port" in err


def test_zenoh_listens_only_where_told() -> None:
    before = set(_listening_sockets())
    # --connect only: a peer that listens nowhere (Zenoh's own default is every
    # interface on a random port).
    with ZenohPublisher(connect=[f"tcp/127.0.0.1:{free_port()}"]):
        time.sleep(0.3)
        assert set(_listening_sockets()) - before == set()
    port = free_port()
    with ZenohPublisher(listen=[f"tcp/127.0.0.1:{port}"]):
        time.sleep(0.3)
        added = set(_listening_sockets()) - before
        assert added == {f"tcp 0100007F:{port:04X}"}
    # subscribe's session: the same rules.
    assert zenoh_config(connect=["tcp/127.0.0.1:7447"]).get_json("listen/endpoints") == "[]"


def test_subscribe_says_when_it_is_not_connected() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [*CLI, "subscribe", "--json", "--connect", endpoint],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    assert proc.stderr is not None
    try:
        line = proc.stderr.readline()
        assert f"not connected to {endpoint}" in line
        # The service comes: it says so.
        with ZenohPublisher(listen=[endpoint]):
            line = proc.stderr.readline()
            assert line.strip() == f"connected to {endpoint}"
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)


def test_version_and_log_level(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # `--log-level` reaches child processes through the environment: the variable is
    # restored after the test, or every daemon this worker starts later logs at WARNING
    # and never says it is running.
    monkeypatch.setenv(LOG_LEVEL_VARIABLE, "INFO")  # recorded: undone after the test
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert re.fullmatch(r"tracker-service \d+\.\d+\.\d+\S*\n", capsys.readouterr().out)
    with pytest.raises(SystemExit):
        main(["--log-level", "chatty", "health", "--file", "x"])
    assert "invalid choice: 'CHATTY'" in capsys.readouterr().err
    assert main(["--log-level", "warning", "health", "--file", "/nonexistent"]) == 1
    assert os.environ[LOG_LEVEL_VARIABLE] == "WARNING"


def test_init_writes_the_example_configuration_and_scenarios(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "site"
    assert main(["init", str(target)]) == 0
    config = load_service_config(target / "tracker.toml")
    assert [r.key for r in config.radars] == ["25/11", "25/12", "25/13"]
    scenarios = sorted(p.name for p in (target / "scenarios").glob("*.toml"))
    assert "three_sites.toml" in scenarios and len(scenarios) >= 5
    assert load_scenario(target / "scenarios" / "three_sites.toml").name
    assert os.access(target / "zenoh" / "make-certs.sh", os.X_OK)
    assert (target / "zenoh" / "service.json5").is_file()
    (target / "tracker.toml").write_text("# mine\n", encoding="utf-8")
    assert main(["init", str(target)]) == 0
    assert "kept" in capsys.readouterr().out
    assert (target / "tracker.toml").read_text(encoding="utf-8") == "# mine\n"


def test_the_adsb_feed_is_counted_in_status(tmp_path: Path) -> None:
    """Counted from the decoding the chain takes; the same with the outputs in a process
    of their own (the daemon's, the fusion role's), where the count crosses as a plain
    message: the last status of each, written at the close, compared."""
    recording = simulate(tmp_path / "adsb.mcap", 12.0)
    source = open_replay(str(recording), None, None)
    datagrams = list(source.datagrams)
    service = TrackerService(source.config)
    in_process = service.local.health_file = tmp_path / "in_process.json"
    for name, datagram in datagrams:
        service.process(name, datagram)
    status = {r.radar: r for r in service.status().radars}
    adsb = status["25/50"]
    assert adsb.receiving and adsb.plots_per_second > 1.0, adsb
    assert adsb.last_plot_time is not None and adsb.plot_delay_s is not None
    assert 0.0 <= adsb.plot_delay_s < 5.0
    service.close()
    apart = tmp_path / "output_process.json"
    with OutputProcess(
        source.config, None, zenoh=False, health_file=apart, supervised=False
    ) as outputs:
        core = TrackerService(source.config, outputs=outputs)
        for name, datagram in datagrams:
            core.process(name, datagram)
        core.close()
    last = [
        {r.radar: r for r in StatusMessage.model_validate_json(path.read_text()).radars}["25/50"]
        for path in (in_process, apart)
    ]
    assert last[0] == last[1] and last[0].plots_per_second > 1.0, last


def test_decode_and_replay_read_the_service_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recording = simulate(tmp_path / "short.mcap", 8.0)
    logs = tmp_path / "logs"
    assert main(["replay", str(recording), "--speed", "max", "--mcap-dir", str(logs)]) == 0
    replayed = re.search(r"replayed (\d+) datagrams", capsys.readouterr().err)
    assert replayed
    (log_file,) = logs.glob("*.mcap")
    for path in (log_file, logs):  # a log file, and the directory the service rotates in
        assert main(["decode", str(path), "--summary"]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["datagrams"] == int(replayed.group(1))
        assert summary["errors"] == 0 and summary["records"]["048"] > 50
    assert main(["replay", str(logs), "--speed", "max"]) == 0
    assert "service log" in capsys.readouterr().err
